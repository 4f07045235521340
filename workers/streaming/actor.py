"""The session actor: one Ray actor per (rig, source) holds a live :class:`Session`.

The first viewer creates it (a named, detached actor: every API process finds the same one), the
others share it, and it ends itself after ``idle_seconds`` without any call (sockets send a
``touch`` while they are open, so only a vanished client lets it idle out). A crashed actor is
restarted by Ray (``max_restarts``) and reloads its calibration and frames from the blob store.
Viewers take turns at the renderer (:class:`~workers.streaming.turns.RenderTurns`): at most
``render_slots`` views are drawn at once, the others wait in arrival order, one place per viewer (the API
keeps only a viewer's latest viewpoint and sends it when the previous view came back), so the viewers of a
session are served round robin and a viewer that leaves has its waiting request dropped undrawn. Views
drawn at once share the cores (:func:`_render_threads`; numba's kernels release the GIL); preparing a
view and changing frames run alone (:class:`FrameLock`).

Failures cost one request, never the session: an exception in a render (or in applying a live
frame set) is caught here and answered as an error for that request alone. A process crash during
a render or push (the actor restarts) is reported to the caller as :class:`SessionInterrupted`,
and that request is never sent again: a viewpoint that crashes the renderer would otherwise crash
every restart in turn until none were left.

Only ids, viewpoints and JPEG bytes cross the process boundary: a recording's frames are read from
the blob store by the actor, and a live frame set is sent to it once.
"""
from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import random
import threading
import time
import warnings
from dataclasses import dataclass, field
from typing import Any, Callable, Iterator

import numba
import ray
import ray.exceptions
from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

from workers.common.images import encode_png
from workers.storage import open_store

from .images import decode_stored
from .params import Viewpoint
from .recording import RecordingArchive
from .session import LiveSession, RecordingSession, Session, SessionError, SessionLimits, SetTiming
from .store import archive_key, load_live, load_rig, save_live
from .turns import RenderTurns

log = logging.getLogger("sweepcast.session")

NAMESPACE = "sweepcast"
NAME_PREFIX = "session/"
LIVE = "live"
MAX_RESTARTS = 3


@dataclass(frozen=True)
class SessionConfig:
    """Everything an actor needs to (re)build its session: store, rig, source ("live" or a
    recording id), idle timeout (s), limits, live persistence interval (s), background rate and how many
    views are drawn at once (the others wait their turn)."""

    store_url: str
    rig_id: str
    source: str
    idle_seconds: float = 60.0
    limits: SessionLimits = field(default_factory=SessionLimits)
    persist_seconds: float = 1.0
    bg_rate: float = 0.02
    render_slots: int = 1

    @property
    def name(self) -> str:
        return actor_name(self.rig_id, self.source)


def actor_name(rig_id: str, source: str) -> str:
    return f"{NAME_PREFIX}{rig_id}/{source}"


class SessionInterrupted(Exception):
    """The session actor's process was lost while it handled this request (it restarts, or a new
    one is made on the next call); the request was not served and is not sent again."""


# The calls made for every frame and frame set (several a second per viewer) leave no task event in Ray's GCS:
# it keeps up to 100,000 of them (20,000 calls: +68 MB against +1 MB untracked), and with 4 viewers and a live
# source the GCS server grew 88 -> 229 MB in an hour (benchmarks/soak.py).
_untracked = ray.method(enable_task_events=False)


