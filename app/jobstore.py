"""The job table: the source of truth for every batch job (SQLAlchemy 2; SQLite or PostgreSQL).

Ray keeps nothing across a restart, so a row is committed before its job is submitted, and a
replica owns a job only while it holds the row's lease. Claiming is a single conditional
UPDATE, so two replicas (or a replica and its own recovery sweep) never run the same attempt.

Every attempt that began (``attempts``) ends in one of three ways: a final state, a lost worker
(``worker_losses``, counted by the dispatcher; these spend the retry budget) or a service restart
(``service_restarts``: the replica that ran it stopped or died, counted when its lease is given
back or claimed; these never spend the budget). While a job is active, ``attempts`` minus the two
counters is 1 when an attempt is open, else 0.
"""
from __future__ import annotations

import datetime as dt
import enum
import uuid
from typing import Any, Iterable

from sqlalchemy import (JSON, BigInteger, DateTime, Float, Index, Integer, String, Text, and_, case, create_engine,
                        event, func, select, update)
from sqlalchemy import exc as sa_exc
from sqlalchemy.engine import Engine
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column, sessionmaker


class JobState(str, enum.Enum):
    queued = "queued"
    running = "running"
    succeeded = "succeeded"
    failed = "failed"
    cancelled = "cancelled"

    @property
    def finished(self) -> bool:
        return self in (JobState.succeeded, JobState.failed, JobState.cancelled)


ACTIVE = (JobState.queued.value, JobState.running.value)
ADMIN = "admin"
"""The principal of the service's own keys (``SWEEPCAST_API_KEYS``, or no keys at all) and of every row stored before
jobs had owners."""


def utcnow() -> dt.datetime:
    return dt.datetime.now(dt.timezone.utc)


class Base(DeclarativeBase):
    pass


class Job(Base):
    __tablename__ = "jobs"
    __table_args__ = (Index("ix_jobs_created_by_created_at", "created_by", "created_at", "id"),
                      Index("ix_jobs_created_by_state", "created_by", "state"),
                      Index("ix_jobs_created_at", "created_at", "id"))

    id: Mapped[str] = mapped_column(String(36), primary_key=True)
    kind: Mapped[str] = mapped_column(String(64), index=True)
    params: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)
    inputs: Mapped[dict[str, str]] = mapped_column(JSON, default=dict)
    input_meta: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)
    state: Mapped[str] = mapped_column(String(16), index=True, default=JobState.queued.value)
    progress: Mapped[float] = mapped_column(Float, default=0.0)
    stage: Mapped[str] = mapped_column(String(200), default="queued")
    result: Mapped[dict[str, Any] | None] = mapped_column(JSON, nullable=True)
    error: Mapped[str | None] = mapped_column(Text, nullable=True)
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    worker_losses: Mapped[int] = mapped_column(Integer, default=0, server_default="0")
    service_restarts: Mapped[int] = mapped_column(Integer, default=0, server_default="0")
    lease_owner: Mapped[str | None] = mapped_column(String(64), nullable=True)
    lease_expires_at: Mapped[dt.datetime | None] = mapped_column(DateTime(timezone=True), nullable=True, index=True)
    created_at: Mapped[dt.datetime] = mapped_column(DateTime(timezone=True), default=utcnow)
    updated_at: Mapped[dt.datetime] = mapped_column(DateTime(timezone=True), default=utcnow)
    started_at: Mapped[dt.datetime | None] = mapped_column(DateTime(timezone=True), nullable=True)
    finished_at: Mapped[dt.datetime | None] = mapped_column(DateTime(timezone=True), nullable=True)
    created_by: Mapped[str] = mapped_column(String(64), default=ADMIN, server_default=ADMIN)
    """The key (principal id) that created the job: only it and admin keys see the job."""
    stored_bytes: Mapped[int] = mapped_column(BigInteger, default=0, server_default="0")
    """Bytes the job keeps in the blob store: its uploaded inputs, plus its result files once it succeeded."""

    def as_dict(self) -> dict[str, Any]:
        return {c.name: getattr(self, c.name) for c in self.__table__.columns}


