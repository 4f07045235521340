"""Each key sees only its own: two user keys and an admin key against every route of the OpenAPI document and
every socket.

Alice (a user key) creates one resource of each kind (a photo batch, a face model, a rig with a recording);
Bob (another user key) then calls every operation of the service's own OpenAPI document with Alice's ids and
gets 404, as for ids that do not exist, while Alice gets something else. The operations are read off the
document, so a new route is checked without a new test (and fails here until its path parameters have a value
below).
"""
from __future__ import annotations

import json
import time

import pytest
from starlette.websockets import WebSocketDisconnect

from harness.photos import noise_jpeg
from harness.tenancy import operations, probe, refused_as_missing
from harness.takes import make_take, rig_json, zip_bytes
from tests.streaming.conftest import wait_recording

ADMIN = "admin-secret"


def _make_key(client, name: str, **extra) -> tuple[str, str]:
    r = client.post("/v1/keys", json={"name": name, **extra}, headers=_auth(ADMIN))
    assert r.status_code == 201, r.text
    return r.json()["id"], r.json()["secret"]


def _auth(secret: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {secret}"}


@pytest.fixture(scope="module")
def take():
    return make_take()


@pytest.fixture(scope="module")
def service(ray_local, tmp_path_factory):
    """One service for the module's read-mostly tests (starting one per test cost seconds each)."""
    from fastapi.testclient import TestClient

    from app.main import create_app
    from app.settings import Settings
    from tests.conftest import _wait_ready

    settings = Settings(data_dir=tmp_path_factory.mktemp("tenants") / "data", job_lease_seconds=5.0, demo_rig=False,
                        fetch_models=False, api_keys=[ADMIN])
    with TestClient(create_app(settings)) as client:
        _wait_ready(client)
        yield client


@pytest.fixture(scope="module")
def world(service, take):
    """Alice's resources of every kind in :func:`service`; the keys of Alice and Bob. Tests leave them as they
    found them (the key tests make their own keys)."""
    client = service
    alice_id, alice = _make_key(client, "alice")
    _, bob = _make_key(client, "bob")
    a = _auth(alice)
    rig = client.post("/v1/rigs", files={"files": ("rig.json", rig_json(take.rig))}, headers=a)
    assert rig.status_code == 201, rig.text
    rig_id = rig.json()["id"]
    rec = client.post(f"/v1/rigs/{rig_id}/recordings", files={"archive": ("take.zip", zip_bytes(take))},
                      data={"params": '{"fps": 5}'}, headers=a)
    assert rec.status_code == 202, rec.text
    batch = client.post("/v1/photos/batches", files=[("files", ("a.jpg", noise_jpeg(1), "image/jpeg"))], headers=a)
    assert batch.status_code == 202, batch.text
    model = client.post("/v1/face-models", data={"params": '{"source": "synthetic"}'}, headers=a)
    assert model.status_code == 202, model.text
    client.headers.update(a)
    recording = wait_recording(client, rig_id, rec.json()["id"])
    client.headers.pop("Authorization")
    assert recording["state"] == "ready", recording
    ids = {"job_id": batch.json()["id"], "model_id": model.json()["id"], "rig_id": rig_id,
           "recording_id": recording["id"], "index": "0", "name": "report.json", "frame": "0",
           "key_id": alice_id}
    return {"client": client, "alice": alice, "bob": bob, "alice_id": alice_id, "ids": ids, "take": take}


def _operations(client) -> list[tuple[str, str]]:
    return operations(client.get("/openapi.json").json())


def test_another_keys_resources_answer_404_on_every_route(world):
    client, ids = world["client"], world["ids"]
    doc = client.get("/openapi.json").json()
    assert len(operations(doc)) >= 30
    rows = probe(client, doc, ids, world["bob"], world["alice"])
    assert len(rows) >= 15
    wrong = [r for r in rows if not refused_as_missing(r)]
    assert not wrong, wrong
    # Bob's deletions deleted nothing: Alice still reads everything.
    a = _auth(world["alice"])
    assert client.get(f"/v1/jobs/{ids['job_id']}", headers=a).status_code == 200
    assert client.get(f"/v1/rigs/{ids['rig_id']}/recordings/{ids['recording_id']}", headers=a).json()["state"] == "ready"


def test_lists_show_each_key_its_own_and_an_admin_everything(world):
    client, ids = world["client"], world["ids"]
    bob, alice = _auth(world["bob"]), _auth(world["alice"])
    bob_rig = client.post("/v1/rigs", files={"files": ("rig.json", rig_json(world["take"].rig))}, headers=bob).json()["id"]
    lists = {"/v1/jobs": ("jobs", "id"), "/v1/rigs": ("rigs", "id"), "/v1/face-models": ("models", "id"),
             "/v1/sessions": ("sessions", "rig_id")}
    listed_ops = {p for m, p in _operations(client) if m == "get" and "{" not in p and p != "/v1/keys/me"}
    assert listed_ops - {"/v1/keys"} == set(lists), "a new list route: say here what it lists"
    with client.websocket_connect(f"/v1/rigs/{ids['rig_id']}/view?render=browser&access_token={world['alice']}") as ws:
        assert ws.receive_json()["type"] == "hello"  # a session of Alice's rig now exists... for browser viewers none
    for path, (field, key) in lists.items():
        for who, others in ((bob, set(ids.values())), (alice, {bob_rig})):
            seen = {item[key] for item in client.get(path, headers=who).json()[field]}
            assert not seen & others, (path, seen & others)
    everything = {j["id"] for j in client.get("/v1/jobs", headers=_auth(ADMIN)).json()["jobs"]}
    assert {ids["job_id"], ids["model_id"], ids["recording_id"]} <= everything
    assert {bob_rig, ids["rig_id"]} <= {r["id"] for r in client.get("/v1/rigs", headers=_auth(ADMIN)).json()["rigs"]}
    job = client.get(f"/v1/jobs/{ids['job_id']}", headers=_auth(ADMIN)).json()
    assert job["created_by"] == world["alice_id"]


def test_sockets_refuse_another_keys_job_and_rig(world):
    client, ids = world["client"], world["ids"]
    with client.websocket_connect(f"/v1/jobs/{ids['job_id']}/events?access_token={world['bob']}") as ws:
        assert ws.receive_json() == {"type": "error", "detail": f"no job with id {ids['job_id']!r}"}
    for socket in ("view", "view?render=browser", "live"):
        sep = "&" if "?" in socket else "?"
        with client.websocket_connect(f"/v1/rigs/{ids['rig_id']}/{socket}{sep}access_token={world['bob']}") as ws:
            message = ws.receive_json()
            assert message["type"] == "error" and message["error"] == "rig_not_found", (socket, message)
    with client.websocket_connect(f"/v1/jobs/{ids['job_id']}/events?access_token={world['alice']}") as ws:
        assert ws.receive_json()["type"] in ("snapshot", "final")


def test_the_demo_rig_is_read_by_every_key_and_changed_by_admins_only(world):
    from workers.streaming import store as rigstore

    client, take = world["client"], world["take"]
    svc = client.app.state.services
    demo_id = rigstore.new_rig_id()
    rigstore.save_rig(svc.store, demo_id, take.rig, {"name": "demo", "format": "json", "demo": True})
    bob = _auth(world["bob"])
    assert client.get(f"/v1/rigs/{demo_id}", headers=bob).status_code == 200
    assert demo_id in {r["id"] for r in client.get("/v1/rigs", headers=bob).json()["rigs"]}
    refused = client.delete(f"/v1/rigs/{demo_id}", headers=bob)
    assert refused.status_code == 403 and refused.json()["error"] == "demo_rig_read_only"
    with client.websocket_connect(f"/v1/rigs/{demo_id}/live?access_token={world['bob']}") as ws:
        assert ws.receive_json()["error"] == "demo_rig_read_only"
    assert client.delete(f"/v1/rigs/{demo_id}", headers=_auth(ADMIN)).status_code == 204


def test_keys_are_managed_by_admins_and_revocation_is_immediate(world):
    client = world["client"]
    erin_id, erin = _make_key(client, "erin")
    _, frank = _make_key(client, "frank")
    f = _auth(frank)
    for method, path in (("get", "/v1/keys"), ("post", "/v1/keys"), ("delete", f"/v1/keys/{erin_id}"),
                         ("post", f"/v1/keys/{erin_id}/rotate")):
        r = client.request(method.upper(), path, headers=f, **({"json": {"name": "x"}} if method == "post" else {}))
        assert r.status_code == 403 and r.json()["error"] == "admin_only", (method, path, r.text)
    me = client.get("/v1/keys/me", headers=f).json()
    assert me["name"] == "frank" and me["role"] == "user" and me["limits"]["active_jobs"] == 8
    listed = client.get("/v1/keys", headers=_auth(ADMIN)).json()["keys"]
    assert {"alice", "bob", "erin", "frank"} <= {k["name"] for k in listed}
    assert "secret" not in json.dumps(listed) and erin not in json.dumps(listed)
    rig = client.post("/v1/rigs", files={"files": ("rig.json", rig_json(world["take"].rig))}, headers=_auth(erin))
    rotated = client.post(f"/v1/keys/{erin_id}/rotate", headers=_auth(ADMIN)).json()["secret"]
    assert client.get("/v1/jobs", headers=_auth(erin)).status_code == 401  # the old secret, at once
    assert client.get(f"/v1/rigs/{rig.json()['id']}", headers=_auth(rotated)).status_code == 200  # still hers
    assert client.delete(f"/v1/keys/{erin_id}", headers=_auth(ADMIN)).status_code == 204
    assert client.get("/v1/jobs", headers=_auth(rotated)).status_code == 401
    expired = client.post("/v1/keys", json={"name": "old", "expires_at": "2020-01-01T00:00:00Z"},
                          headers=_auth(ADMIN)).json()["secret"]
    assert client.get("/v1/jobs", headers=_auth(expired)).status_code == 401
    assert client.delete("/v1/keys/me", headers=f).status_code == 204  # a key revokes itself (it leaked)
    assert client.get("/v1/keys/me", headers=f).status_code == 401
    assert client.delete("/v1/keys/me", headers=_auth(ADMIN)).json()["error"] == "service_key"


def test_quotas_refuse_before_anything_is_stored(client_factory):
    client = client_factory(api_keys=[ADMIN], quota_uploads_per_minute=3)
    _, small = _make_key(client, "small", quota={"stored_bytes": 60_000, "active_jobs": 5})
    s = _auth(small)
    store = client.app.state.services.store
    first = client.post("/v1/photos/batches", files=[("files", ("a.jpg", noise_jpeg(1), "image/jpeg"))], headers=s)
    assert first.status_code == 202, first.text
    blobs = sorted(store.list("jobs"))
    over = client.post("/v1/photos/batches", headers=s, files=[("files", (f"{i}.jpg", noise_jpeg(i), "image/jpeg"))
                                                               for i in range(2, 6)])
    assert over.status_code == 507 and over.json()["error"] == "storage_quota_exceeded", over.text
    jobs = client.get("/v1/jobs", headers=s).json()["jobs"]
    assert [j["id"] for j in jobs] == [first.json()["id"]]  # the refused batch left no job
    assert sorted(store.list("jobs")) == blobs  # ... and stored no input
    tiny = {"file": ("a.jpg", noise_jpeg(1, 64, 48), "image/jpeg")}
    client.post("/v1/photos/orientation", files=tiny, headers=s)
    rate = client.post("/v1/photos/orientation", files=tiny, headers=s)
    assert rate.status_code == 429 and 1 <= int(rate.headers["retry-after"]) <= 60, rate.text
    assert rate.json()["error"] == "upload_rate_exceeded"
    me = client.get("/v1/keys/me", headers=s).json()
    assert me["limits"]["stored_bytes"] == 60_000 and me["usage"]["uploads_per_minute"] == 3
    assert 0 < me["usage"]["stored_bytes"] <= 60_000
    # the admin key has no limits of its own
    for _ in range(4):
        assert client.post("/v1/photos/orientation", files=tiny, headers=_auth(ADMIN)).status_code == 200
    assert client.get("/v1/keys/me", headers=_auth(ADMIN)).json()["limits"]["uploads_per_minute"] is None


def test_active_jobs_and_viewer_sessions_have_limits(client_factory, take):
    client = client_factory(api_keys=[ADMIN], job_resources={"tenants_no_worker": 1},
                            job_unschedulable_seconds=600)
    _, one = _make_key(client, "one", quota={"active_jobs": 1, "viewer_sessions": 1})
    s = _auth(one)
    assert client.post("/v1/photos/batches", files=[("files", ("a.jpg", noise_jpeg(1), "image/jpeg"))],
                       headers=s).status_code == 202
    second = client.post("/v1/photos/batches", files=[("files", ("b.jpg", noise_jpeg(2), "image/jpeg"))], headers=s)
    assert second.status_code == 429 and second.headers["retry-after"] == "30"
    assert second.json()["error"] == "active_jobs_exceeded"
    rig_id = client.post("/v1/rigs", files={"files": ("rig.json", rig_json(take.rig))}, headers=s).json()["id"]
    url = f"/v1/rigs/{rig_id}/view?render=browser&source=live&access_token={one}"
    with client.websocket_connect(url) as first:
        assert first.receive_json()["type"] == "hello"
        with client.websocket_connect(url) as refused:
            message = refused.receive_json()
            assert message["error"] == "viewer_sessions_exceeded", message
            with pytest.raises(WebSocketDisconnect):
                refused.receive_json()
    deadline = time.monotonic() + 5
    while client.get("/v1/keys/me", headers=s).json()["usage"]["viewer_sessions"] and time.monotonic() < deadline:
        time.sleep(0.05)
    with client.websocket_connect(url) as again:  # the closed one was given back
        assert again.receive_json()["type"] == "hello"


def test_the_access_log_names_the_key_and_never_its_secret(service):
    import asyncio
    import logging

    from app.auth import ApiKeyMiddleware
    from app.logredact import NameTheKey, request_key_name

    client = service
    key_id, secret = _make_key(client, "carol")
    seen = []

    async def inner(scope, receive, send):
        seen.append(request_key_name.get())
        record = logging.LogRecord("uvicorn.access", logging.INFO, "", 0, '%s - "%s %s HTTP/%s" %d',
                                   ("127.0.0.1:5000", "GET", "/v1/jobs", "1.1", 200), None)
        NameTheKey().filter(record)
        seen.append(record.getMessage())

    scope = {"type": "http", "method": "GET", "path": "/v1/jobs", "app": client.app,
             "headers": [(b"authorization", f"Bearer {secret}".encode())]}
    asyncio.run(ApiKeyMiddleware(inner)(scope, None, None))
    assert seen == [f"carol ({key_id})", f'127.0.0.1:5000 key=carol ({key_id}) - "GET /v1/jobs HTTP/1.1" 200']
    assert secret not in seen[1]


def test_a_key_revoked_on_one_replica_fails_at_once_on_another(client_factory):
    first = client_factory(api_keys=[ADMIN])
    second = client_factory(api_keys=[ADMIN])  # the same database: a second API replica
    key_id, secret = _make_key(first, "dave")
    assert second.get("/v1/keys/me", headers=_auth(secret)).json()["name"] == "dave"  # made on the first
    assert first.delete(f"/v1/keys/{key_id}", headers=_auth(ADMIN)).status_code == 204
    assert second.get("/v1/keys/me", headers=_auth(secret)).status_code == 401


def test_the_keys_command_creates_lists_rotates_and_revokes(tmp_path, capsys, monkeypatch):
    from app.cli import main
    from app.jobstore import JobStore
    from app.keys import KeyStore

    monkeypatch.delenv("SWEEPCAST_DATABASE_URL", raising=False)
    data = ["--data-dir", str(tmp_path / "data")]
    assert main(["keys", "create", "--name", "ops", "--role", "admin", "--expires", "30d",
                 "--quota", "active_jobs=3", *data]) == 0
    created = capsys.readouterr().out.splitlines()
    secret = created[-1]
    assert secret.startswith("sck_") and "ops" in created[0] and "admin" in created[0] and "active_jobs=3" in created[0]
    assert main(["keys", "list", *data]) == 0
    assert "ops" in capsys.readouterr().out
    assert main(["keys", "rotate", "ops", *data]) == 0
    rotated = capsys.readouterr().out.splitlines()[-1]
    keys = KeyStore(JobStore(f"sqlite:///{(tmp_path / 'data' / 'sweepcast.db').resolve()}").engine)
    assert keys.lookup(secret) is None and keys.lookup(rotated).name == "ops"
    assert main(["keys", "revoke", "ops", *data]) == 0 and keys.lookup(rotated) is None
    assert main(["keys", "revoke", "nobody", *data]) == 1
    assert "no key with id 'nobody'" in capsys.readouterr().err


def test_frame_sets_are_private_to_caches_once_managed_keys_exist(client_factory, take):
    client = client_factory()  # no SWEEPCAST_API_KEYS: managed keys alone turn authentication on
    _, secret = client.app.state.services.keys.create("gina")
    g = _auth(secret)
    rig_id = client.post("/v1/rigs", files={"files": ("rig.json", rig_json(take.rig))}, headers=g).json()["id"]
    rec = client.post(f"/v1/rigs/{rig_id}/recordings", files={"archive": ("take.zip", zip_bytes(take))},
                      data={"params": '{"fps": 5}'}, headers=g).json()
    client.headers.update(g)
    assert wait_recording(client, rig_id, rec["id"])["state"] == "ready"
    frame = client.get(f"/v1/rigs/{rig_id}/recordings/{rec['id']}/frames/0")
    assert frame.status_code == 200 and frame.headers["cache-control"].startswith("private")
    client.headers.pop("Authorization")
    assert client.get(f"/v1/rigs/{rig_id}/recordings/{rec['id']}/frames/0").status_code == 401