class SessionHost:
    """The body of the session actor around a :class:`Session` (see the module docstring);
    :data:`SessionActor` is its Ray actor class."""

    def __init__(self, config: SessionConfig) -> None:
        ctx = ray.get_runtime_context()
        self.config = config
        self.node = {"node_id": ctx.get_node_id(), "node_ip": ray.util.get_node_ip_address()}
        """Where the session runs (``GET /v1/sessions``: which worker an operator looks at for a slow viewer)."""
        with warnings.catch_warnings():  # Ray reads its own deprecated actor_id property here
            warnings.simplefilter("ignore", DeprecationWarning)
            self.restarted = ctx.was_current_actor_reconstructed
        self.store = open_store(config.store_url)
        self.session = self._load()
        self._frames = FrameLock()
        self.turns = RenderTurns(config.render_slots)
        self._last = time.monotonic()
        self._busy = 0
        self._viewers: dict[str, float] = {}
        self._persisted = 0.0
        self._persist_lock = threading.Lock()
        self.persisted_seq = self.session.seq
        self.failures = 0
        """Renders and pushes that raised unexpectedly (each answered with an error) since (re)start."""
        self._me = ctx.current_actor
        threading.Thread(target=self._watch, name="idle-watch", daemon=True).start()

    def _load(self) -> Session:
        rig = load_rig(self.store, self.config.rig_id)
        if self.config.source == LIVE:
            session = LiveSession(rig, self.config.limits, self.config.bg_rate)
            seq, jpegs, pngs, stale = load_live(self.store, self.config.rig_id, len(rig))
            # stored at the size the session worked at (at most the camera's); resampled to today's
            backgrounds = [decode_stored(p, (c.width, c.height)) for c, p in zip(rig.cameras, pngs)]
            session.restore(seq, jpegs, backgrounds, stale)
            return session
        archive = RecordingArchive(self.store.local_path(archive_key(self.config.source)))
        return RecordingSession(rig, archive, self.config.limits)

    # --- calls ------------------------------------------------------------------------------------
    @_untracked
    def view(self, viewer: str, vp: Viewpoint) -> tuple[dict[str, Any], bytes]:
        """The frame header and JPEG of ``vp`` (validated by the socket; its limits are the session's check);
        SessionError (a ViewError for what the client sent) when it cannot be served."""
        self._touch(viewer)
        t0 = time.perf_counter()
        with self._working(locked=False), self.turns.turn(viewer) as turn:
            waited = time.perf_counter() - t0
            self._frames.acquire_write()
            drawing = False
            try:
                plan = self.session.prepare(viewer, vp)
                self._frames.downgrade()  # other viewers draw beside this one; frame changes wait
                drawing = True
                with _render_threads(self._frames.readers):
                    header, jpeg = self.session.draw(viewer, plan)
            except SessionError:
                raise
            except Exception as exc:  # noqa: BLE001 - a renderer bug costs this view, not the session
                log.exception("render of viewpoint %s for viewer %s failed", vp.id, viewer)
                self.failures += 1
                if drawing:  # discarding changes the session: alone
                    self._frames.release_read()
                    self._frames.acquire_write()
                self.session.discard_after_failure(viewer)
                self._frames.release_write()
                raise SessionError("render_failed", f"the renderer failed on this viewpoint ({_summary(exc)}); "
                                                    "the session goes on") from None
            finally:
                if self._frames.holds_current():
                    self._frames.release_current()
        header["session_ms"] = round((time.perf_counter() - t0) * 1e3, 2)
        header["turn"], header["turn_wait_ms"] = turn, round(waited * 1e3, 2)
        return header, jpeg

    @_untracked
    def push(self, jpegs: list[bytes], background: bool = False, timing: SetTiming = SetTiming()) -> dict[str, Any]:
        """Apply a live frame set (JPEGs in rig order; ``timing``: when its frames were taken, which are stale): its
        ack (``seq``, timings, the set's spread, ...); SessionError when the set cannot be applied (its spread over
        the tolerance, a bad image: the previous set stays shown).
        The set is decoded before the render lock is taken (OpenCV releases the GIL), so a decode
        runs beside a render instead of delaying it."""
        self._touch(None)
        session = self.session
        if not isinstance(session, LiveSession):
            raise SessionError("not_live", "this session shows a recording")
        session.check_timing(timing, background)  # before any decoding: a set that cannot be shown costs nothing
        with self._working(locked=False):
            t0 = time.perf_counter()
            images = session.decode(jpegs, timing=timing)
        t1 = time.perf_counter()
        with self._working():
            t2 = time.perf_counter()
            try:
                session.apply(images, jpegs, background, timing)
                ack = session.ack((t1 - t0) * 1e3, (time.perf_counter() - t2) * 1e3, background)
            except SessionError:
                raise
            except Exception as exc:  # noqa: BLE001 - as in view: this set is lost, not the session
                log.exception("applying a live frame set failed")
                self.failures += 1
                session.discard_after_failure(None)
                raise SessionError("frame_set_failed", f"the frame set could not be applied ({_summary(exc)}); "
                                                       "send the next one") from None
            due = background or time.monotonic() - self._persisted >= self.config.persist_seconds
            snapshot = self._live_snapshot(with_background=background) if due else None
        if snapshot is not None:  # written after the lock is released: views are not held up by the disk
            self._persist_live(snapshot)
        ack["lock_wait_ms"] = round((t2 - t1) * 1e3, 2)
        return ack

    def _live_snapshot(self, with_background: bool) -> tuple[int, list[bytes], list[Any] | None, list[bool]]:
        """What :meth:`_persist_live` stores, taken while the frames' write lock is held: the latest live
        set and, when a background set reset it, the background model (its slow drift is relearnt after
        a restart)."""
        session = self.session
        self._persisted = time.monotonic()  # due again only after the interval, even while this one writes
        return (session.seq, list(session.latest_jpegs), session.background.images() if with_background else None,
                list(session.latest_timing.stale))

    def _persist_live(self, snapshot: tuple[int, list[bytes], list[Any] | None, list[bool]]) -> None:
        """Store a :meth:`_live_snapshot` (one writer at a time): skipped when a newer set was stored
        meanwhile, unless it carries a background model (then stored with its own, consistent set)."""
        seq, jpegs, backgrounds, stale = snapshot
        with self._persist_lock:
            if seq <= self.persisted_seq and backgrounds is None:
                return
            save_live(self.store, self.config.rig_id, seq, jpegs, backgrounds, stale)
            self.persisted_seq = max(self.persisted_seq, seq)

    @_untracked
    def frame_set_after(self, seq: int) -> dict[str, Any] | None:
        """The latest live frame set when it is newer than ``seq``: ``{"seq", "jpegs", "background", "captured",
        "spread_ms", "stale"}`` (the JPEGs as the live client sent them, rig order; :meth:`LiveSession.timing`); None when there is none newer (or this shows a recording). For
        the API processes that relay live sets to browser-rendering viewers (app/live_relay.py)."""
        self._touch(None)
        session = self.session
        if not isinstance(session, LiveSession):
            return None
        self._frames.acquire_read()
        try:
            if session.seq <= seq or not session.latest_jpegs:
                return None
            return {"seq": session.seq, "jpegs": list(session.latest_jpegs), "background": session.latest_background,
                    **session.timing()}
        finally:
            self._frames.release_read()

    def background_pngs(self) -> list[bytes] | None:
        """The live background model as one PNG per camera (rig order, at the size the session works at), or
        None while there is none (no background set has arrived)."""
        session = self.session
        if not isinstance(session, LiveSession) or not session.background.ready:
            return None
        with self._frames.writing():
            images = session.background.images()
        return [encode_png(i) for i in images]

    @_untracked
    def touch(self, viewer: str | None = None) -> None:
        """Keep the session alive (sockets call this while they are open)."""
        self._touch(viewer)

    def leave(self, viewer: str) -> None:
        """A viewer left: drop its waiting request at once, then forget what was kept for it."""
        self.turns.leave(viewer)
        self._viewers.pop(viewer, None)
        with self._frames.writing():
            self.session.forget(viewer)

    def info(self) -> dict[str, Any]:
        now = time.monotonic()
        active = [v for v, t in self._viewers.items() if now - t <= self.config.idle_seconds]
        return {**self.session.describe(), "rig_id": self.config.rig_id, "source": self.config.source,
                "viewers": len(active), "restarted": self.restarted, "pid": os.getpid(), **self.node,
                "idle_s": round(now - self._last, 3), "persisted_seq": self.persisted_seq,
                "failures": self.failures, "turns": self.turns.describe()}

    # --- lifecycle --------------------------------------------------------------------------------
    def _touch(self, viewer: str | None) -> None:
        self._last = time.monotonic()
        if viewer is not None:
            self._viewers[viewer] = self._last

    def _working(self, locked: bool = True) -> "_Busy":
        return _Busy(self, locked)

    def _watch(self) -> None:
        """End the actor when idle; store a live set that arrived within the persistence interval."""
        period = min(1.0, self.config.idle_seconds / 4, self.config.persist_seconds / 2)
        while True:
            time.sleep(period)
            if isinstance(self.session, LiveSession) and self.session.seq != self.persisted_seq:
                with self._frames.writing():
                    snapshot = self._live_snapshot(with_background=False)
                self._persist_live(snapshot)
            if self._busy == 0 and time.monotonic() - self._last > self.config.idle_seconds:
                ray.kill(self._me, no_restart=True)  # an idle end is final: no restart
                return


