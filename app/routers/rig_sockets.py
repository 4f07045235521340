"""WebSockets of a rig: viewers (``/v1/rigs/{id}/view``) and live ingest (``/v1/rigs/{id}/live``).

Viewer socket (``?source=<recording id>|live``, default the newest ready recording, else live):
the server sends ``{"type": "hello", ...}`` (cameras, frames, fps, orbit frame, quality levels, and ``controls``: what a
viewer may ask for, :func:`workers.streaming.rules.viewpoint_controls`), then
``{"type": "ready", "session": {...}}`` once the session runs. The client sends viewpoints as JSON
text (:class:`workers.streaming.params.Viewpoint`); the server answers each rendered one with a
binary message (4-byte big-endian header length, JSON header ``{"type": "frame", "id", "frame",
"depth_range", "render_ms", "encode_ms", ...}``, then the JPEG). Latest viewpoint wins: while a
render is in flight only the newest viewpoint waits (``skipped`` counts those replaced). A bad
viewpoint gets ``{"type": "error", "error", "detail", "id"}`` and the socket stays open: so does a
text message over ``MAX_TEXT_CHARS`` characters (``message_too_large``, not parsed at all) or one
that is not JSON or nests too deeply to parse (``bad_json``). A binary message closes it with 1003.

A viewer that renders in its own browser (WebGL2; the viewer page's default where it can) opens the socket
with ``?render=browser`` and sends no viewpoints. Its hello adds ``"render_mode": "browser"``, ``"render"``
(the rig's geometry at every source factor, silhouette settings, overlay colours and the renderer's rules:
:func:`workers.streaming.browser.render_spec`) and
``"target_fps"``; for a recording, ``"frame_sets": {"url": ".../frames/{frame}", "format", "quality"}`` (one
atlas per frame set over HTTP, immutable, cached by the browser: no session is started and nothing more comes
on the socket), for the live stream ``"live": {"background_url", "background_rate"}`` and then every frame set
the live session applies, as the live client sent it (binary: header ``{"type": "frame_set", "seq", "sizes",
"background", "resync", "dropped", "captured", "spread_ms", "stale"}``, then one JPEG per camera;
:mod:`app.live_relay`; a stale camera's image is not of the set's instant and is not to be rendered). Such a
client sends only ``{"type": "ping"}``; a viewpoint gets the error ``client_renders``, a binary message closes with 1003.

A failure costs one viewpoint, never the socket or the session: an exception in the renderer is
answered with ``render_failed``; when the session's process is lost during a render (it restarts
and reloads its frames) the viewpoint gets ``session_restarting`` and is not rendered again (it
may be what crashed it); the next viewpoint is rendered once the session is back.

Live socket: the server sends ``{"type": "hello", "cameras": [...]}``; the client sends frame sets
as binary messages (header ``{"sizes": [...], "cameras"?, "background"?, "seq"?, "captured"?, "stale"?,
"tolerance"?}``, then one JPEG per camera; see :mod:`workers.streaming.framing`). Each applied set is acknowledged
with ``{"type": "ack", "seq", "live_seq", "dropped", "spread_ms", "stale", "captured", ...}``; a bad set gets
``{"type": "error", ..., "seq"}`` and the previous set stays on show: so does a set whose capture times spread over
its tolerance (``spread_over_tolerance``: never rendered as one instant); a set the session failed on gets
``frame_set_failed`` (or ``session_restarting`` when its process was lost meanwhile; the set is not sent again). A text
message other than ``{"type": "ping"}`` (at most ``MAX_TEXT_CHARS`` characters) closes it with 1003.

A socket whose peer stops reading gets no new frame once the connection holds more than a few it has not taken,
and after ``viewer_stall_seconds`` without progress it is closed with 1008 and a reason, logged once, and cut off
when it still reads nothing (:class:`Channel`); and the viewers of a session take turns at its renderer (:mod:`workers.streaming.turns`).

Unknown rigs or recordings, and wrong API keys, close with 1008 and a reason. While the job database cannot be
reached, a recording this process has served opens as before (frames need nothing from the database); another
gets the error ``database_unavailable`` and a close with 1013 (try again later). Either socket keeps
its session alive while open; when the last one goes, the session ends after the idle timeout.
"""
from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import time
import uuid
from typing import Any, Awaitable, Callable, Literal