def _restart_interrupts_open_attempt(new_owner: str | None = None) -> Any:
    """SQL for ``service_restarts`` when a job leaves its replica: one more if an attempt was open
    (begun, and neither lost nor interrupted yet). With ``new_owner``, a replica re-claiming its
    own lapsed lease is no restart: its attempt still runs."""
    open_attempt = Job.attempts > Job.worker_losses + Job.service_restarts
    if new_owner is not None:
        open_attempt = and_(open_attempt, Job.lease_owner != new_owner)
    return case((open_attempt, Job.service_restarts + 1), else_=Job.service_restarts)


def as_utc(value: dt.datetime | None) -> dt.datetime | None:
    # SQLite returns naive datetimes even for timezone=True columns.
    if value is not None and value.tzinfo is None:
        return value.replace(tzinfo=dt.timezone.utc)
    return value


DATABASE_DOWN = ("the job database cannot be reached just now: nothing was changed; retry in a few seconds "
                 "(`/readyz` says when it is back)")


def database_unavailable(exc: BaseException) -> bool:
    """Whether ``exc`` says the database cannot be reached or used just now (refused, dropped or timed-out
    connections, a server shutting down, SQLite's busy file), as opposed to a bug in a query: worth a wait and
    another try, and a 503 to a client meanwhile."""
    if isinstance(exc, sa_exc.DBAPIError):
        return exc.connection_invalidated or isinstance(exc, (sa_exc.OperationalError, sa_exc.InterfaceError))
    return isinstance(exc, sa_exc.TimeoutError)  # the connection pool's wait


def normalise_url(url: str) -> str:
    """Plain ``postgresql://`` (or ``postgres://``) URLs use psycopg 3, the driver we install."""
    for prefix in ("postgresql://", "postgres://"):
        if url.startswith(prefix):
            return "postgresql+psycopg://" + url[len(prefix):]
    return url


def make_engine(url: str) -> Engine:
    """An engine for ``url``; SQLite gets WAL mode and a busy timeout for concurrent writers."""
    url = normalise_url(url)
    if url.startswith("sqlite"):
        engine = create_engine(url, connect_args={"check_same_thread": False, "timeout": 30})

        @event.listens_for(engine, "connect")
        def _pragmas(dbapi_conn: Any, _record: Any) -> None:
            cur = dbapi_conn.cursor()
            cur.execute("PRAGMA journal_mode=WAL")
            cur.execute("PRAGMA synchronous=NORMAL")
            cur.close()

        return engine
    # A server that does not answer (a frozen host, a dropped network) fails a connection within seconds rather
    # than holding a request and a thread for as long as the operating system's TCP timeout.
    return create_engine(url, pool_pre_ping=True, connect_args={"connect_timeout": 5})


