"""A virtual-view session: one rig, one source of frames (a recording or a live stream), rendering
JPEG views for any number of viewers. Plain Python (no Ray): :mod:`workers.streaming.actor` wraps it.

:meth:`Session.render` answers one :class:`Viewpoint` with ``(header, jpeg)``; the header is::

    {"type": "frame", "id": <the viewpoint's id>, "frame": <index> | "live", "seq": <live set> | null,
     "width", "height", "method", "d_bnd", "planes", "overlay", "source_factor": <int, see below>,
     "depth_range": [near, far]  (metres, the swept range), "depth_found": [min, max] | null,
     "coverage": share of pixels with a surface, "quality": the level drawn ("best", "fast", or "custom" where the
     viewpoint's own aggregation or occlusions differ from its level's), "quality_asked": the viewpoint's
     render_quality ("auto", "best", "fast"), "render_ms", "encode_ms", "reshaded": bool, "timings": {stage: ms}}

A viewer whose new viewpoint differs from its previous one only in the colour weighting (method,
D_bnd, k) is answered by re-shading the previous depth, without a new sweep; one that asks for the same view of
another frame set (playing a recording, watching the live stream) keeps the previous depth wherever the scene stood
still (:mod:`workers.sweep.temporal`: no flicker there). The header's "held" is the share of such pixels.

A recording session renders from frames at about the viewer's size: for a view w x h it shrinks the
rig's images by the integer factor :func:`source_factor` (the largest that keeps them at least w x h;
1920x1080 cameras and a 640x360 view: 3), once per frame set and factor (area averaging, then the
renderer's undistortion at the small size), and keeps a renderer per factor in use (at most
``MAX_LEVELS``). The header then also says ``"source_factor"`` (1: the recorded size). A live session
decodes each pushed set once, at the factor of the largest view its present viewers ask for (JPEG DCT
scaling: a 640x480 rig seen at 320x240 decodes at half size), see :class:`LiveSession`.
"""
from __future__ import annotations

import threading
import time
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Any, Sequence

import cv2
import numpy as np
from pydantic import ValidationError

from workers.camera import Camera, CameraError
from workers.common.errors import InputError
from workers.common.validation import describe_errors
from workers.sweep.overlays import depth_image, regions_image
from workers.sweep.renderer import RenderOptions, RenderResult, SweepRenderer
from workers.sweep.rig import Rig, RigError

from .background import BackgroundModel
from .images import ImageError, decode_reduced, encode_jpeg
from .params import Viewpoint
from .quality import QualityChooser
from .recording import RecordingArchive
from .viewpoint import OrbitFrame, orbit_frame, virtual_camera

MiB = 1 << 20
OVERLAY_WEIGHT = 0.55
MAX_SOURCE_FACTOR = 8
MAX_LEVELS = 3


def source_factor(rig: Rig, width: int, height: int) -> int:
    """The factor (1..MAX_SOURCE_FACTOR) a recording session shrinks ``rig``'s images by for views of
    ``width`` x ``height`` px: the largest whose shrunk images are all at least that size (:func:`views_up_to`; a
    view never samples images coarser than itself), 1 where none is."""
    fits = [f for f in range(2, MAX_SOURCE_FACTOR + 1)
            if width <= views_up_to(rig, f)[0] and height <= views_up_to(rig, f)[1]]
    return max(fits, default=1)


def views_up_to(rig: Rig, factor: int) -> tuple[int, int]:
    """The largest view (width, height) px that ``rig``'s images shrunk by ``factor`` serve: every camera's image
    at least that size (the smallest camera's width and height over ``factor``, rounded down)."""
    return min(c.width for c in rig.cameras) // factor, min(c.height for c in rig.cameras) // factor


def shrunk_camera(cam: Camera, factor: int) -> Camera:
    """``cam`` for its image resized to round(W / factor) x round(H / factor) px: K scaled per axis by
    the exact size ratios (pixel centres kept: u' = (u + 0.5) W'/W - 0.5), distortion unchanged (it acts
    on normalised coordinates)."""
    w, h = max(1, round(cam.width / factor)), max(1, round(cam.height / factor))
    sx, sy = w / cam.width, h / cam.height
    K = cam.K.copy()
    K[0] *= sx
    K[1] *= sy
    K[0, 2] = (cam.K[0, 2] + 0.5) * sx - 0.5
    K[1, 2] = (cam.K[1, 2] + 0.5) * sy - 0.5
    return Camera(cam.name, K, cam.R, cam.t, w, h, cam.dist)