import ray.exceptions
from fastapi import APIRouter, WebSocket
from pydantic import ValidationError
from starlette.websockets import WebSocketDisconnect

from app.auth import socket_principal
from app.errors import ApiError
from app.jobstore import DATABASE_DOWN, database_unavailable
from app.keys import Principal
from app.live_relay import TIMING_KEYS, LiveSet
from app.socket_transport import abort, queued_bytes
from app.stored_rigs import Source, resolve_source, session_config
from app.services import Services
from workers.common.validation import describe_errors
from workers.streaming.actor import LIVE, SessionClient, SessionInterrupted
from workers.streaming.browser import render_spec
from workers.streaming.framing import FramingError, pack_message, unpack_frame_set
from workers.streaming.params import Viewpoint
from workers.streaming.session import SessionError, SetTiming

log = logging.getLogger("sweepcast.rigs")
ws_router = APIRouter(prefix="/v1/rigs", tags=["rigs"])

UNSUPPORTED_DATA = 1003
POLICY_VIOLATION = 1008
INTERNAL_ERROR = 1011
TRY_AGAIN_LATER = 1013
QUEUED_LIMIT = 16 * 1024
"""Bytes a socket may hold that its peer has not acknowledged before its next frame is made: a viewer's closed
loop (next viewpoint after each frame) finds the queue empty, a slow link gets its frames as fast as it takes
them (not a backlog of stale ones), and one that stopped reading gets a frame or two more (what its own
receive buffer holds)."""
CLOSE_GRACE_S = 2.0
"""How long a stalled socket's close frame may wait for room before the connection is cut off."""
MAX_TEXT_CHARS = 8192
"""Longest text message parsed: a viewpoint or a ping is a few hundred characters. The cap also
bounds the work of a hostile message before json.loads sees it."""


class BadMessage(ValueError):
    """A client's text message that cannot be read: ``code`` and ``detail`` go back in an error."""

    def __init__(self, code: str, detail: str) -> None:
        super().__init__(detail)
        self.code = code
        self.detail = detail


def parse_text(text: str) -> Any:
    """The JSON value of a client text message; BadMessage when too long, not JSON or nested too
    deeply for the parser (json.loads raises RecursionError there, which would end the handler)."""
    if len(text) > MAX_TEXT_CHARS:
        raise BadMessage("message_too_large", f"a text message is at most {MAX_TEXT_CHARS} characters; "
                                              f"got {len(text)}")
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise BadMessage("bad_json", f"not JSON: {exc}") from None
    except RecursionError:
        raise BadMessage("bad_json", "not usable JSON: nested too deeply") from None