class JobStore:
    """Every read and write of the job table. Methods are blocking: call them off the event loop."""

    def __init__(self, url: str) -> None:
        from app.migrate import upgrade

        self.engine = make_engine(url)
        upgrade(self.engine)
        self._session = sessionmaker(self.engine, expire_on_commit=False)

    def close(self) -> None:
        self.engine.dispose()

    def ping(self) -> None:
        with self.engine.connect() as conn:
            conn.exec_driver_sql("SELECT 1")

    def create(
        self,
        kind: str,
        params: dict[str, Any],
        inputs: dict[str, str],
        input_meta: dict[str, Any],
        owner: str,
        lease_seconds: float,
        job_id: str | None = None,
        created_by: str = ADMIN,
    ) -> Job:
        """Commit a new queued job leased to ``owner`` (the replica that submits it next), created by the key
        ``created_by``; its uploaded inputs' sizes (``input_meta[name]["size"]``) count as its stored bytes."""
        now = utcnow()
        job = Job(
            id=job_id or str(uuid.uuid4()),
            kind=kind,
            params=params,
            inputs=inputs,
            input_meta=input_meta,
            state=JobState.queued.value,
            stage="queued",
            progress=0.0,
            attempts=0,
            worker_losses=0,
            service_restarts=0,
            lease_owner=owner,
            lease_expires_at=now + dt.timedelta(seconds=lease_seconds),
            created_at=now,
            updated_at=now,
            created_by=created_by,
            stored_bytes=_input_bytes(input_meta),
        )
        with self._session.begin() as s:
            s.add(job)
        return job

    def get(self, job_id: str) -> Job | None:
        with self._session() as s:
            return s.get(Job, job_id)

    def list(self, state: str | None = None, kind: str | None = None, limit: int = 50, offset: int = 0,
             created_by: str | None = None) -> list[Job]:
        """Jobs newest first; ``created_by``: only that key's (an index range, not a scan of the table)."""
        query = select(Job).order_by(Job.created_at.desc(), Job.id.desc()).limit(limit).offset(offset)
        if created_by is not None:
            query = query.where(Job.created_by == created_by)
        if state:
            query = query.where(Job.state == state)
        if kind:
            query = query.where(Job.kind == kind)
        with self._session() as s:
            return list(s.scalars(query))

    def usage(self, created_by: str) -> tuple[int, int]:
        """(bytes stored, jobs queued or running) of one key's jobs."""
        query = select(func.coalesce(func.sum(Job.stored_bytes), 0),
                       func.count().filter(Job.state.in_(ACTIVE))).where(Job.created_by == created_by)
        with self._session() as s:
            stored, active = s.execute(query).one()
        return int(stored), int(active)

    def claim_expired(self, owner: str, lease_seconds: float, limit: int = 100) -> list[Job]:
        """Take over active jobs whose lease has expired (their owner is gone); return them. An
        attempt their owner had open was interrupted by a service restart: counted as one."""
        now = utcnow()
        with self._session() as s:
            candidates = list(s.scalars(
                select(Job.id).where(Job.state.in_(ACTIVE), Job.lease_expires_at < now).limit(limit)
            ))
        claimed = []
        for job_id in candidates:
            if self._conditional_update(
                job_id,
                [Job.state.in_(ACTIVE), Job.lease_expires_at < now],
                lease_owner=owner,
                lease_expires_at=now + dt.timedelta(seconds=lease_seconds),
                state=JobState.queued.value,
                stage="recovered, queued again",
                service_restarts=_restart_interrupts_open_attempt(owner),
            ):
                claimed.append(self.get(job_id))
        return [j for j in claimed if j is not None]

    def begin_attempt(self, job_id: str, owner: str, lease_seconds: float,
                      max_worker_losses: int | None = None) -> Job | None:
        """Count a new attempt of a job this owner holds; None when it is no longer ours or active.
        When ``max_worker_losses`` attempts were already lost, nothing is counted: the caller sees
        ``job.worker_losses >= max_worker_losses`` and gives up."""
        with self._session.begin() as s:
            job = s.get(Job, job_id, with_for_update=True)
            if job is None or job.state not in ACTIVE or job.lease_owner != owner:
                return None
            if max_worker_losses is not None and job.worker_losses >= max_worker_losses:
                return job
            job.attempts += 1
            job.lease_expires_at = utcnow() + dt.timedelta(seconds=lease_seconds)
            job.updated_at = utcnow()
        return job

    def record_worker_loss(self, job_id: str, owner: str) -> bool:
        """The open attempt of a job this owner holds lost its worker (it spends the retry budget)."""
        return self._conditional_update(
            job_id, [Job.state.in_(ACTIVE), Job.lease_owner == owner], worker_losses=Job.worker_losses + 1,
        )

    def mark_running(self, job_id: str, owner: str) -> bool:
        now = utcnow()
        return self._conditional_update(
            job_id, [Job.state.in_(ACTIVE), Job.lease_owner == owner],
            state=JobState.running.value, started_at=now, stage="running",
        )

    def set_progress(self, job_id: str, owner: str, fraction: float, stage: str) -> bool:
        return self._conditional_update(
            job_id, [Job.state.in_(ACTIVE), Job.lease_owner == owner], progress=fraction, stage=stage[:200],
        )

    def renew_leases(self, job_ids: Iterable[str], owner: str, lease_seconds: float) -> None:
        ids = list(job_ids)
        if not ids:
            return
        with self._session.begin() as s:
            s.execute(
                update(Job)
                .where(Job.id.in_(ids), Job.lease_owner == owner, Job.state.in_(ACTIVE))
                .values(lease_expires_at=utcnow() + dt.timedelta(seconds=lease_seconds))
            )

    def release(self, job_id: str, owner: str) -> bool:
        """Give an active job back (on shutdown): anyone may claim it at once. Its open attempt,
        if any, counts as interrupted by a service restart."""
        return self._conditional_update(
            job_id, [Job.state.in_(ACTIVE), Job.lease_owner == owner],
            state=JobState.queued.value, stage="queued (service restarted)", lease_expires_at=utcnow(),
            service_restarts=_restart_interrupts_open_attempt(),
        )

    def finish(self, job_id: str, owner: str | None, state: JobState, result: dict | None = None,
               error: str | None = None) -> bool:
        """Move an active job to a final state (owner None: whoever holds it, e.g. a cancel)."""
        conditions = [Job.state.in_(ACTIVE)]
        if owner is not None:
            conditions.append(Job.lease_owner == owner)
        values: dict[str, Any] = dict(state=state.value, finished_at=utcnow(), result=result, error=error,
                                      lease_expires_at=None, stage=state.value)
        if state is JobState.succeeded:
            values["progress"] = 1.0
            values["stored_bytes"] = Job.stored_bytes + _result_bytes(result)
        return self._conditional_update(job_id, conditions, **values)

    def replace_result(self, job_id: str, result: dict) -> bool:
        """Replace a succeeded job's result manifest (a person's review adds files and counts); False when the job
        is not (or no longer) succeeded."""
        with self._session.begin() as s:
            job = s.get(Job, job_id, with_for_update=True)
            if job is None or job.state != JobState.succeeded.value:
                return False
            job.stored_bytes = _input_bytes(job.input_meta) + _result_bytes(result)
            job.result = result
            job.updated_at = utcnow()
        return True

    def delete(self, job_id: str) -> bool:
        with self._session.begin() as s:
            job = s.get(Job, job_id)
            if job is None:
                return False
            s.delete(job)
        return True

    def _conditional_update(self, job_id: str, conditions: list, **values: Any) -> bool:
        values.setdefault("updated_at", utcnow())
        with self._session.begin() as s:
            result = s.execute(update(Job).where(Job.id == job_id, *conditions).values(**values))
        return result.rowcount == 1