def shrunk_rig(rig: Rig, factor: int) -> Rig:
    """``rig`` with every camera :func:`shrunk_camera` by ``factor`` (``rig`` itself for 1)."""
    if factor == 1:
        return rig
    return Rig(tuple(shrunk_camera(c, factor) for c in rig.cameras), rig.image_files, rig.depth_range)


def shrunk_images(images: Sequence[np.ndarray], rig: Rig) -> list[np.ndarray]:
    """``images`` (H, W, 3) uint8 each, area-averaged to the sizes of ``rig``'s cameras (unchanged when equal)."""
    return [img if img.shape[:2] == (c.height, c.width)
            else cv2.resize(img, (c.width, c.height), interpolation=cv2.INTER_AREA)
            for img, c in zip(images, rig.cameras)]


class SessionError(Exception):
    """A request a session could not serve: ``code`` and ``detail`` go to the client as they are. Raised in the
    session's actor, it reaches the API process intact (:class:`workers.streaming.actor.SessionClient`)."""

    def __init__(self, code: str, detail: str) -> None:
        super().__init__(detail)
        self.code = code
        self.detail = detail

    def __reduce__(self) -> tuple:  # pickled across Ray with both arguments
        return type(self), (self.code, self.detail)


class ViewError(SessionError, InputError):
    """A request the session cannot serve because of what the client sent (or has not sent yet): an
    :class:`~workers.common.errors.InputError` (422 with its ``code`` where an HTTP route meets it, a batch render's
    view limits)."""


@dataclass(frozen=True)
class SessionLimits:
    """max_pixels: largest output (width x height); max_planes: most depth planes per view;
    cache_bytes: decoded recording frames kept in memory; viewers_kept: previous renders kept
    for re-shading; max_spread: the largest spread of capture times (s) a live frame set may have, whatever
    tolerance its client declares; target_fps: the rate a render at the "best" quality level must hold for "auto" to
    draw it (:class:`workers.streaming.quality.QualityChooser`)."""

    max_pixels: int = 1920 * 1080
    max_planes: int = 256
    cache_bytes: int = 256 * MiB
    viewers_kept: int = 32
    max_spread: float = 0.1
    target_fps: float = 15.0

    def check(self, width: int, height: int, planes: int) -> None:
        """ViewError when a view of ``width`` x ``height`` pixels and ``planes`` depth planes is over the
        limits: the one rule for viewer sockets, sessions and batch renders."""
        if width * height > self.max_pixels:
            raise ViewError("too_large", f"output {width}x{height} is over the limit of {self.max_pixels:,} pixels")
        if planes > self.max_planes:
            raise ViewError("too_many_planes", f"{planes} planes is over the limit of {self.max_planes}")


@dataclass(frozen=True)
class Plan:
    """A view ready to draw (:meth:`Session.prepare`): the viewpoint, its camera and options, the quality level
    they were taken from and what runs (the level, or "custom"), the key of what it shows (for re-shading), and
    the renderer, frame label, live set and factor it was planned on."""

    vp: Viewpoint
    camera: Camera
    options: RenderOptions
    level: str
    runs: str
    key: tuple
    frame_label: int | str
    renderer: SweepRenderer
    seq: int | None
    source_factor: int
    timing: dict[str, Any] = field(default_factory=dict)
    """What the frame header says of the live set drawn: ``captured``, ``spread_ms``, ``stale`` (empty otherwise)."""