SessionActor = ray.remote(SessionHost)


def _summary(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0][:200]}" if text else type(exc).__name__


class FrameLock:
    """A readers-writer lock over a session's frames: views are drawn by any number of threads at once
    (readers); preparing a view, a new frame set, a viewer leaving, persisting run alone (the writer).
    A waiting writer goes before new readers, so frame sets are not starved by a stream of views;
    :meth:`downgrade` turns the writer into a reader without letting another writer in between (a view
    is drawn on the very frames it was prepared on). Which mode the calling thread holds is kept per
    thread for :meth:`holds_current` / :meth:`release_current`."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self.readers = 0
        self._writer = False
        self._writers_waiting = 0
        self._mine = threading.local()

    def acquire_write(self) -> None:
        with self._cond:
            self._writers_waiting += 1
            while self._writer or self.readers:
                self._cond.wait()
            self._writers_waiting -= 1
            self._writer = True
        self._mine.mode = "write"

    def release_write(self) -> None:
        with self._cond:
            self._writer = False
            self._cond.notify_all()
        self._mine.mode = None

    def downgrade(self) -> None:
        with self._cond:
            self._writer = False
            self.readers += 1
            self._cond.notify_all()
        self._mine.mode = "read"

    def acquire_read(self) -> None:
        with self._cond:
            while self._writer or self._writers_waiting:
                self._cond.wait()
            self.readers += 1
        self._mine.mode = "read"

    def release_read(self) -> None:
        with self._cond:
            self.readers -= 1
            self._cond.notify_all()
        self._mine.mode = None

    def holds_current(self) -> bool:
        return getattr(self._mine, "mode", None) is not None

    def release_current(self) -> None:
        (self.release_write if self._mine.mode == "write" else self.release_read)()

    @contextlib.contextmanager
    def writing(self) -> Iterator[None]:
        self.acquire_write()
        try:
            yield
        finally:
            self.release_write()


@contextlib.contextmanager
def _render_threads(drawing: int) -> Iterator[None]:
    """Share the compute threads among the views drawn at once: a view drawn alone uses numba's
    threads; ``drawing`` views at once take a share each (numba's setting is per calling thread),
    so concurrent views fill the cores instead of oversubscribing them."""
    total = numba.config.NUMBA_NUM_THREADS
    numba.set_num_threads(max(1, total // max(1, drawing)))
    try:
        yield
    finally:
        numba.set_num_threads(total)


class _Busy:
    """Marks the actor busy (the idle watch never ends a busy actor) and holds the frames' write lock
    (unless ``locked`` is False)."""

    def __init__(self, actor: Any, locked: bool = True) -> None:
        self.actor = actor
        self.locked = locked

    def __enter__(self) -> None:
        self.actor._busy += 1
        if self.locked:
            self.actor._frames.acquire_write()

    def __exit__(self, *exc: object) -> None:
        if self.locked:
            self.actor._frames.release_write()
        self.actor._busy -= 1
        self.actor._last = time.monotonic()


# --- the API side ---------------------------------------------------------------------------------
def get_or_create(config: SessionConfig, resources: dict[str, float] | None = None,
                  actor_class: Any = SessionActor) -> Any:
    """The handle of the session actor for ``config`` (created from ``actor_class`` when there is none; with no
    resources asked, on the node :func:`wait_for_session_node` finds). Blocking. ``resources``: what the actor needs
    of a node; a "GPU" entry (a fraction of one, say 0.25: four sessions share a card) is Ray's own GPU resource,
    which also makes the GPU visible to the actor (Ray hides every GPU from an actor that asks for none), so that
    its renderer searches depth there."""
    resources = dict(resources or {})
    gpus = float(resources.pop("GPU", 0.0))
    # A session that asks for a GPU share or a custom resource goes where Ray finds it free (an API or head node
    # has neither); one that asks nothing is pinned to a node with CPUs. The pin is hard: Ray's soft one put 1 and
    # 2 of 4 new sessions on the caller's node anyway (a CPU-less head and one worker, 2026-11-29). A session whose
    # node is lost then fails as unschedulable (Ray frees its name once it marks the node dead), and
    # SessionClient makes a new one on a live node.
    asks = gpus > 0 or any(v > 0 for v in resources.values())
    node = None if asks or _exists(config.name) else wait_for_session_node()
    return actor_class.options(
        name=config.name, namespace=NAMESPACE, lifetime="detached", get_if_exists=True,
        max_restarts=MAX_RESTARTS, max_concurrency=64, num_cpus=0, num_gpus=gpus, resources=resources,
        scheduling_strategy=NodeAffinitySchedulingStrategy(node, soft=False) if node else "DEFAULT",
    ).remote(config)


SESSION_NODE_WAIT_S = 60.0
"""How long a new session waits for a node with CPUs to join before Ray places it where it can."""


def _exists(name: str) -> bool:
    try:
        ray.get_actor(name, namespace=NAMESPACE)
        return True
    except ValueError:
        return False


def wait_for_session_node(timeout_s: float = SESSION_NODE_WAIT_S) -> str | None:
    """:func:`session_node` of the live nodes, asked every half second until one qualifies or ``timeout_s`` has
    passed (a cluster's API replica is ready before its workers have joined: the demo session it starts at once
    ran on the replica's own node for the rest of a compose soak, 2026-11-29); None after that."""
    deadline = time.monotonic() + timeout_s
    said = False
    while (node := session_node(ray.nodes())) is None and time.monotonic() < deadline:
        if not said:
            log.info("waiting up to %.0f s for a node with CPUs to start a viewer session on", timeout_s)
            said = True
        time.sleep(0.5)
    if node is None:
        log.warning("no node with CPUs joined in %.0f s: the session starts where Ray places it", timeout_s)
    return node


def session_node(nodes: list[dict[str, Any]], rng: random.Random | None = None) -> str | None:
    """The id of the node a new session actor that asks for no resource should run on: a live one (of ``nodes``,
    as :func:`ray.nodes` lists them) with CPUs, drawn at random weighted by its CPUs, so that sessions spread over
    the worker nodes as their cores do. None when no node qualifies.

    Why: a session actor reserves no CPU (a node's CPUs are for the batch jobs, and a job retried alone on a node
    asks for all of them), so Ray's own choice for it is any node, and it prefers the caller's: in the compose
    stack one session ran on an API replica's node (``docker/verify-stack.sh`` soak, 2026-11-29), which joins
    the cluster without CPUs; the head's node has none either. Where either is a small machine of its own, a
    renderer there starves it."""
    candidates = [(node["NodeID"], float(node["Resources"]["CPU"])) for node in nodes
                  if node.get("Alive") and node.get("Resources", {}).get("CPU", 0.0) > 0]
    if not candidates:
        return None
    ids, cpus = zip(*candidates)
    return (rng or random).choices(ids, weights=cpus)[0]


class SessionClient:
    """Async calls to the session actor of one (rig, source), for one socket of the API.

    A call that finds the actor gone (it idled out, or its restarts are spent) creates a new one and
    tries again; a call that finds it restarting waits for it. What a call could not serve (a
    :class:`~workers.streaming.session.SessionError`) is raised here as it was raised in the actor. A call made with ``resend=False``
    (a render or a push: it may be what crashed the actor) is not tried again: it raises
    :class:`SessionInterrupted`, and the next such call first waits for the actor to be back."""

    def __init__(self, config: SessionConfig, resources: dict[str, float] | None = None,
                 restart_wait_s: float = 30.0) -> None:
        self.config = config
        self.resources = resources
        self.restart_wait_s = restart_wait_s
        self._handle: Any = None
        self._interrupted = False

    # --- the session actor's calls, one method each (see :class:`SessionHost`) ------------------
    async def info(self) -> dict[str, Any]:
        return await self._call(lambda actor: actor.info.remote())

    async def view(self, viewer: str, vp: Viewpoint) -> tuple[dict[str, Any], bytes]:
        """Not sent again when the actor is lost during it (it may be what crashed it)."""
        return await self._call(lambda actor: actor.view.remote(viewer, vp), resend=False)

    async def push(self, jpegs: list[bytes], background: bool = False, timing: SetTiming = SetTiming()) -> dict[str, Any]:
        """Not sent again when the actor is lost during it (it may be what crashed it)."""
        return await self._call(lambda actor: actor.push.remote(jpegs, background, timing), resend=False)

    async def touch(self, viewer: str | None = None) -> None:
        await self._call(lambda actor: actor.touch.remote(viewer))

    async def frame_set_after(self, seq: int) -> dict[str, Any] | None:
        return await self._call(lambda actor: actor.frame_set_after.remote(seq))

    async def background_pngs(self) -> list[bytes] | None:
        return await self._call(lambda actor: actor.background_pngs.remote())

    async def leave(self, viewer: str, timeout_s: float = 5.0) -> None:
        """Tell the actor ``viewer`` left, if this client has reached it; never creates one, never raises."""
        if self._handle is None:
            return
        try:
            await asyncio.wait_for(self._handle.leave.remote(viewer), timeout_s)
        except (ray.exceptions.RayError, asyncio.TimeoutError):
            pass

    async def _call(self, invoke: Callable[[Any], Any], resend: bool = True) -> Any:
        if not resend and self._interrupted:
            await self.touch()  # harmless to repeat: waits out the restart or makes a new actor
            self._interrupted = False
        deadline = time.monotonic() + self.restart_wait_s
        recreated = 0
        while True:
            if self._handle is None:
                self._handle = await asyncio.to_thread(get_or_create, self.config, self.resources)
            try:
                return await invoke(self._handle)
            except ray.exceptions.RayTaskError as exc:  # raised by the call itself: what it could not serve
                if isinstance(exc.cause, SessionError):
                    raise exc.cause from None
                raise
            except ray.exceptions.ActorUnavailableError as exc:
                if not resend:
                    raise self._interruption(exc) from exc
                if time.monotonic() > deadline:
                    raise
                await asyncio.sleep(0.1)
            except (ray.exceptions.ActorDiedError, ray.exceptions.ActorUnschedulableError) as exc:
                # unschedulable: the node it was pinned to is gone (get_or_create); a new one goes elsewhere
                self._handle = None
                if not resend:
                    raise self._interruption(exc) from exc
                recreated += 1
                if recreated > 2:
                    raise

    def _interruption(self, exc: Exception) -> SessionInterrupted:
        self._interrupted = True
        log.warning("session %s lost its process during a call: %s", self.config.name, type(exc).__name__)
        return SessionInterrupted("the session's process was lost while handling this request; it restarts "
                                  "and reloads its frames, and the next request is served then")


def list_sessions() -> list[dict[str, str]]:
    """``[{"name", "rig_id", "source"}]`` of the session actors alive in the cluster. Blocking."""
    out = []
    for entry in ray.util.list_named_actors(all_namespaces=True):
        name = entry["name"]
        if entry.get("namespace") == NAMESPACE and name.startswith(NAME_PREFIX):
            rig_id, _, source = name[len(NAME_PREFIX):].partition("/")
            out.append({"name": name, "rig_id": rig_id, "source": source})
    return out


def session_info(name: str, timeout_s: float = 5.0) -> dict[str, Any] | None:
    """The ``info()`` of a session actor (waiting while it restarts), or None when it is gone or
    does not answer within ``timeout_s``. Blocking."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            handle = ray.get_actor(name, namespace=NAMESPACE)
            return ray.get(handle.info.remote(), timeout=max(deadline - time.monotonic(), 0.1))
        except ray.exceptions.ActorUnavailableError:
            if time.monotonic() > deadline:
                return None
            time.sleep(0.1)
        except (ValueError, ray.exceptions.RayError):
            return None


def end_sessions(rig_id: str, source: str | None = None) -> int:
    """End the session actors of a rig (or of one of its sources); return how many. Blocking."""
    ended = 0
    for s in list_sessions():
        if s["rig_id"] == rig_id and source in (None, s["source"]):
            try:
                ray.kill(ray.get_actor(s["name"], namespace=NAMESPACE), no_restart=True)
                ended += 1
            except ValueError:  # ended meanwhile
                pass
    return ended
