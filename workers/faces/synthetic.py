"""Procedural training faces, so the face transformer works out of the box.

A face is a grid surface (the front of a head, about 15 x 22 cm, in centimetres, y up and z
towards the viewer) over template coordinates ``(u, v)`` in [-1, 1]^2, shaped by identity
parameters (face size, nose, eyes, brows, cheeks, lips, chin). Expressions are sums of smooth
"actions" (jaw rotation, lip parting, spreading, puckering, funnelling, smiling, squinting,
brow raising) whose shape follows the identity's features, so displacements differ from person
to person.
The six expressions follow the paper's Table 1: uttering a, i, u, o; closed and open smiling.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from workers.faces.dataset import NEUTRAL, FaceDataset
from workers.faces.mesh import Mesh

EXPRESSIONS = ("utter_a", "utter_i", "utter_u", "utter_o", "smile_closed", "smile_open")
ACTIONS = ("jaw_open", "lip_part", "spread", "pucker", "funnel", "smile", "squint", "brow_raise")
RECIPES: dict[str, dict[str, float]] = {
    "utter_a": {"jaw_open": 1.0, "lip_part": 0.8, "spread": 0.1},
    "utter_i": {"jaw_open": 0.25, "lip_part": 0.4, "spread": 0.9},
    "utter_u": {"jaw_open": 0.15, "lip_part": 0.2, "pucker": 1.0},
    "utter_o": {"jaw_open": 0.5, "lip_part": 0.3, "funnel": 1.0},
    "smile_closed": {"smile": 1.0, "spread": 0.4, "squint": 0.5},
    "smile_open": {"smile": 1.0, "spread": 0.4, "squint": 0.6, "jaw_open": 0.5, "lip_part": 0.7},
}
# Identity parameters: mean and standard deviation (lengths in cm, positions in template units).
IDENTITY = {
    "half_width": (7.5, 0.5), "half_height": (11.0, 0.7), "depth": (9.0, 0.5),
    "nose": (2.2, 0.35), "nose_width": (0.16, 0.02), "eye_depth": (0.9, 0.2), "eye_sep": (0.36, 0.03),
    "brow": (0.5, 0.15), "cheek": (0.6, 0.2), "mouth_width": (0.27, 0.03), "lip": (0.45, 0.1),
    "chin": (0.8, 0.2), "jaw_narrow": (0.3, 0.06), "mouth_y": (-0.45, 0.03),
}


@dataclass(frozen=True)
class Template:
    """The grid: ``u``, ``v`` (N,) float64 template coordinates and ``faces`` (F, 3) int64 triangles."""

    u: np.ndarray
    v: np.ndarray
    faces: np.ndarray


def template(rows: int = 64, cols: int = 56) -> Template:
    """A rows x cols vertex grid over [-1, 1]^2 split into triangles (front-facing, z towards the viewer)."""
    v, u = np.meshgrid(np.linspace(1.0, -1.0, rows), np.linspace(-1.0, 1.0, cols), indexing="ij")
    idx = np.arange(rows * cols).reshape(rows, cols)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    faces = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3), np.stack([b, c, d], -1).reshape(-1, 3)])
    return Template(u.ravel(), v.ravel(), faces.astype(np.int64))


def random_identity(rng: np.random.Generator) -> dict[str, float]:
    """Identity parameters drawn from ``IDENTITY`` (independent normals)."""
    return {k: float(mu + sd * rng.standard_normal()) for k, (mu, sd) in IDENTITY.items()}


def _bump(du: np.ndarray, dv: np.ndarray, su: float, sv: float) -> np.ndarray:
    return np.exp(-((du / su) ** 2) - (dv / sv) ** 2)


def neutral_face(tpl: Template, idp: dict[str, float]) -> np.ndarray:
    """(N, 3) float64 neutral face (cm) of identity parameters ``idp`` on template ``tpl``."""
    u, v = tpl.u, tpl.v
    au = np.abs(u)
    theta = 1.2 * u
    x = idp["half_width"] * np.sin(theta) * (1.0 - idp["jaw_narrow"] * np.clip(-v, 0, 1) ** 2)
    y = idp["half_height"] * v
    z = idp["depth"] * np.cos(theta) * np.sqrt(np.clip(1.0 - 0.35 * v**2, 0.0, None))
    my, mw = idp["mouth_y"], idp["mouth_width"]
    z = z + idp["nose"] * (_bump(u, v + 0.1, idp["nose_width"], 0.22)
                           + 0.4 * _bump(u, v - 0.12, 0.8 * idp["nose_width"], 0.25))
    z = z - idp["eye_depth"] * _bump(au - idp["eye_sep"], v - 0.22, 0.14, 0.09)
    z = z + idp["brow"] * _bump(au - idp["eye_sep"], v - 0.36, 0.22, 0.06)
    z = z + idp["cheek"] * _bump(au - 0.42, v + 0.1, 0.16, 0.16)
    z = z + idp["lip"] * (_bump(u, v - my - 0.035, 0.9 * mw, 0.035) + _bump(u, v - my + 0.05, 0.8 * mw, 0.045))
    z = z - 0.3 * _bump(u, v - my, mw, 0.012)
    z = z + idp["chin"] * _bump(u, v + 0.8, 0.25, 0.12)
    return np.stack([x, y, z], axis=1)


def expression_displacement(
    tpl: Template, idp: dict[str, float], neutral: np.ndarray, actions: dict[str, float], asymmetry: float = 0.0
) -> np.ndarray:
    """(N, 3) float64 displacement (cm) of an expression given as action amounts (about 0-1).

    ``neutral``: the (N, 3) neutral face of ``idp``; ``asymmetry`` scales the left and right
    halves by ``1 -/+ asymmetry`` (real expressions are rarely symmetric).
    """
    disp = np.zeros_like(neutral)
    if actions.get("jaw_open", 0.0):
        disp += _jaw(neutral, tpl.v, tpl.u, idp, 0.35 * actions["jaw_open"])
    for name, field in _ACTION_FIELDS.items():
        if actions.get(name, 0.0):
            disp += actions[name] * field(tpl.u, tpl.v, idp)
    # Parted lips show the mouth cavity: the lip line sinks in, more with an open jaw.
    cavity = 1.2 * actions.get("lip_part", 0.0) + 0.8 * actions.get("jaw_open", 0.0)
    disp[:, 2] -= cavity * _bump(tpl.u, tpl.v - idp["mouth_y"] + 0.01, 0.8 * idp["mouth_width"], 0.04)
    return disp * (1.0 - asymmetry * np.tanh(tpl.u / 0.3))[:, None]


def _mouth(u: np.ndarray, v: np.ndarray, idp: dict[str, float]) -> np.ndarray:
    return _bump(u, v - idp["mouth_y"], 1.6 * idp["mouth_width"], 0.12)


def _xyz(x: np.ndarray | float, y: np.ndarray | float, z: np.ndarray | float, n: int) -> np.ndarray:
    return np.stack(np.broadcast_arrays(x, y, z, np.zeros(n))[:3], axis=1)


def _lip_part(u: np.ndarray, v: np.ndarray, idp: dict[str, float]) -> np.ndarray:
    """Upper lip up, lower lip down (cm per unit amount)."""
    my, mw = idp["mouth_y"], idp["mouth_width"]
    return _xyz(0.0, 0.4 * _bump(u, v - my - 0.04, mw, 0.06) - 0.5 * _bump(u, v - my + 0.06, mw, 0.07), 0.0, len(u))


def _spread(u: np.ndarray, v: np.ndarray, idp: dict[str, float]) -> np.ndarray:
    """Mouth corners outwards, lips flattened."""
    my, mw = idp["mouth_y"], idp["mouth_width"]
    return _xyz(0.9 * np.tanh(u / mw) * _mouth(u, v, idp), 0.0, -0.2 * _bump(u, v - my, mw, 0.06), len(u))


def _pucker(u: np.ndarray, v: np.ndarray, idp: dict[str, float]) -> np.ndarray:
    """Mouth drawn together and pushed forward."""
    my, mw = idp["mouth_y"], idp["mouth_width"]
    return _xyz(-0.7 * np.tanh(u / mw) * _mouth(u, v, idp), 0.0, 1.2 * _bump(u, v - my, 1.1 * mw, 0.1), len(u))


def _funnel(u: np.ndarray, v: np.ndarray, idp: dict[str, float]) -> np.ndarray:
    """Rounded lips: corners in, lips apart and flared forward, a dark opening in the middle."""
    my, mw = idp["mouth_y"], idp["mouth_width"]
    upper, lower = _bump(u, v - my - 0.05, 0.8 * mw, 0.04), _bump(u, v - my + 0.07, 0.8 * mw, 0.05)
    return _xyz(-0.5 * np.tanh(u / mw) * _mouth(u, v, idp), 0.35 * upper - 0.45 * lower,
                0.5 * (upper + lower) - 0.8 * _bump(u, v - my, 0.5 * mw, 0.04), len(u))


def _smile(u: np.ndarray, v: np.ndarray, idp: dict[str, float]) -> np.ndarray:
    """Mouth corners up, out and back; cheeks raised and bulging."""
    corner = _bump(np.abs(u) - idp["mouth_width"], v - idp["mouth_y"], 0.12, 0.1)
    cheek = _bump(np.abs(u) - 0.42, v + 0.1, 0.18, 0.18)
    return _xyz(0.3 * np.sign(u) * corner, 0.7 * corner + 0.35 * cheek, -0.3 * corner + 0.3 * cheek, len(u))


def _squint(u: np.ndarray, v: np.ndarray, idp: dict[str, float]) -> np.ndarray:
    """Lower eyelids up."""
    return _xyz(0.0, 0.25 * _bump(np.abs(u) - idp["eye_sep"], v - 0.15, 0.15, 0.05), 0.0, len(u))


def _brow_raise(u: np.ndarray, v: np.ndarray, idp: dict[str, float]) -> np.ndarray:
    return _xyz(0.0, 0.4 * _bump(np.abs(u) - idp["eye_sep"], v - 0.36, 0.25, 0.1), 0.0, len(u))


_ACTION_FIELDS = {"lip_part": _lip_part, "spread": _spread, "pucker": _pucker, "funnel": _funnel,
                  "smile": _smile, "squint": _squint, "brow_raise": _brow_raise}


def _jaw(neutral: np.ndarray, v: np.ndarray, u: np.ndarray, idp: dict[str, float], angle: float) -> np.ndarray:
    """Displacement of rotating the lower face by ``angle`` (rad) about a horizontal axis near the ears."""
    lower = 1.0 / (1.0 + np.exp(-(idp["mouth_y"] - v) / 0.03)) * np.exp(-((u / 0.8) ** 4))
    pivot_y, pivot_z = idp["half_height"] * (idp["mouth_y"] + 0.4), -0.3 * idp["depth"]
    ry, rz = neutral[:, 1] - pivot_y, neutral[:, 2] - pivot_z
    c, s = np.cos(angle), np.sin(angle)
    disp = np.zeros_like(neutral)
    disp[:, 1] = (ry * c - rz * s - ry) * lower
    disp[:, 2] = (ry * s + rz * c - rz) * lower
    return disp


@dataclass(frozen=True)
class Person:
    """One synthetic person: identity parameters and personal expression style (per-action gains)."""

    identity: dict[str, float]
    style: dict[str, float]
    asymmetry: float


def random_person(rng: np.random.Generator) -> Person:
    """A person with random identity, action gains ``exp(0.15 N(0,1))`` and asymmetry ``N(0, 0.08)``."""
    style = {k: float(np.exp(0.15 * rng.standard_normal())) for k in ACTIONS}
    return Person(random_identity(rng), style, float(0.08 * rng.standard_normal()))


def expression_face(
    tpl: Template, person: Person, expression: str, intensity: float = 1.0,
    nuisance: dict[str, float] | None = None,
) -> np.ndarray:
    """(N, 3) float64 face of ``person`` showing ``expression`` (or ``"neutral"``) at ``intensity``.

    ``nuisance``: extra action amounts (e.g. a little brow raise) added on top of the recipe.
    """
    neutral = neutral_face(tpl, person.identity)
    if expression == NEUTRAL:
        return neutral
    if expression not in RECIPES:
        raise ValueError(f"unknown synthetic expression {expression!r}; known: {', '.join(RECIPES)}")
    actions = {k: intensity * w * person.style[k] for k, w in RECIPES[expression].items()}
    for k, w in (nuisance or {}).items():
        actions[k] = actions.get(k, 0.0) + w
    return neutral + expression_displacement(tpl, person.identity, neutral, actions, person.asymmetry)


def generate_dataset(
    people: int = 40, seed: int = 0, intensity: tuple[float, float] = (0.7, 1.0),
    noise_cm: float = 0.01, tpl: Template | None = None,
) -> FaceDataset:
    """``people`` x (neutral + the six expressions): the paper's 40 x 7 = 280 faces by default.

    Each expression face gets an intensity uniform in ``intensity``, small random brow/squint
    nuisance actions, and every face Gaussian "scanner" noise of ``noise_cm`` per coordinate.
    """
    rng = np.random.default_rng(seed)
    tpl = tpl or template()
    faces, persons, labels = [], [], []
    for p in range(people):
        person = random_person(rng)
        for expression in (NEUTRAL, *EXPRESSIONS):
            nuisance = {"brow_raise": 0.15 * rng.standard_normal(), "squint": 0.1 * abs(rng.standard_normal())}
            amount = rng.uniform(*intensity)
            face = expression_face(tpl, person, expression, amount, None if expression == NEUTRAL else nuisance)
            faces.append(face + noise_cm * rng.standard_normal(face.shape))
            persons.append(f"p{p:03d}")
            labels.append(expression)
    topology = Mesh.from_faces(faces[0], tpl.faces)
    return FaceDataset(np.stack(faces), np.array(persons), np.array(labels), topology)


