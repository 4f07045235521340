"""Validated messages and job parameters of the streaming service (pydantic, extra fields refused).

- :class:`Viewpoint`: one message of a viewer socket: where to look from, output size, method,
  ``D_bnd``, planes, frame index or ``"live"``, overlay, JPEG quality.
- :class:`RecordingImportParams`: job ``streaming.recording`` (decode uploaded videos or image folders).
- :class:`BatchRenderParams`: job ``streaming.render`` (a camera path -> H.264 MP4 + depth PNGs).
- :class:`DemoParams`: job ``streaming.demo`` (the procedural demo recording).

Angles are degrees; lengths metres in the rig's world frame; sizes pixels. NaN and infinities
are refused everywhere (``allow_inf_nan=False``).
"""
from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, create_model, model_validator
from pydantic.fields import FieldInfo

from workers.sweep.renderer import RenderOptions

from .quality import LEVEL_FIELDS, Quality, level_options

Vec3 = tuple[float, float, float]
STRICT = ConfigDict(extra="forbid", allow_inf_nan=False)


class Orbit(BaseModel):
    """A camera on a sphere around the rig's focus point, looking at it with the rig's up shown upwards.

    azimuth: turn about the rig's up axis, 0 = the rig cameras' mean direction, positive =
    anticlockwise seen from above. elevation: above the horizontal plane (None: the rig cameras' mean).
    distance: from the target (None: the cameras' mean). target: None = the rig's focus point.
    """

    model_config = STRICT
    azimuth: float = Field(0.0, ge=-3600.0, le=3600.0)
    elevation: float | None = Field(None, ge=-89.0, le=89.0)
    distance: float | None = Field(None, gt=0.0, le=1e5)
    target: Vec3 | None = None


class LookAt(BaseModel):
    """A camera at ``eye`` looking at ``target``; ``up`` (None: the rig's up) shown upwards."""

    model_config = STRICT
    eye: Vec3
    target: Vec3
    up: Vec3 | None = None


class Pose(BaseModel):
    """A world-to-camera pose: ``x_cam = R X + t`` (R a rotation, 3 rows of 3)."""

    model_config = STRICT
    R: tuple[Vec3, Vec3, Vec3]
    t: Vec3


class ViewPose(BaseModel):
    """Where a virtual camera is: exactly one of ``orbit``, ``look_at`` or ``pose`` (none: the
    rig's home orbit), and its horizontal field of view ``fov`` in degrees."""

    model_config = STRICT
    orbit: Orbit | None = None
    look_at: LookAt | None = None
    pose: Pose | None = None
    fov: float = Field(50.0, ge=5.0, le=150.0)

    @model_validator(mode="after")
    def _one_pose(self) -> "ViewPose":
        given = [n for n in ("orbit", "look_at", "pose") if getattr(self, n) is not None]
        if len(given) > 1:
            raise ValueError(f"give one of orbit, look_at or pose, not {' and '.join(given)}")
        return self


CLIENT_RENDER_FIELDS = ("method", "d_bnd", "k", "planes", "near", "far", "visual_hull", "coarse_to_fine",
                        "aggregation", "visibility", "occlusions")
"""The renderer options a viewer or a batch render may set: :class:`RenderOptions`' own fields (types, limits,
descriptions), read off it; ``coarse_to_fine`` defaults otherwise (on: a viewer's views are live), and the options
a quality level decides (:data:`workers.streaming.quality.LEVEL_FIELDS`) default to None: the level's."""


def _client_field(name: str) -> tuple[object, FieldInfo]:
    info = RenderOptions.model_fields[name]
    if name == "coarse_to_fine":
        return info.annotation, FieldInfo.merge_field_infos(info, default=True)
    if name in LEVEL_FIELDS:
        return info.annotation | None, FieldInfo.merge_field_infos(
            info, default=None, description=f"{info.description}. None (the default): as the quality level says "
                                            "(workers.streaming.quality); a value here makes the level 'custom'")
    return info.annotation, info


_RenderFields = create_model("SweepSettings", __config__=STRICT,
                             **{name: _client_field(name) for name in CLIENT_RENDER_FIELDS})


class SweepSettings(_RenderFields):
    """Renderer options a client may set (see :class:`workers.sweep.renderer.RenderOptions`)."""

    @model_validator(mode="after")
    def _near_far(self) -> "SweepSettings":
        if self.near is not None and self.far is not None and not self.near < self.far:
            raise ValueError(f"near ({self.near}) must be less than far ({self.far})")
        return self

    def render_fields(self, level: str) -> tuple[dict, str]:
        """The fields :class:`RenderOptions` takes, those a quality level decides from ``level`` ("best" or
        "fast") where this request leaves them None; and what runs: the level, or "custom" where the request's own
        values differ from it."""
        fields = self.model_dump(include=set(CLIENT_RENDER_FIELDS))
        decided, name = level_options(level, {k: fields[k] for k in LEVEL_FIELDS})
        return {**fields, **decided}, name