def _input_bytes(input_meta: dict[str, Any] | None) -> int:
    """Bytes of a job's own uploaded inputs (inputs it reads in place, ``stored``, belong to another job)."""
    return sum(int(m.get("size") or 0) for m in (input_meta or {}).values() if "stored" not in m)


def _result_bytes(result: dict[str, Any] | None) -> int:
    return sum(int(f.get("size") or 0) for f in (result or {}).get("files", []))


def job_public(job: Job) -> dict[str, Any]:
    """The API view of a row."""
    return {
        "id": job.id,
        "kind": job.kind,
        "created_by": job.created_by or ADMIN,
        "state": job.state,
        "progress": {"fraction": job.progress, "stage": job.stage},
        "params": job.params,
        "inputs": [
            {"name": name, **{k: v for k, v in (job.input_meta or {}).get(name, {}).items() if k in ("filename", "size")}}
            for name in sorted(job.inputs or {})
        ],
        "result": job.result,
        "error": job.error,
        "attempts": job.attempts,
        "worker_losses": job.worker_losses or 0,
        "service_restarts": job.service_restarts or 0,
        "created_at": as_utc(job.created_at),
        "started_at": as_utc(job.started_at),
        "finished_at": as_utc(job.finished_at),
        "updated_at": as_utc(job.updated_at),
    }