class Channel:
    """One socket's sends, serialised (frames and errors come from different tasks). A send to a peer that has
    gone (it closed before the hello, or mid-stream) marks the channel closed instead of raising: the reader
    sees the disconnect and ends the socket quietly, with no traceback in the log.

    A peer that stops reading is noticed two ways. Before its worker makes the next frame it waits in
    :meth:`taken` until the connection holds at most :data:`QUEUED_LIMIT` bytes the peer has not acknowledged
    (:func:`app.socket_transport.queued_bytes`): a viewer's frames are not rendered faster than it takes them, and
    one that takes nothing gets none (a server-rendering viewer's newest viewpoint waits; a browser-rendering live
    viewer keeps only the newest set). And no send waits more than ``stall_seconds``. When either waits
    ``stall_seconds``, the socket ends: one log line, a close with 1008 and the reason (sent if
    the peer makes room for it within :data:`CLOSE_GRACE_S`), else the connection is cut off."""

    def __init__(self, websocket: WebSocket, stall_seconds: float | None = None, label: str = "socket") -> None:
        self.ws = websocket
        self.stall_seconds = stall_seconds
        self.label = label
        self._lock = asyncio.Lock()
        self.closed = False

    async def taken(self) -> bool:
        """Wait until the peer has taken all but :data:`QUEUED_LIMIT` bytes of what was sent (at once where that
        cannot be known); False when the socket is closed, or was now closed for not getting there within
        ``stall_seconds`` (a peer that reads a trickle is no better: a kernel that merely compacts its receive
        buffer also takes a few bytes now and then)."""
        queued = queued_bytes(self.ws.scope)
        if queued is None or queued <= QUEUED_LIMIT or self.stall_seconds is None:
            return not self.closed
        deadline, pause = time.monotonic() + self.stall_seconds, 0.005
        while not self.closed:
            await asyncio.sleep(pause)
            now = queued_bytes(self.ws.scope)
            if now is None or now <= QUEUED_LIMIT:
                return not self.closed
            pause = min(pause * 2, 0.1)
            if time.monotonic() > deadline:
                async with self._lock:
                    if not self.closed:
                        self.closed = True
                        await self._cut_off()
        return False

    async def json(self, message: dict[str, Any]) -> None:
        await self._send(lambda: self.ws.send_text(json.dumps(message)))

    async def binary(self, data: bytes) -> None:
        await self._send(lambda: self.ws.send_bytes(data))

    async def error(self, code: str, detail: str, **extra: Any) -> None:
        await self.json({"type": "error", "error": code, "detail": detail, **extra})

    async def close(self, code: int, reason: str) -> None:
        await self._send(lambda: self.ws.close(code=code, reason=reason[:120]), closing=True)

    async def _send(self, send: Callable[[], Awaitable[None]], closing: bool = False) -> None:
        async with self._lock:
            if self.closed:
                return
            self.closed = closing
            try:
                await asyncio.wait_for(send(), self.stall_seconds)
            except WebSocketDisconnect:
                self.closed = True
            except asyncio.TimeoutError:  # nothing was written: the server writes a message whole once there is room
                self.closed = True
                await self._cut_off()

    async def _cut_off(self) -> None:
        """Log the stall once, close with 1008 and the reason, and cut the connection off unless the peer takes
        everything (the close frame comes last) within :data:`CLOSE_GRACE_S`."""
        client = self.ws.client
        reason = f"stopped reading: nothing taken for {self.stall_seconds:g} s"
        log.warning("%s from %s %s; closing it", self.label, f"{client.host}:{client.port}" if client else "?", reason)
        deadline = time.monotonic() + CLOSE_GRACE_S
        with contextlib.suppress(asyncio.TimeoutError, WebSocketDisconnect, RuntimeError):
            await asyncio.wait_for(self.ws.close(code=POLICY_VIOLATION, reason=reason), CLOSE_GRACE_S)
        while (queued_bytes(self.ws.scope) or 0) > 0 and time.monotonic() < deadline:
            await asyncio.sleep(0.05)
        if (queued_bytes(self.ws.scope) or 0) > 0:
            abort(self.ws.scope)


class Latest:
    """A one-slot mailbox: a new item replaces one not taken yet (latest wins)."""

    def __init__(self) -> None:
        self._item: Any = None
        self._ready = asyncio.Event()
        self.replaced = 0

    def put(self, item: Any) -> None:
        if self._item is not None:
            self.replaced += 1
        self._item = item
        self._ready.set()

    async def take(self) -> Any:
        await self._ready.wait()
        self._ready.clear()
        item, self._item = self._item, None
        return item


async def _open(websocket: WebSocket, rig_id: str, source: str | None, label: str,
                change: bool = False) -> tuple[Channel, Source, Principal] | None:
    """Check the key, accept, resolve the rig and source the key may see (``change``: may change); None (socket
    closed) when refused. ``label`` names the socket in the log."""
    who = await socket_principal(websocket)
    if who is None:
        await websocket.close(code=POLICY_VIOLATION, reason="missing or wrong API key")
        return None
    await websocket.accept()
    svc: Services = websocket.app.state.services
    channel = Channel(websocket, svc.settings.viewer_stall_seconds, label)
    try:
        target = await resolve_source(svc, rig_id, source, who, change)
    except ApiError as exc:
        await channel.error(exc.code, str(exc.detail))
        await channel.close(POLICY_VIOLATION, str(exc.detail))
        return None
    except Exception as exc:
        if not database_unavailable(exc):
            raise
        await channel.error("database_unavailable", DATABASE_DOWN)
        await channel.close(TRY_AGAIN_LATER, "the job database cannot be reached just now: reconnect in a few seconds")
        return None
    return channel, target, who


