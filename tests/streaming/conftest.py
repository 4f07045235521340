"""Fixtures of the streaming tests: a small procedural take, apps with short session timeouts."""
from __future__ import annotations

import time

import pytest

from harness.takes import Take, make_take, rig_json, zip_bytes

IDLE_S = 2.0


@pytest.fixture(scope="session")
def take() -> Take:
    return make_take()


@pytest.fixture
def stream_client(client_factory):
    """An app (without the demo rig, as every test app) whose sessions end after IDLE_S idle seconds."""
    return client_factory(session_idle_seconds=IDLE_S)


def add_rig(client, take: Take, name: str = "test rig") -> str:
    r = client.post("/v1/rigs", files={"files": ("rig.json", rig_json(take.rig))}, data={"name": name})
    assert r.status_code == 201, r.text
    return r.json()["id"]


def wait_recording(client, rig_id: str, recording_id: str, timeout: float = 120.0) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        rec = client.get(f"/v1/rigs/{rig_id}/recordings/{recording_id}").json()
        if rec["state"] != "processing":
            return rec
        time.sleep(0.05)
    raise AssertionError(f"recording {recording_id} still processing")


def add_recording(client, rig_id: str, take: Take) -> str:
    r = client.post(f"/v1/rigs/{rig_id}/recordings", files={"archive": ("take.zip", zip_bytes(take))},
                    data={"params": '{"fps": 5}'})
    assert r.status_code == 202, r.text
    rec = wait_recording(client, rig_id, r.json()["id"])
    assert rec["state"] == "ready", rec
    return rec["id"]


def wait_until(predicate, timeout: float = 30.0, step: float = 0.1) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(step)
    return predicate()
