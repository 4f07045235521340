import datetime as dt
import time

import pytest

from app.jobstore import JobState, JobStore, job_public


@pytest.fixture(params=["sqlite", "postgresql"])
def database_url(request, tmp_path):
    if request.param == "sqlite":
        return f"sqlite:///{tmp_path / 'jobs.db'}"
    return request.getfixturevalue("postgres_url")


@pytest.fixture
def jobs(database_url):
    store = JobStore(database_url)
    yield store
    store.close()


def _new(jobs, owner="A", lease=30.0):
    return jobs.create("orientation.batch", {"force": False}, {"photo-0000": "k"}, {"photo-0000": {"filename": "a.jpg"}},
                       owner, lease)


def test_create_and_read_back(jobs):
    job = _new(jobs)
    got = jobs.get(job.id)
    assert got.state == "queued" and got.attempts == 0 and got.lease_owner == "A"
    public = job_public(got)
    assert public["inputs"] == [{"name": "photo-0000", "filename": "a.jpg"}]
    assert public["created_at"].tzinfo is not None


def test_attempts_progress_and_finish_need_the_lease(jobs):
    job = _new(jobs)
    assert jobs.begin_attempt(job.id, "B", 30) is None  # B does not hold the lease
    assert jobs.begin_attempt(job.id, "A", 30).attempts == 1
    assert jobs.mark_running(job.id, "A")
    assert jobs.set_progress(job.id, "A", 0.5, "half")
    assert not jobs.set_progress(job.id, "B", 0.9, "not mine")
    assert jobs.finish(job.id, "A", JobState.succeeded, {"files": []})
    done = jobs.get(job.id)
    assert done.state == "succeeded" and done.progress == 1.0 and done.finished_at is not None
    # A final state is final: nothing moves it again.
    assert not jobs.finish(job.id, None, JobState.cancelled)
    assert not jobs.set_progress(job.id, "A", 0.1, "late")


def test_expired_leases_are_claimed_once(jobs):
    stale = _new(jobs, owner="dead", lease=0.01)
    fresh = _new(jobs, owner="alive", lease=60)
    time.sleep(0.05)
    claimed = jobs.claim_expired("B", 30)
    assert [j.id for j in claimed] == [stale.id]
    assert jobs.get(stale.id).lease_owner == "B"
    assert jobs.claim_expired("C", 30) == []  # B's lease is fresh now
    assert jobs.get(fresh.id).lease_owner == "alive"


def test_release_hands_a_job_to_the_next_claimer(jobs):
    job = _new(jobs, owner="A", lease=60)
    jobs.begin_attempt(job.id, "A", 60)
    jobs.mark_running(job.id, "A")
    assert jobs.release(job.id, "A")
    assert jobs.get(job.id).state == "queued"
    assert [j.id for j in jobs.claim_expired("B", 30)] == [job.id]


def test_list_filters_and_orders_newest_first(jobs):
    a = _new(jobs)
    b = _new(jobs)
    jobs.begin_attempt(b.id, "A", 30)
    jobs.finish(b.id, "A", JobState.failed, error="bad")
    assert [j.id for j in jobs.list()] == [b.id, a.id]
    assert [j.id for j in jobs.list(state="failed")] == [b.id]
    assert jobs.list(kind="nope") == []
    assert jobs.delete(a.id) and jobs.get(a.id) is None


def test_renew_extends_only_own_active_leases(jobs):
    job = _new(jobs, owner="A", lease=0.01)
    other = _new(jobs, owner="B", lease=0.01)
    jobs.renew_leases([job.id, other.id], "A", 60)
    now = dt.datetime.now(dt.timezone.utc).replace(tzinfo=None)
    assert jobs.get(job.id).lease_expires_at.replace(tzinfo=None) > now + dt.timedelta(seconds=50)
    assert jobs.get(other.id).lease_expires_at.replace(tzinfo=None) < now + dt.timedelta(seconds=5)


def test_migrations_match_the_model_and_run_twice(database_url):
    from alembic.autogenerate import compare_metadata
    from alembic.migration import MigrationContext

    import app.keys  # noqa: F401 - the api_keys table is declared there, on the same metadata
    from app.jobstore import Base

    first = JobStore(database_url)
    first.close()
    store = JobStore(database_url)  # a second start finds the schema current
    with store.engine.connect() as conn:
        diff = compare_metadata(MigrationContext.configure(conn), Base.metadata)
    store.close()
    assert diff == []