async def _serve(websocket: WebSocket, channel: Channel, client: SessionClient, viewer: str | None,
                 reader: Callable[[], Awaitable[None]], worker: Callable[[], Awaitable[None]]) -> None:
    """Run a socket's reader with its worker and a heartbeat (for ``viewer``, or None for a live
    client); tidy up when the reader ends."""
    svc: Services = websocket.app.state.services
    interval = min(max(svc.settings.session_idle_seconds / 3, 0.2), 10.0)

    async def heartbeat() -> None:
        while True:
            await asyncio.sleep(interval)
            try:
                await client.touch(viewer)
            except ray.exceptions.RayError as exc:
                log.warning("session heartbeat failed: %s", exc)

    async def guarded() -> None:
        try:
            await worker()
        except asyncio.CancelledError:
            raise
        except Exception:  # noqa: BLE001 - a bug must close the socket, not leave it silent
            log.exception("a rig socket's worker failed")
            await channel.error("internal_error", "the server failed on this socket")
            await channel.close(INTERNAL_ERROR, "internal error")

    tasks = [asyncio.create_task(guarded()), asyncio.create_task(heartbeat())]
    try:
        await reader()
    except WebSocketDisconnect:
        pass
    except Exception:  # noqa: BLE001 - as in guarded(): close with a code, never drop the connection
        log.exception("a rig socket's reader failed")
        with contextlib.suppress(Exception):  # the socket itself may be what failed
            await channel.error("internal_error", "the server failed on this socket")
            await channel.close(INTERNAL_ERROR, "internal error")
    finally:
        channel.closed = True
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        if viewer is not None:
            await client.leave(viewer)


# --- viewers --------------------------------------------------------------------------------------
@ws_router.websocket("/{rig_id}/view")
async def view_socket(websocket: WebSocket, rig_id: str, source: str | None = None,
                      render: Literal["server", "browser"] = "server") -> None:
    """Viewpoints in (JSON text), JPEG frames out (binary: header + JPEG); with ``render=browser``, what the
    browser needs to render itself. See the module docstring."""
    opened = await _open(websocket, rig_id, source, "viewer socket" if render == "server" else "browser viewer socket")
    if opened is None:
        return
    channel, target, who = opened
    svc: Services = websocket.app.state.services
    refused = svc.quotas.open_viewer(who)
    if refused is not None:
        await channel.error(refused.code, str(refused.detail))
        await channel.close(POLICY_VIOLATION, "too many viewer sessions")
        return
    try:
        await _viewer(websocket, channel, target, svc, render)
    finally:
        svc.quotas.close_viewer(who)


async def _viewer(websocket: WebSocket, channel: Channel, target: Source, svc: Services,
                  render: Literal["server", "browser"]) -> None:
    rig_id = target.rig_id
    if render == "browser":
        await _browser_viewer(websocket, channel, target, svc)
        return
    client = SessionClient(session_config(svc, rig_id, target.source), svc.settings.session_resources)
    viewer = uuid.uuid4().hex
    mailbox = Latest()
    await channel.json({**target.hello(), "viewer": viewer, "limits": {
        "max_pixels": svc.settings.max_view_pixels, "max_planes": svc.settings.max_view_planes}})

    async def read() -> None:
        while True:
            message = await websocket.receive()
            if message["type"] == "websocket.disconnect":
                return
            if message.get("text") is None:
                await channel.close(UNSUPPORTED_DATA, "viewpoints are JSON text messages")
                return
            vp = await _viewpoint(channel, message["text"])
            if vp is not None:
                mailbox.put(vp)

    async def send_views() -> None:
        try:
            info = await client.info()
        except ray.exceptions.RayError as exc:
            await channel.error("session_failed", f"the session could not start: {_cause(exc)}")
            await channel.close(INTERNAL_ERROR, "the session could not start")
            return
        await channel.json({"type": "ready", "session": info})
        while await channel.taken():  # no frame is made for a viewer that does not take them
            vp: Viewpoint = await mailbox.take()
            t0 = time.perf_counter()
            try:
                header, jpeg = await client.view(viewer, vp)
            except SessionInterrupted as exc:
                await channel.error("session_restarting", str(exc), id=vp.id)
                continue
            except SessionError as exc:
                await channel.error(exc.code, exc.detail, id=vp.id)
                continue
            except ray.exceptions.RayError as exc:
                await channel.error("session_failed", f"the render failed: {_cause(exc)}", id=vp.id)
                continue
            header = {**header, "skipped": mailbox.replaced,
                      "round_trip_ms": round((time.perf_counter() - t0) * 1e3, 2)}
            await channel.binary(pack_message(header, [jpeg]))

    await _serve(websocket, channel, client, viewer, read, send_views)


