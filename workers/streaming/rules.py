"""The server's rules as data for the viewer page (app/static): what the page and its browser renderer would
otherwise restate by hand, read off the models and constants that define them, so that each has one home.

- :func:`viewpoint_controls`: what a viewer may ask for (the view socket's hello, ``controls``, in both render
  modes): the choices of every enumerated :class:`Viewpoint` field, in order, its defaults and the planes' range.
- :func:`renderer_rules`: what the browser renderer follows (the hello's ``render.rules``): :class:`RenderOptions`'
  defaults and choices, the codes its shaders take as ``#define`` s (the weightings, the overlays), the constants of
  the server's geometry and depth search, and the fill's visibility rule as a table.

Everything is JSON-able; the browser reads it, never a copy of it (docs/architecture.md, "Where the browser
renderer's rules come from").
"""
from __future__ import annotations

import json
import types
from typing import Any, Literal, Union, get_args, get_origin

from pydantic import BaseModel
from pydantic.fields import FieldInfo

from workers.sweep.kernels import MIN_OCCLUDER_PARALLAX_PX
from workers.sweep.layout import MAX_BITS, Z_MIN
from workers.sweep.occlusion import CONFIRM_TOLERANCE_PX
from workers.sweep.renderer import AUTO_BLEND_FRACTION, FALLBACK_SPACING_RAD, REFINE_RADIUS, RenderOptions
from workers.sweep.rig import NEAR_FAR_RATIO
from workers.sweep.temporal import NEAREST_CAMERAS, STILL_LEVELS
from workers.sweep.weighting import METHOD_CODES

from .params import Viewpoint

CONTROL_FIELDS = ("method", "aggregation", "occlusions", "overlay", "render_quality")
"""The enumerated :class:`Viewpoint` fields a viewer page offers as choices."""


def choices(field: FieldInfo) -> list[Any]:
    """The values a field of Literal type (or an optional one) allows, in their declared order."""
    found: list[Any] = []

    def collect(annotation: Any) -> None:
        if get_origin(annotation) is Literal:
            found.extend(get_args(annotation))
        elif get_origin(annotation) in (Union, types.UnionType):
            for arm in get_args(annotation):
                collect(arm)

    collect(field.annotation)
    return found


def enumerated(model: type[BaseModel]) -> dict[str, list[Any]]:
    """The choices of every field of ``model`` that takes one of a few literal values (and maybe None)."""
    return {name: values for name, field in model.model_fields.items()
            if (values := choices(field)) and len(values) > 1}


def bounds(field: FieldInfo) -> tuple[float | None, float | None]:
    """(least, greatest) value a numeric field allows (``ge``/``gt`` and ``le``/``lt``; None where unbounded)."""
    low = high = None
    for limit in field.metadata:  # annotated_types' Ge, Gt, Le, Lt
        low = getattr(limit, "ge", getattr(limit, "gt", low))
        high = getattr(limit, "le", getattr(limit, "lt", high))
    return low, high


def viewpoint_controls(max_planes: int | None = None) -> dict[str, Any]:
    """What a viewer may ask for: ``choices`` (each of :data:`CONTROL_FIELDS`: its values in order), ``defaults``
    (every :class:`Viewpoint` field's default, JSON: fov in degrees, planes, JPEG quality, ...) and ``planes``
    ({min, max}: the field's limits, the greatest lowered to ``max_planes``, the service's ``max_view_planes``)."""
    fields = Viewpoint.model_fields
    low, high = bounds(fields["planes"])
    if max_planes is not None:
        high = max_planes if high is None else min(high, max_planes)
    return {
        "choices": {name: choices(fields[name]) for name in CONTROL_FIELDS},
        "defaults": Viewpoint().model_dump(mode="json", exclude={"type", "id"}),
        "planes": {"min": low, "max": high},
    }


def visibility_scopes() -> dict[str, dict[str, str]]:
    """:attr:`RenderOptions.visibility_scope` as a table: JSON of ``visibility`` (``"null"``, ``"true"``,
    ``"false"``) -> ``occlusions`` -> scope ("all", "filled" or "none")."""
    occlusions = choices(RenderOptions.model_fields["occlusions"])
    return {json.dumps(v): {o: RenderOptions(visibility=v, occlusions=o).visibility_scope
                            for o in occlusions} for v in (None, True, False)}


def renderer_rules() -> dict[str, Any]:
    """What the browser renderer takes from the server instead of restating it (module docstring):

    - ``defaults``: every :class:`RenderOptions` field's default (JSON; ``fill`` BGR);
    - ``choices``: the values of its enumerated fields, in order;
    - ``codes``: ``method`` (the weightings' codes, :data:`workers.sweep.weighting.METHOD_CODES`) and ``overlay``
      (the position of each :class:`Viewpoint` overlay): the shaders get them as ``#define METHOD_KOJIMA 3``, ...;
    - ``constants``: of the per-view geometry (``near_far_ratio`` of the automatic depth range,
      ``fallback_spacing_rad`` and ``auto_blend_fraction`` of the automatic D_bnd);
    - ``glsl``: the depth search's constants the shaders take as ``#define`` s: ``Z_MIN`` (a point this close to a
      camera's centre plane gets no vote), ``SEARCH_BITS`` (samples at 1 / 2**bits px), ``REFINE_RADIUS`` (the
      coarse choices around a pixel's parent that set its planes), ``CONFIRM_TOLERANCE_PX`` (the cross-view check),
      ``MIN_OCCLUDER_PARALLAX_PX`` (how far a nearer surface must have moved against a point to hide it),
      ``STILL_LEVELS`` and ``NEAREST_CAMERAS`` (what a still scene is, for a view drawn again on a newer frame set:
      :mod:`workers.sweep.temporal`);
    - ``visibility_scope``: where the colour is visibility-aware, by visibility and occlusions
      (:func:`visibility_scopes`).
    """
    return {
        "defaults": RenderOptions().model_dump(mode="json"),
        "choices": enumerated(RenderOptions),
        "codes": {"method": dict(METHOD_CODES),
                  "overlay": {name: i for i, name in enumerate(choices(Viewpoint.model_fields["overlay"]))}},
        "constants": {"near_far_ratio": NEAR_FAR_RATIO, "fallback_spacing_rad": FALLBACK_SPACING_RAD,
                      "auto_blend_fraction": AUTO_BLEND_FRACTION},
        "glsl": {"Z_MIN": Z_MIN, "SEARCH_BITS": MAX_BITS, "REFINE_RADIUS": REFINE_RADIUS,
                 "CONFIRM_TOLERANCE_PX": CONFIRM_TOLERANCE_PX, "MIN_OCCLUDER_PARALLAX_PX": MIN_OCCLUDER_PARALLAX_PX,
                 "STILL_LEVELS": STILL_LEVELS, "NEAREST_CAMERAS": NEAREST_CAMERAS},
        "visibility_scope": visibility_scopes(),
    }