def _counts(jobs, job_id):
    job = jobs.get(job_id)
    return job.attempts, job.worker_losses, job.service_restarts


def test_lost_workers_and_service_restarts_are_counted_apart(jobs):
    job = _new(jobs, owner="A", lease=60)
    jobs.begin_attempt(job.id, "A", 60)
    assert jobs.record_worker_loss(job.id, "A") and not jobs.record_worker_loss(job.id, "B")
    assert jobs.begin_attempt(job.id, "A", 0.01).attempts == 2
    time.sleep(0.05)  # "A" was killed with its attempt open: its lease runs out
    assert [j.id for j in jobs.claim_expired("B", 60)] == [job.id]
    assert _counts(jobs, job.id) == (2, 1, 1)
    jobs.begin_attempt(job.id, "B", 60)
    assert jobs.release(job.id, "B")  # a clean stop with an attempt open
    assert _counts(jobs, job.id) == (3, 1, 2)
    assert [j.id for j in jobs.claim_expired("C", 60)] == [job.id]
    assert _counts(jobs, job.id) == (3, 1, 2)  # the release already counted that restart
    public = job_public(jobs.get(job.id))
    assert (public["attempts"], public["worker_losses"], public["service_restarts"]) == (3, 1, 2)


def test_a_restart_before_any_attempt_and_an_own_lapsed_lease_count_nothing(jobs):
    never_begun = _new(jobs, owner="dead", lease=0.01)
    own = _new(jobs, owner="A", lease=60)
    jobs.begin_attempt(own.id, "A", 0.01)
    time.sleep(0.05)
    assert {j.id for j in jobs.claim_expired("A", 60)} == {never_begun.id, own.id}
    assert _counts(jobs, never_begun.id) == (0, 0, 0)
    assert _counts(jobs, own.id) == (1, 0, 0)  # A's attempt still runs: no restart happened


def test_begin_attempt_counts_nothing_once_the_lost_worker_budget_is_spent(jobs):
    job = _new(jobs, owner="A", lease=60)
    for _ in range(2):
        jobs.begin_attempt(job.id, "A", 60, max_worker_losses=2)
        jobs.record_worker_loss(job.id, "A")
    spent = jobs.begin_attempt(job.id, "A", 60, max_worker_losses=2)
    assert spent.worker_losses == 2 and spent.attempts == 2


def test_rows_from_before_owners_belong_to_admin_after_the_migration(tmp_path):
    from alembic import command
    from alembic.config import Config
    from sqlalchemy import text

    from app.jobstore import make_engine
    from app.migrate import MIGRATIONS

    url = f"sqlite:///{tmp_path / 'old.db'}"
    engine = make_engine(url)
    config = Config()
    config.set_main_option("script_location", str(MIGRATIONS))
    with engine.begin() as conn:  # the schema of the release before owners, with one job in it
        config.attributes["connection"] = conn
        command.upgrade(config, "0002")
        conn.execute(text("INSERT INTO jobs (id, kind, params, inputs, input_meta, state, progress, stage, attempts, "
                          "created_at, updated_at) VALUES ('old', 'orientation.batch', '{}', '{}', '{}', 'succeeded', "
                          "1.0, 'done', 1, '2026-11-01 00:00:00', '2026-11-01 00:00:00')"))
    engine.dispose()
    jobs = JobStore(url)  # migrates to the newest schema
    try:
        assert jobs.get("old").created_by == "admin"
        assert [j.id for j in jobs.list(created_by="admin")] == ["old"] and jobs.list(created_by="key_x") == []
        assert jobs.usage("admin") == (0, 0)
    finally:
        jobs.close()


def test_stored_bytes_count_inputs_then_results(jobs):
    job = jobs.create("orientation.batch", {}, {"a": "k", "r": "other"}, {"a": {"size": 1000}, "r": {"stored": "x"}},
                      "A", 30, created_by="key_1")
    assert jobs.usage("key_1") == (1000, 1)  # an input read in place (another job's) is not this job's
    jobs.finish(job.id, "A", JobState.succeeded, {"files": [{"name": "out", "size": 500}]})
    assert jobs.usage("key_1") == (1500, 0) and jobs.usage("key_2") == (0, 0)
    assert jobs.replace_result(job.id, {"files": [{"name": "out", "size": 500}, {"name": "more", "size": 20}]})
    assert jobs.usage("key_1") == (1520, 0)