async def _browser_viewer(websocket: WebSocket, channel: Channel, target: Source, svc: Services) -> None:
    """A viewer that renders in its browser: one hello with the rig's geometry and where its frame sets are
    (a recording's: immutable HTTP URLs; the live stream's: pushed on this socket, see :mod:`app.live_relay`),
    then only pings. No session is started for a recording: such a viewer costs the server its downloads."""
    hello = {**target.hello(), "render_mode": "browser", "render": render_spec(target.rig),
             "target_fps": svc.settings.viewer_target_fps}
    if target.recording is not None:
        hello["frame_sets"] = {"url": f"/v1/rigs/{target.rig_id}/recordings/{target.source}/frames/{{frame}}",
                           "format": svc.settings.viewer_frame_format, "quality": svc.settings.viewer_frame_quality}
    else:
        hello["live"] = {"background_url": f"/v1/rigs/{target.rig_id}/live/background",
                         "background_rate": session_config(svc, target.rig_id, LIVE).bg_rate}
    await channel.json(hello)
    if target.recording is None:
        await _browser_live(websocket, channel, target, svc)
        return
    await channel.json({"type": "ready", "session": None})
    try:
        while True:
            message = await websocket.receive()
            if message["type"] == "websocket.disconnect":
                return
            if not await _browser_message(channel, message):
                return
    except WebSocketDisconnect:
        return


async def _browser_live(websocket: WebSocket, channel: Channel, target: Source, svc: Services) -> None:
    """The live stream for a browser-rendering viewer: every frame set the live session applies, as the live
    client sent it (binary: header ``{"type": "frame_set", "seq", "sizes", "background", "resync", "dropped",
    "captured", "spread_ms", "stale"}``, then one JPEG per camera in rig order). ``resync``: a background set was
    skipped, fetch the model again; ``stale``: cameras whose image is not of this instant."""
    config = session_config(svc, target.rig_id, LIVE)
    client = SessionClient(config, svc.settings.session_resources)
    viewer = uuid.uuid4().hex
    sub = svc.live_relay.subscribe(target.rig_id, lambda: SessionClient(config, svc.settings.session_resources))

    async def read() -> None:
        while True:
            message = await websocket.receive()
            if message["type"] == "websocket.disconnect" or not await _browser_message(channel, message):
                return

    async def send() -> None:
        await channel.json({"type": "ready", "session": None})
        while await channel.taken():  # meanwhile only the newest set waits in the mailbox
            item, resync = await sub.take()
            header = {"type": "frame_set", "seq": item.seq, "sizes": [len(j) for j in item.jpegs],
                      "background": item.background, "resync": resync, "dropped": sub.dropped, **item.timing}
            await channel.binary(pack_message(header, item.jpegs))

    try:
        await _serve(websocket, channel, client, viewer, read, send)
    finally:
        await svc.live_relay.unsubscribe(sub)


async def _browser_message(channel: Channel, message: dict[str, Any]) -> bool:
    """Answer a browser-rendering viewer's message (a ping, or an error for anything else); False when the
    socket was closed for it."""
    if message.get("text") is None:
        await channel.close(UNSUPPORTED_DATA, "a browser-rendering viewer sends only JSON text pings")
        return False
    if _is_ping(message["text"]):
        await channel.json({"type": "pong"})
    else:
        await channel.error("client_renders", "this socket was opened with render=browser: the browser renders "
                                              "every view itself and sends no viewpoints (open it without "
                                              "render=browser to have the server render)")
    return True