class Session:
    """Renders views of ``rig`` from the frames loaded by a subclass. Not thread-safe as a whole:
    :meth:`prepare` and frame changes run alone, :meth:`draw` on several threads at once (the actor's
    readers-writer lock)."""

    kind = "?"
    seq: int | None = None
    """Number of the live frame set shown (live sessions only)."""

    def __init__(self, rig: Rig, limits: SessionLimits) -> None:
        self.rig = rig
        self.limits = limits
        self.orbit: OrbitFrame = orbit_frame(rig)
        self.renderer: SweepRenderer | None = None
        self.frame_key: Any = None
        self.source_factor = 1
        self._previous: OrderedDict[str, tuple[tuple, RenderResult]] = OrderedDict()
        self._kept_lock = threading.Lock()  # _previous: drawn into from several threads
        self.renders = 0
        self.quality = QualityChooser(limits.target_fps)

    def view(self, viewer: str, vp: Viewpoint) -> tuple[dict[str, Any], bytes]:
        """The view ``vp`` asks for, as a frame header and a JPEG, for ``viewer`` (any id; it keys the previous
        render for re-shading); ViewError when ``vp`` is over the limits or cannot be served."""
        return self.draw(viewer, self.prepare(viewer, vp))

    def prepare(self, viewer: str, vp: Viewpoint) -> "Plan":
        """First half of :meth:`view`: check ``vp`` against the limits (the one check of the viewer path) and
        load the frames it asks for into the renderer. Changes the session: callers that draw on several
        threads run it alone."""
        self.limits.check(vp.width, vp.height, vp.planes)
        frame_label = self._prepare(viewer, vp)
        level = vp.render_quality
        if level == "auto":
            level = self.quality.choose((vp.width, vp.height, vp.planes))
        try:
            cam = virtual_camera(vp, self.orbit, (vp.width, vp.height))
            fields, runs = vp.render_fields(level)
            options = RenderOptions(**fields)
        except (RigError, CameraError, ValidationError) as exc:
            raise ViewError("bad_view", _one_line(exc)) from None
        key = (self.frame_key, cam.K.tobytes(), cam.R.tobytes(), cam.t.tobytes(), vp.planes, vp.near, vp.far,
               vp.visual_hull, vp.coarse_to_fine, options.aggregation, options.occlusions)
        return Plan(vp, cam, options, level, runs, key, frame_label, self.renderer, self.seq, self.source_factor,
                    self.timing())

    def draw(self, viewer: str, plan: "Plan") -> tuple[dict[str, Any], bytes]:
        """Second half of :meth:`view`: sweep (or re-shade) and encode. Reads the frames only, so
        several threads may draw at once while no :meth:`prepare` or frame change runs."""
        vp = plan.vp
        try:
            with self._kept_lock:
                previous = self._previous.get(viewer)
            reshaded = previous is not None and previous[0] == plan.key
            if reshaded:
                result = plan.renderer.reshade(previous[1], method=vp.method, d_bnd=vp.d_bnd, k=vp.k,
                                               visibility=vp.visibility)
            else:
                # the same view of another frame set: its depth stays where the scene stood still (no flicker)
                earlier = previous[1] if previous is not None and previous[0][1:] == plan.key[1:] else None
                result = plan.renderer.render(plan.camera, plan.options, previous=earlier)
        except (RigError, CameraError, ValidationError) as exc:
            raise ViewError("bad_view", _one_line(exc)) from None
        self._remember(viewer, plan.key, result)
        if not reshaded and plan.runs == plan.level:
            self.quality.record((vp.width, vp.height, vp.planes), plan.level, result.timings.get("total_ms", 0.0))
        t0 = time.perf_counter()
        jpeg = encode_jpeg(_composed(result, vp.overlay), vp.quality)
        encode_ms = (time.perf_counter() - t0) * 1e3
        self.renders += 1
        found = np.isfinite(result.depth)
        header = {
            "type": "frame", "id": vp.id, "frame": plan.frame_label, "seq": plan.seq,
            "width": vp.width, "height": vp.height, "method": vp.method, "d_bnd": result.d_bnd, "planes": vp.planes,
            "overlay": vp.overlay, "source_factor": plan.source_factor,
            "depth_range": [float(result.planes.min()), float(result.planes.max())],
            "depth_found": [float(result.depth[found].min()), float(result.depth[found].max())] if found.any() else None,
            "coverage": float(found.mean()), "held": float(result.held.mean()) if result.held is not None else 0.0,
            "quality": plan.runs, "quality_asked": vp.render_quality,
            "render_ms": round(result.timings.get("total_ms", 0.0), 2), "encode_ms": round(encode_ms, 2),
            "reshaded": reshaded, "timings": {k: round(v, 2) for k, v in result.timings.items()},
            **plan.timing,
        }
        return header, jpeg

    def forget(self, viewer: str) -> None:
        """Drop what is kept for ``viewer`` (it left)."""
        with self._kept_lock:
            self._previous.pop(viewer, None)

    def discard_after_failure(self, viewer: str | None) -> None:
        """After an unexpected exception in a render for ``viewer`` (None: in applying frames),
        drop what it may have left half-made: the kept renders it could be re-shaded from, and
        which frames the renderer holds (the next render loads them again)."""
        if viewer is None:
            self._previous.clear()
        else:
            self._previous.pop(viewer, None)
        self.frame_key = None

    def describe(self) -> dict[str, Any]:
        return {"kind": self.kind, "cameras": len(self.rig), "renders": self.renders}

    def timing(self) -> dict[str, Any]:
        """When the frames shown were taken, for a frame's header (a live session's; empty for a recording)."""
        return {}

    def _prepare(self, viewer: str, vp: Viewpoint) -> int | str:
        """Load the frames ``vp`` asks for into the renderer; return the frame label for the header."""
        raise NotImplementedError

    def _remember(self, viewer: str, key: tuple, result: RenderResult) -> None:
        with self._kept_lock:
            self._previous[viewer] = (key, result)
            self._previous.move_to_end(viewer)
            while len(self._previous) > self.limits.viewers_kept:
                self._previous.popitem(last=False)


