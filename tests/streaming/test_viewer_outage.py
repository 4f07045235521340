"""A viewer while the job database is down: frames need nothing from it, so a recording this replica has served keeps
opening, and its route shows it (the compose stack's chaos run saw every viewer socket end during a database outage);
any other closes with 1013 (try again later) and says why, never an abnormal close."""
import json

import pytest
from starlette.websockets import WebSocketDisconnect

from harness.servers import create_database
from tests.streaming.conftest import IDLE_S, add_recording, add_rig
from tests.streaming.test_sockets import VIEW, receive, until

KEY = "viewer-outage-key"
AUTH = {"Authorization": f"Bearer {KEY}"}


def test_a_viewer_connects_through_a_database_outage_to_a_recording_its_replica_served(client_factory, take,
                                                                                         stoppable_postgres):
    client = client_factory(database_url=create_database(stoppable_postgres.url, "viewer_outage"), api_keys=[KEY],
                            session_idle_seconds=IDLE_S)
    client.headers.update(AUTH)  # the service's own key, as the compose stack's clients use: checked without the database
    rig_id = add_rig(client, take)
    served, other = add_recording(client, rig_id, take), add_recording(client, rig_id, take)
    kept = client.app.state.services.finished_imports
    del kept[other]  # as on a replica that never served it

    stoppable_postgres.stop()
    try:
        shown = client.get(f"/v1/rigs/{rig_id}/recordings/{served}")
        assert shown.status_code == 200 and shown.json()["state"] == "ready", shown.text
        assert client.get(f"/v1/rigs/{rig_id}/recordings/{other}").status_code == 503
        with client.websocket_connect(f"/v1/rigs/{rig_id}/view?source={served}", headers=AUTH) as ws:
            hello, _, _ = until(ws, "hello")
            assert hello["source"] == served and hello["frames"] == 3
            until(ws, "ready")
            ws.send_text(json.dumps({"id": 1, "orbit": {"azimuth": 5.0}, "frame": 1, **VIEW}))
            header, jpeg, _ = until(ws, "frame")
            assert header["id"] == 1 and jpeg[:2] == b"\xff\xd8"
        with client.websocket_connect(f"/v1/rigs/{rig_id}/view?source={other}", headers=AUTH) as ws:
            error, _, _ = until(ws, "error")
            assert error["error"] == "database_unavailable" and "retry" in error["detail"]
            with pytest.raises(WebSocketDisconnect) as closed:
                receive(ws)
        assert closed.value.code == 1013
    finally:
        stoppable_postgres.start()
    with client.websocket_connect(f"/v1/rigs/{rig_id}/view?source={other}", headers=AUTH) as ws:  # back: kept again
        until(ws, "ready")
    assert other in kept