async def _viewpoint(channel: Channel, text: str) -> Viewpoint | None:
    """The viewpoint in a text message, or None after answering with an error (or a pong)."""
    try:
        data = parse_text(text)
    except BadMessage as exc:
        await channel.error(exc.code, exc.detail)
        return None
    if not isinstance(data, dict):
        await channel.error("bad_viewpoint", "a viewpoint is a JSON object")
        return None
    msg_id = data.get("id") if isinstance(data.get("id"), int) else None
    if data.get("type") == "ping":
        await channel.json({"type": "pong", "id": msg_id})
        return None
    try:  # the one validation of a viewpoint; its limits are the session's check (Session.prepare)
        return Viewpoint.model_validate(data)
    except ValidationError as exc:
        await channel.error("bad_viewpoint", describe_errors(exc, "viewpoint"), id=msg_id)
        return None


# --- live ingest ----------------------------------------------------------------------------------
@ws_router.websocket("/{rig_id}/live")
async def live_socket(websocket: WebSocket, rig_id: str) -> None:
    """Synchronised frame sets in (binary: header + one JPEG per camera), acks out; see the module docstring."""
    opened = await _open(websocket, rig_id, LIVE, "live socket", change=True)
    if opened is None:
        return
    channel, target, _ = opened
    svc: Services = websocket.app.state.services
    client = SessionClient(session_config(svc, rig_id, LIVE), svc.settings.session_resources)
    names = target.rig.names
    mailbox = Latest()
    await channel.json({**target.hello(), "frame_set": "4-byte big-endian header length, JSON header "
                                                      "{\"sizes\": [...], \"captured\"?: [...], \"stale\"?: [...], "
                                                      "\"tolerance\"?: s}, then one JPEG per camera"})

    async def read() -> None:
        while True:
            message = await websocket.receive()
            if message["type"] == "websocket.disconnect":
                return
            if message.get("bytes") is None:
                if _is_ping(message.get("text")):
                    await channel.json({"type": "pong"})
                    continue
                await channel.close(UNSUPPORTED_DATA, "frame sets are binary messages")
                return
            try:
                mailbox.put(unpack_frame_set(message["bytes"], names))
            except FramingError as exc:
                await channel.error("bad_frame_set", str(exc))

    async def push() -> None:
        while True:
            frame_set = await mailbox.take()
            timing = SetTiming(tuple(frame_set.captured) if frame_set.captured is not None else None,
                               tuple(frame_set.stale) if any(frame_set.stale) else (), frame_set.tolerance)
            try:
                reply = await client.push(frame_set.jpegs, frame_set.background, timing)
            except SessionInterrupted as exc:
                await channel.error("session_restarting", str(exc), seq=frame_set.seq)
                continue
            except SessionError as exc:
                await channel.error(exc.code, exc.detail, seq=frame_set.seq)
                continue
            except ray.exceptions.RayError as exc:
                await channel.error("session_failed", f"the frame set was not applied: {_cause(exc)}",
                                    seq=frame_set.seq)
                continue
            live_seq = reply.pop("seq")
            svc.live_relay.publish(rig_id, LiveSet(live_seq, frame_set.jpegs, frame_set.background,
                                                   {k: reply.get(k) for k in TIMING_KEYS}))
            await channel.json({"type": "ack", "seq": frame_set.seq, "live_seq": live_seq,
                                "dropped": mailbox.replaced, **reply})

    await _serve(websocket, channel, client, None, read, push)


def _is_ping(text: str | None) -> bool:
    if text is None:
        return False
    with contextlib.suppress(BadMessage):
        data = parse_text(text)
        return isinstance(data, dict) and data.get("type") == "ping"
    return False


def _cause(exc: Exception) -> str:
    return str(exc).strip().splitlines()[0][:300] if str(exc).strip() else type(exc).__name__