@dataclass
class _Level:
    """The rig shrunk by ``factor``, its renderer and the frame index the renderer holds (None: unknown)."""

    factor: int
    rig: Rig
    renderer: SweepRenderer
    frame: int | None


class RecordingSession(Session):
    """Views of a stored recording; viewers pick the frame index. Frames are shrunk to about the
    viewer's size (:func:`source_factor`, module docstring); shrunk frame sets are cached (least
    recently used first out) up to ``limits.cache_bytes``."""

    kind = "recording"

    def __init__(self, rig: Rig, archive: RecordingArchive, limits: SessionLimits = SessionLimits()) -> None:
        super().__init__(rig, limits)
        info = archive.info
        if list(info.cameras) != rig.names or list(info.sizes) != [(c.width, c.height) for c in rig.cameras]:
            raise ValueError("the recording was made for other cameras than this rig's")
        self.archive = archive
        self.frames = info.frames
        self.fps = info.fps
        self._cache: OrderedDict[tuple[int, int], list[np.ndarray]] = OrderedDict()
        self._levels: OrderedDict[int, _Level] = OrderedDict()
        start = Viewpoint()  # the protocol's default view size
        self._use(source_factor(rig, start.width, start.height), 0)

    def _prepare(self, viewer: str, vp: Viewpoint) -> int:
        if not isinstance(vp.frame, int):
            raise ViewError("bad_frame", "this socket shows a recording: 'frame' must be a frame index")
        if not 0 <= vp.frame < self.frames:
            raise ViewError("bad_frame", f"frame {vp.frame} is out of range: the recording has {self.frames} "
                                         f"frames (0..{self.frames - 1})")
        self._use(source_factor(self.rig, vp.width, vp.height), vp.frame)
        return vp.frame

    def _use(self, factor: int, index: int) -> None:
        """Make the renderer of ``factor`` current, holding frame set ``index`` (built or loaded only
        when it is not already so)."""
        level = self._levels.get(factor)
        if level is None:
            small = shrunk_rig(self.rig, factor)
            backgrounds = shrunk_images(self.archive.backgrounds(), small)
            level = _Level(factor, small, SweepRenderer(small, self._frame_set(small, factor, index),
                                                        backgrounds=backgrounds), index)
            self._levels[factor] = level
            while len(self._levels) > MAX_LEVELS:
                self._levels.popitem(last=False)
        elif level.frame != index:
            level.renderer.set_frames(self._frame_set(level.rig, factor, index))
            level.frame = index
        self._levels.move_to_end(factor)
        self.renderer = level.renderer
        self.source_factor = factor
        self.frame_key = (factor, index)

    def _frame_set(self, small: Rig, factor: int, index: int) -> list[np.ndarray]:
        """Frame set ``index`` shrunk to the cameras of ``small`` (the rig shrunk by ``factor``)."""
        key = (factor, index)
        if key in self._cache:
            self._cache.move_to_end(key)
            return self._cache[key]
        images = shrunk_images(self.archive.frame_set(index), small)
        self._cache[key] = images
        while len(self._cache) > 1 and sum(i.nbytes for s in self._cache.values() for i in s) > self.limits.cache_bytes:
            self._cache.popitem(last=False)
        return images

    def discard_after_failure(self, viewer: str | None) -> None:
        super().discard_after_failure(viewer)
        for level in self._levels.values():
            level.frame = None

    def describe(self) -> dict[str, Any]:
        return {**super().describe(), "frames": self.frames, "fps": self.fps, "cached_frames": len(self._cache),
                "source_factors": sorted(self._levels)}


