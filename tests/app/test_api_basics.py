"""The service skeleton: health, auth, errors, body limits, the committed OpenAPI document."""
import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def test_health_ready_and_front_page(client_factory):
    client = client_factory()
    assert client.get("/healthz").json() == {"status": "ok"}
    ready = client.get("/readyz")
    assert ready.status_code == 200
    assert ready.json()["checks"]["database"]["ok"] and ready.json()["checks"]["ray"]["ok"]
    assert "/docs" in client.get("/").text


def test_unknown_job_is_a_json_404(client_factory):
    client = client_factory()
    r = client.get("/v1/jobs/not-a-job")
    assert r.status_code == 404
    assert r.json() == {"error": "job_not_found", "detail": "no job with id 'not-a-job'"}
    assert client.get("/v1/jobs").json()["jobs"] == []


def test_bad_query_is_a_422_naming_the_field(client_factory):
    r = client_factory().get("/v1/jobs", params={"limit": 0})
    assert r.status_code == 422
    assert r.json()["error"] == "invalid_request" and "limit" in r.json()["detail"]


def test_api_keys_guard_every_v1_route_and_socket(client_factory):
    client = client_factory(api_keys=["s3cret", "other"])
    assert client.get("/healthz").status_code == 200  # probes stay open
    r = client.get("/v1/jobs")
    assert r.status_code == 401 and r.json()["error"] == "unauthorized"
    assert client.get("/v1/jobs", headers={"Authorization": "Bearer wrong"}).status_code == 401
    assert client.get("/v1/jobs", headers={"Authorization": "Bearer other"}).status_code == 200
    r = client.post("/v1/photos/orientation", files={"file": ("a.jpg", b"x")})
    assert r.status_code == 401
    from starlette.websockets import WebSocketDisconnect

    with pytest.raises(WebSocketDisconnect) as closed:
        with client.websocket_connect("/v1/jobs/abc/events") as ws:
            ws.receive_json()
    assert closed.value.code == 1008
    with client.websocket_connect("/v1/jobs/abc/events?access_token=s3cret") as ws:
        assert ws.receive_json()["type"] == "error"  # authorised; the job just does not exist


def test_declared_body_over_the_limit_is_refused_before_reading(client_factory):
    client = client_factory(max_upload_bytes=1000)
    r = client.post("/v1/photos/orientation", files={"file": ("big.jpg", b"\xff" * 5000)})
    assert r.status_code == 413
    assert r.json()["error"] == "payload_too_large" and "1000" in r.json()["detail"]


def test_streamed_body_over_the_limit_is_cut_off(client_factory):
    client = client_factory(max_upload_bytes=1000)

    def body():
        for _ in range(50):
            yield b"\x00" * 100

    r = client.post("/v1/photos/orientation", content=body(),
                    headers={"content-type": "multipart/form-data; boundary=xyz"})
    assert r.status_code == 413 and r.json()["error"] == "payload_too_large"


def test_committed_openapi_matches_the_app():
    from app.main import render_openapi

    committed = ROOT / "openapi" / "openapi.json"
    assert committed.exists(), "openapi/openapi.json is missing: run 'sweepcast openapi'"
    assert json.loads(committed.read_text()) == json.loads(render_openapi()), (
        "openapi/openapi.json differs from the app's schema: run 'sweepcast openapi' and commit it"
    )


def test_serve_refuses_a_public_host_without_keys(capsys, monkeypatch):
    from app.cli import main

    monkeypatch.delenv("SWEEPCAST_API_KEYS", raising=False)
    assert main(["serve", "--host", "0.0.0.0"]) == 2
    assert "--insecure" in capsys.readouterr().err


def test_serve_logs_the_services_own_messages_at_the_chosen_level(capsys):
    """Without a handler Python drops the service's INFO lines (Ray's start, the demo, the kernels)."""
    import logging

    from app.cli import _log_to_stderr

    logger = logging.getLogger("sweepcast")
    before = list(logger.handlers), logger.level, logger.propagate
    try:
        _log_to_stderr("info")
        logging.getLogger("sweepcast.demo").info("demo session warm")
        logging.getLogger("sweepcast.demo").debug("not shown at info")
        err = capsys.readouterr().err
        assert "INFO sweepcast.demo: demo session warm" in err and "not shown" not in err
    finally:
        logger.handlers[:], logger.propagate = before[0], before[2]
        logger.setLevel(before[1])