class Viewpoint(ViewPose, SweepSettings):
    """One viewer message: pose, output ``width`` x ``height``, renderer settings, which frame
    (a recording frame index, or ``"live"``), an ``overlay`` (``regions``: by the number of cameras
    blended, 1 / 2 / 3+; or ``depth``), the JPEG ``quality`` and the picture's ``render_quality`` (a level of
    :mod:`workers.streaming.quality`: "auto" draws "best" where the session holds the viewer's target rate with it,
    else "fast"). ``id`` is echoed in the answer's header."""

    model_config = STRICT
    type: Literal["view"] = "view"
    id: int | None = Field(None, ge=0, le=2**53)
    width: int = Field(320, ge=16, le=8192)
    height: int = Field(240, ge=16, le=8192)
    frame: int | Literal["live"] = 0
    overlay: Literal["none", "regions", "depth"] = "none"
    quality: int = Field(80, ge=20, le=95)
    render_quality: Quality = Field("auto", description="the picture's quality level: 'best' (semi-global depth, "
                                    "occlusion fill), 'fast' (semi-global depth as searched) or 'auto' (best where "
                                    "the session holds the viewer's target rate with it, else fast); an aggregation "
                                    "or occlusions given here overrides the level's")

    @model_validator(mode="after")
    def _frame(self) -> "Viewpoint":
        if isinstance(self.frame, int) and self.frame < 0:
            raise ValueError(f"frame must be >= 0 or 'live', got {self.frame}")
        return self


class RecordingRequest(BaseModel):
    """The ``params`` form field of a new recording."""

    model_config = STRICT
    name: str | None = Field(None, max_length=200)
    fps: float | None = Field(None, gt=0.0, le=1000.0, description="frame rate of image folders (default 25)")


ARCHIVE_INPUT = "archive"
"""The input name of a recording's zip of image folders (the upload route names its inputs, the job reads them)."""


def media_input(i: int) -> str:
    """The input name of the ``i``-th video of a recording."""
    return f"media-{i:03d}"


def background_input(i: int) -> str:
    """The input name of the ``i``-th background image of a recording."""
    return f"background-{i:03d}"


class RecordingImportParams(BaseModel):
    """Job ``streaming.recording``: inputs ``rig`` (our rig JSON), ``media-NNN`` (one video per
    camera, or one zip ``archive`` of per-camera image folders) and optional ``background-NNN``
    (empty-scene images). ``cameras[i]`` is the rig index of ``media-i``; ``backgrounds[i]`` that
    of ``background-i``."""

    model_config = STRICT
    rig_id: str
    source: Literal["videos", "images"]
    cameras: list[int] = Field(default_factory=list)
    backgrounds: list[int] = Field(default_factory=list)
    fps: float | None = Field(None, gt=0.0, le=1000.0)
    max_frames: int = Field(3000, ge=1, le=1_000_000)
    name: str | None = Field(None, max_length=200)


class OrbitPath(BaseModel):
    """A camera path around the rig: azimuth from ``azimuth_from`` to ``azimuth_to`` (degrees)."""

    model_config = STRICT
    azimuth_from: float = Field(-45.0, ge=-3600.0, le=3600.0)
    azimuth_to: float = Field(45.0, ge=-3600.0, le=3600.0)
    elevation: float | None = Field(None, ge=-89.0, le=89.0)
    distance: float | None = Field(None, gt=0.0, le=1e5)
    target: Vec3 | None = None
    fov: float = Field(50.0, ge=5.0, le=150.0)


class Keyframe(ViewPose):
    """One key pose of a path; ``at`` in [0, 1] is where along the path (None: evenly spaced)."""

    at: float | None = Field(None, ge=0.0, le=1.0)


class BatchRenderParams(SweepSettings):
    """Job ``streaming.render``: a camera path (``orbit`` or ``keyframes``) over the recording's
    frames ``frame_start``..``frame_end`` (inclusive; None: the last), ``frames`` output frames
    (None: one per recording frame in the range), H.264 at ``fps`` (None: the recording's) with
    quality ``crf``, ``width`` x ``height`` (even), the picture's ``render_quality`` (default "best": nobody
    waits for a frame). Inputs ``rig`` and ``recording``."""

    recording_id: str
    orbit: OrbitPath | None = None
    keyframes: list[Keyframe] | None = Field(None, min_length=2, max_length=200)
    frame_start: int = Field(0, ge=0)
    frame_end: int | None = Field(None, ge=0)
    frames: int | None = Field(None, ge=1, le=100_000)
    fps: float | None = Field(None, gt=0.0, le=240.0)
    width: int = Field(640, ge=16, le=8192, multiple_of=2)
    height: int = Field(480, ge=16, le=8192, multiple_of=2)
    crf: int = Field(20, ge=0, le=51)
    coarse_to_fine: bool = False
    render_quality: Literal["best", "fast"] = Field("best", description="the picture's quality level "
                                                    "(workers.streaming.quality); an aggregation or occlusions "
                                                    "given here overrides the level's")

    @model_validator(mode="after")
    def _path(self) -> "BatchRenderParams":
        if (self.orbit is None) == (self.keyframes is None):
            raise ValueError("give exactly one camera path: 'orbit' or 'keyframes'")
        if self.frame_end is not None and self.frame_end < self.frame_start:
            raise ValueError(f"frame_end ({self.frame_end}) is before frame_start ({self.frame_start})")
        if self.keyframes is not None:
            ats = [k.at for k in self.keyframes]
            if any(a is not None for a in ats):
                if any(a is None for a in ats) or any(b <= a for a, b in zip(ats, ats[1:])):
                    raise ValueError("keyframe 'at' values must be given for all keyframes and increase")
        return self


class DemoParams(BaseModel):
    """Job ``streaming.demo``: the procedural studio seen by the rig of input ``rig``, ``frames``
    frames of a small sphere circling the object group, at ``fps``."""

    model_config = STRICT
    frames: int = Field(12, ge=1, le=600)
    fps: float = Field(6.0, gt=0.0, le=120.0)