@dataclass(frozen=True)
class SetTiming:
    """When a live frame set was taken, as its client said: ``captured`` (s since the Unix epoch, rig order; None
    when the client sent no capture times), ``stale`` (rig order: the camera's frame is not of this instant) and
    ``tolerance`` (the largest spread, s, the client allowed; None: the session's ``max_spread``)."""

    captured: tuple[float, ...] | None = None
    stale: tuple[bool, ...] = ()
    tolerance: float | None = None

    def fresh(self, n: int) -> list[int]:
        """Indices of the cameras whose frame is of this instant (all of ``n`` when none is stale)."""
        return [i for i in range(n) if not (self.stale and self.stale[i])]

    def spread(self, n: int) -> float | None:
        """Latest minus earliest capture time of the fresh frames, s (None without capture times)."""
        if self.captured is None:
            return None
        times = [self.captured[i] for i in self.fresh(n)]
        return max(times) - min(times)


class LiveSession(Session):
    """Views of the latest frame set pushed by a live client; keeps a background model per camera
    for the silhouettes (:class:`BackgroundModel`).

    Frames are decoded at the size the viewers need: shrunk by :func:`source_factor` of the largest
    view asked for by a viewer still present (JPEG DCT scaling: :func:`decode_reduced`), or of the
    protocol's default view size while there is none. The renderer and the background model work at
    that size; a viewer that needs finer frames has the latest set decoded again for it at once, and
    a factor that viewers leaving make coarser takes effect with the next set.

    A set's capture times (:class:`SetTiming`) are checked first: a set whose fresh frames spread over its
    tolerance (the client's, at most ``limits.max_spread``) is refused (``spread_over_tolerance``) and the
    previous set stays shown, so frames of different instants are never rendered as one. A stale camera (its
    client lost it: its frame is an older one) is not decoded and is left out of the render: the view is swept
    from the other cameras (a renderer over the rig without it, kept while the same cameras are stale).

    :meth:`decode` (the expensive part, thread-safe, no state changed) and :meth:`apply` (under the
    caller's lock) split :meth:`push`, so the actor decodes a set while views are rendered."""

    kind = "live"

    def __init__(self, rig: Rig, limits: SessionLimits = SessionLimits(), bg_rate: float = 0.02) -> None:
        super().__init__(rig, limits)
        self.background = BackgroundModel(len(rig), rate=bg_rate)
        self.seq = 0
        self.latest_jpegs: list[bytes] = []
        self.latest_background = False
        """Whether the latest set was flagged as background (the empty studio)."""
        self.latest_timing = SetTiming()
        self.received_at: float | None = None
        start = Viewpoint()
        self.default_factor = source_factor(rig, start.width, start.height)
        self.source_factor = self.default_factor
        self.work_rig = shrunk_rig(rig, self.default_factor)
        self._viewer_factors: dict[str, int] = {}
        self._full: SweepRenderer | None = None
        self._partial: dict[tuple[int, ...], SweepRenderer] = {}
        self._images: list[np.ndarray] = []

    def wanted_factor(self) -> int:
        """The factor frames are decoded at: the finest any present viewer needs (else the default's)."""
        return min(self._viewer_factors.values(), default=self.default_factor)

    def check_timing(self, timing: SetTiming, is_background: bool = False) -> None:
        """ViewError when the set cannot be shown as one instant: its fresh frames spread over its tolerance (the
        client's, at most ``limits.max_spread``), or a background set with a stale camera."""
        n = len(self.rig)
        if timing.stale and any(timing.stale):
            if len(timing.fresh(n)) < 2:
                raise ViewError("bad_frame_set", "a frame set needs at least two cameras that are not stale")
            if is_background:
                stale = [c.name for c, s in zip(self.rig.cameras, timing.stale) if s]
                raise ViewError("bad_frame_set", f"a background set needs every camera; stale: {', '.join(stale)}")
        spread = timing.spread(n)
        limit = min(timing.tolerance or self.limits.max_spread, self.limits.max_spread)
        if spread is not None and spread > limit + 1e-9:
            raise ViewError("spread_over_tolerance",
                            f"the frames of this set were captured {spread * 1e3:.1f} ms apart; at most "
                            f"{limit * 1e3:.1f} ms make one instant (the client's tolerance, at most the service's "
                            f"{self.limits.max_spread * 1e3:.0f} ms): not shown, the previous set stays")

    def decode(self, jpegs: Sequence[bytes], factor: int | None = None, timing: SetTiming = SetTiming()) -> list[np.ndarray]:
        """The frame set (one JPEG per camera, rig order) decoded at ``factor`` (None: :meth:`wanted_factor`),
        (h, w, 3) uint8 BGR per camera; a stale camera (``timing``) is not decoded (its image is the one shown
        before, or black: it is not rendered). A JPEG that does not decode, or not at its camera's size,
        raises ViewError. Changes nothing: safe to call while another thread renders."""
        if len(jpegs) != len(self.rig):
            raise ViewError("bad_frame_set", f"{len(jpegs)} images for {len(self.rig)} cameras")
        factor = self.wanted_factor() if factor is None else factor
        small = shrunk_rig(self.rig, factor)
        images = []
        for i, (cam, data) in enumerate(zip(self.rig.cameras, jpegs)):
            if timing.stale and timing.stale[i]:
                shown = self._images[i] if len(self._images) == len(jpegs) else None
                size = (small.cameras[i].height, small.cameras[i].width)
                images.append(shown if shown is not None and shown.shape[:2] == size else np.zeros((*size, 3), np.uint8))
                continue
            try:
                images.append(decode_reduced(data, (cam.width, cam.height), factor))
            except ImageError as exc:
                raise ViewError("bad_image", f"camera {cam.name}: the image {exc}") from None
        return images

    def apply(self, images: Sequence[np.ndarray], jpegs: Sequence[bytes], is_background: bool = False,
              timing: SetTiming = SetTiming()) -> None:
        """Show a decoded set (:meth:`decode` of ``jpegs``): background model, silhouettes, renderer (without the
        stale cameras). A set decoded at another factor than the one wanted now is decoded again."""
        self.check_timing(timing, is_background)
        factor = self.wanted_factor()
        small = shrunk_rig(self.rig, factor)
        if [img.shape[:2] for img in images] != [(c.height, c.width) for c in small.cameras]:
            images = self.decode(jpegs, factor, timing)
        self._use_factor(factor, small)
        self.latest_timing = timing
        silhouettes = self.background.observe(images, is_background)
        self._show(images, silhouettes)
        self.seq += 1
        self.frame_key = ("live", self.seq, factor)
        self.latest_jpegs = list(jpegs)
        self.latest_background = bool(is_background)
        self.received_at = time.time()

    def push(self, jpegs: Sequence[bytes], is_background: bool = False, timing: SetTiming = SetTiming()) -> dict[str, Any]:
        """Check, decode and apply a synchronised frame set (one JPEG per camera, rig order). A set over its
        tolerance, or a JPEG that does not decode (or not at its camera's size), raises ViewError and keeps the
        previous set."""
        self.check_timing(timing, is_background)
        t0 = time.perf_counter()
        images = self.decode(jpegs, timing=timing)
        t1 = time.perf_counter()
        self.apply(images, jpegs, is_background, timing)
        return self.ack(decode_ms=(t1 - t0) * 1e3, apply_ms=(time.perf_counter() - t1) * 1e3,
                        background=is_background)

    def ack(self, decode_ms: float, apply_ms: float, background: bool) -> dict[str, Any]:
        """What a client is told of the set just applied."""
        return {"seq": self.seq, "decode_ms": round(decode_ms, 2), "apply_ms": round(apply_ms, 2),
                "background_model": self.background.ready, "background": background,
                "source_factor": self.source_factor, **self.timing()}

    def timing(self) -> dict[str, Any]:
        """``captured`` (the set's instant: median capture time of its fresh frames, s since the epoch, or None),
        ``spread_ms`` (None without capture times) and ``stale`` (names of the cameras left out)."""
        t, n = self.latest_timing, len(self.rig)
        spread = t.spread(n)
        instant = float(np.median([t.captured[i] for i in t.fresh(n)])) if t.captured is not None else None
        return {"captured": instant, "spread_ms": round(spread * 1e3, 3) if spread is not None else None,
                "stale": [c.name for c, s in zip(self.rig.cameras, t.stale) if s] if t.stale else []}

    def restore(self, seq: int, jpegs: Sequence[bytes], backgrounds: Sequence[np.ndarray] | None,
                stale: Sequence[bool] = ()) -> None:
        """Reload a persisted state: the background model (if any; any stored size, resampled to the
        working size) and frame set number ``seq`` (``stale``: its cameras left out, as when it was shown)."""
        if backgrounds:
            self.background.load(backgrounds, [(c.width, c.height) for c in self.work_rig.cameras])
        if jpegs:
            self.seq = seq - 1
            self.push(jpegs, timing=SetTiming(stale=tuple(stale)) if any(stale) else SetTiming())

    def forget(self, viewer: str) -> None:
        super().forget(viewer)
        self._viewer_factors.pop(viewer, None)

    def _prepare(self, viewer: str, vp: Viewpoint) -> str:
        if vp.frame != "live":
            raise ViewError("bad_frame", "this socket shows the live stream: 'frame' must be \"live\"")
        if self.renderer is None:
            raise ViewError("no_frames", "no live frame set has arrived yet")
        self._viewer_factors[viewer] = source_factor(self.rig, vp.width, vp.height)
        factor = self.wanted_factor()
        if factor < self.source_factor:  # this viewer needs finer frames than those shown: decode them again
            small = shrunk_rig(self.rig, factor)
            images = self.decode(self.latest_jpegs, factor, self.latest_timing)
            self._use_factor(factor, small)
            self._show(images, self.background.silhouettes(images))
            self.frame_key = ("live", self.seq, factor)
        return "live"

    def _use_factor(self, factor: int, small: Rig) -> None:
        """Make ``factor`` (with ``small``, the rig shrunk by it) the working size of the renderer and model."""
        if factor == self.source_factor and self.renderer is not None:
            return
        self.source_factor, self.work_rig = factor, small
        self.renderer = self._full = None  # rebuilt for the new camera sizes by _show
        self._partial = {}
        self.background.resize([(c.width, c.height) for c in small.cameras])

    def _show(self, images: Sequence[np.ndarray], silhouettes: Sequence[np.ndarray] | None) -> None:
        """Give the renderer the set: every camera's, or (stale cameras) those of the fresh ones only."""
        self._images = list(images)
        fresh = self.latest_timing.fresh(len(self.rig))
        if len(fresh) == len(self.rig):
            if self._full is None:
                self._full = SweepRenderer(self.work_rig, images, silhouettes=silhouettes)
            else:
                self._full.set_frames(images, silhouettes)
            self.renderer = self._full
            return
        key = tuple(fresh)
        some = [images[i] for i in fresh]
        masks = [silhouettes[i] for i in fresh] if silhouettes is not None else None
        renderer = self._partial.get(key)
        if renderer is None:
            rig = Rig(tuple(self.work_rig.cameras[i] for i in fresh), tuple(self.work_rig.image_files[i] for i in fresh),
                      self.work_rig.depth_range)
            self._partial = {key: SweepRenderer(rig, some, silhouettes=masks)}  # one: the next change needs another
        else:
            renderer.set_frames(some, masks)
        self.renderer = self._partial[key]

    def describe(self) -> dict[str, Any]:
        return {**super().describe(), "seq": self.seq, "background_model": self.background.ready,
                "received_at": self.received_at, "source_factor": self.source_factor, **self.timing()}


def _composed(result: RenderResult, overlay: str) -> np.ndarray:
    """The picture sent: the view, the view under its region map, or the depth map."""
    if overlay == "depth":
        return depth_image(result.depth)
    if overlay == "regions":  # tint where there is a surface: by camera where one camera colours it, dark where two blend
        tint = regions_image(result.regions, result.primary)
        mixed = (result.image * (1 - OVERLAY_WEIGHT) + tint * OVERLAY_WEIGHT).round().astype(np.uint8)
        return np.where((result.regions > 0)[..., None], mixed, result.image)
    return result.image


def _one_line(exc: Exception) -> str:
    if isinstance(exc, ValidationError):
        return describe_errors(exc)
    return str(exc).splitlines()[0]
