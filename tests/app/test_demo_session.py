"""The demo session is started ahead of its first viewer: once the recording is ready it is created, renders the
view the browser viewer asks for first, and is touched so that it never idles out."""
from __future__ import annotations

import asyncio
from types import SimpleNamespace

from app import demo_session
from app.settings import Settings


class FakeClient:
    calls: list = []

    def __init__(self, config, resources):
        self.config = config

    async def info(self):
        FakeClient.calls.append(("info", ()))
        return {}

    async def view(self, viewer, viewpoint):
        FakeClient.calls.append(("view", (viewer, viewpoint)))
        return {"render_ms": 5.0}, b"jpeg"

    async def leave(self, viewer):
        FakeClient.calls.append(("leave", (viewer,)))

    async def touch(self, viewer=None):
        FakeClient.calls.append(("touch", (viewer,)))
        if sum(m == "touch" for m, _ in FakeClient.calls) >= 2:
            raise asyncio.CancelledError  # the service stops


def test_the_demo_session_is_started_rendered_and_kept_warm(tmp_path, monkeypatch):
    settings = Settings(data_dir=tmp_path, viewer_size="400x300", session_idle_seconds=0.3)
    ready = asyncio.Event()
    svc = SimpleNamespace(settings=settings, store=SimpleNamespace(url="file:///nowhere"),
                          dispatcher=SimpleNamespace(ray_ready=ready))
    answers = iter([None, None, ("rig1", "rec1")])  # the recording is being rendered, then ready

    async def recording(_svc):
        return next(answers)

    FakeClient.calls = []
    monkeypatch.setattr(demo_session, "demo_recording", recording)
    monkeypatch.setattr(demo_session, "SessionClient", FakeClient)
    monkeypatch.setattr(demo_session, "POLL_SECONDS", 0.01)

    async def run():
        task = asyncio.create_task(demo_session.keep_demo_session_warm(svc))
        await asyncio.sleep(0.05)
        assert FakeClient.calls == []  # nothing before Ray is up
        ready.set()
        try:
            await asyncio.wait_for(task, 5)
        except asyncio.CancelledError:
            pass

    asyncio.run(run())
    methods = [m for m, _ in FakeClient.calls]
    assert methods[:3] == ["info", "view", "leave"] and methods[3:] == ["touch", "touch"]
    viewer, view = FakeClient.calls[1][1]
    assert viewer == demo_session.PRESTART_VIEWER and (view.width, view.height) == (400, 300)


def test_nothing_happens_without_the_demo(tmp_path, monkeypatch):
    FakeClient.calls = []
    monkeypatch.setattr(demo_session, "SessionClient", FakeClient)
    svc = SimpleNamespace(settings=Settings(data_dir=tmp_path, demo_rig=False))
    asyncio.run(demo_session.keep_demo_session_warm(svc))
    assert FakeClient.calls == []
