"""Rig importers (our JSON, COLMAP text, OpenCV FileStorage YAML, Middlebury ``_par.txt``, rectified
Middlebury stereo sets) and image loading. Every importer returns a :class:`Rig` in our conventions
(``x_cam = R X + t``, pixel (0, 0) at the centre of the top-left pixel); malformed input raises
:class:`RigError` or :class:`CameraError` (both :class:`~workers.common.errors.InputError`, so ``ValueError``)
naming the camera and field.

Our JSON::

    {"cameras": [{"name": "cam00", "K": [[fx,0,cx],[0,fy,cy],[0,0,1]], "R": [[...]x3],
                  "t": [tx,ty,tz] (or "center": [x,y,z]), "width": 640, "height": 480,
                  "dist": [k1,k2,p1,p2,k3] (optional), "image": "cam00.png" (optional)}, ...],
     "depth_range": [near, far] (optional)}

A plain camera list (the layout CMU Panoptic's ``calibration_*.json`` ships, and many studio domes,
sports rigs and webcam arrays use)::

    {"cameras": [{"name": "00_00", "type": "hd" (optional), "resolution": [1920, 1080],
                  "K": [[fx,0,cx],[0,fy,cy],[0,0,1]], "distCoef": [k1,k2,p1,p2,k3] (optional),
                  "R": [[...]x3] (world-to-camera), "t": [[tx],[ty],[tz]] (3x1 or 3)}, ...]}

(or the bare list). Its ``t`` is in any unit: :func:`load_rig` takes the unit (``units``), by default
centimetres (:data:`DEFAULT_UNITS`), Panoptic's. Pixel (0, 0) is taken as the centre of the top-left
pixel, as in OpenCV (Panoptic's ``projectPoints`` is OpenCV's).

OpenCV FileStorage (YAML/XML): a sequence ``cameras`` of maps with ``name``, ``K`` (or
``camera_matrix``), ``dist`` (or ``distortion_coefficients``, ``D``), ``R`` (3x3, or a 3-vector
Rodrigues ``rvec``), ``t`` (or ``T``, ``tvec``), ``width``/``height`` (or ``image_width``/
``image_height``), optional ``image``; or one such map at the top level (a single camera file).
"""
from __future__ import annotations

import json
import re
import tempfile
from pathlib import Path
from typing import Any, Sequence

import cv2
import numpy as np

from workers.camera import Camera, CameraError, quat_to_rotation
from workers.common.errors import InputError

from .rig import Rig, RigError

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".ppm", ".pgm", ".webp")


# --- our JSON ---------------------------------------------------------------------------------
def rig_from_dict(d: dict[str, Any]) -> Rig:
    """A rig from our JSON structure (see the module docstring)."""
    cams_in = d.get("cameras") if isinstance(d, dict) else None
    if not isinstance(cams_in, list):
        raise RigError(None, "cameras", "missing or not a list")
    cams = []
    files = []
    for i, cd in enumerate(cams_in):
        if not isinstance(cd, dict):
            raise RigError(f"#{i}", "camera", "is not an object")
        cam = Camera.from_dict(cd, name=f"#{i}")
        cams.append(cam)
        files.append(str(cd.get("image", cam.name)))
    dr = d.get("depth_range")
    return Rig(tuple(cams), tuple(files), tuple(dr) if dr is not None else None)


def rig_to_dict(rig: Rig) -> dict[str, Any]:
    """Our JSON structure for ``rig``."""
    cams = []
    for cam, f in zip(rig.cameras, rig.image_files):
        d = cam.to_dict()
        d["image"] = f
        cams.append(d)
    out: dict[str, Any] = {"cameras": cams}
    if rig.depth_range is not None:
        out["depth_range"] = list(rig.depth_range)
    return out


def load_rig_json(path: str | Path) -> Rig:
    """Read our JSON rig file."""
    return rig_from_dict(_read_json(path))


def _read_json(path: str | Path) -> Any:
    try:
        return json.loads(Path(path).read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise RigError(None, "file", f"{Path(path).name} is not valid JSON ({e})") from None
    except RecursionError:  # "[[[[...]]]]": json's recursive parser runs out of stack
        raise RigError(None, "file", f"{Path(path).name} nests too deeply to be a rig") from None


def save_rig_json(rig: Rig, path: str | Path) -> None:
    """Write ``rig`` as our JSON."""
    Path(path).write_text(json.dumps(rig_to_dict(rig), indent=1))


# --- a plain camera list (CMU Panoptic) -------------------------------------------------------
CAMERA_LIST = "camera_list"
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}
"""Unit names :func:`metres_per_unit` understands, in metres."""
DEFAULT_UNITS = {CAMERA_LIST: "cm"}
"""The unit of ``t`` when the upload names none, per format; every other format is read in metres."""
_LIST_KEYS = ("resolution", "distCoef")


def is_camera_list(d: Any) -> bool:
    """Whether parsed JSON ``d`` is a plain camera list (its cameras have ``resolution`` or ``distCoef``
    and no ``width``) rather than our rig JSON."""
    cams = d if isinstance(d, list) else d.get("cameras") if isinstance(d, dict) else None
    if not isinstance(cams, list) or not cams:
        return False
    entries = [c for c in cams if isinstance(c, dict)]
    return (any(k in c for c in entries for k in _LIST_KEYS) and not any("width" in c for c in entries))


def rig_from_camera_list(d: Any, metres_per_unit: float = UNITS[DEFAULT_UNITS[CAMERA_LIST]],
                         camera_type: str | None = None) -> Rig:
    """A rig from a plain camera list (see the module docstring), ``t`` scaled to metres by
    ``metres_per_unit``; ``camera_type`` keeps only the cameras of that ``type`` (Panoptic mixes "vga",
    "hd" and "kinect-color" cameras in one file).

    Validated strictly, naming the camera and field: ``resolution`` two positive integers, ``K`` 3x3
    upper triangular with positive focal lengths, ``distCoef`` 4, 5, 8, 12 or 14 numbers, ``R`` a 3x3
    rotation (orthonormal within 1e-5, det +1), ``t`` 3 numbers (3 or 3x1), all finite; names unique."""
    cams_in = d if isinstance(d, list) else d.get("cameras") if isinstance(d, dict) else None
    if not isinstance(cams_in, list):
        raise RigError(None, "cameras", "missing or not a list")
    cams = []
    types = set()
    for i, cd in enumerate(cams_in):
        if not isinstance(cd, dict):
            raise RigError(f"#{i}", "camera", "is not an object")
        name = str(cd.get("name", f"#{i}"))
        kind = cd.get("type")
        types.add(str(kind))
        if camera_type is not None and kind != camera_type:
            continue
        for key in ("K", "R", "t", "resolution"):
            if key not in cd:
                raise CameraError(name, key, "missing")
        res = cd["resolution"]
        if (not isinstance(res, list) or len(res) != 2
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and v > 0 and v == int(v)
                           for v in res)):
            raise CameraError(name, "resolution", f"must be [width, height], two positive integers, got {res!r}")
        t = _vector3(name, cd["t"]) * float(metres_per_unit)
        cams.append(Camera(name, cd["K"], cd["R"], t, int(res[0]), int(res[1]), cd.get("distCoef")))
    if camera_type is not None and not cams:
        raise RigError(None, "camera_type", f"no camera of type {camera_type!r} (the file has: "
                                            f"{', '.join(sorted(types))})")
    return Rig(tuple(cams))


def _vector3(name: str, t: Any) -> np.ndarray:
    try:
        v = np.array(t, dtype=np.float64)
    except (TypeError, ValueError):
        raise CameraError(name, "t", "is not numeric") from None
    if v.shape not in ((3,), (3, 1), (1, 3)):
        raise CameraError(name, "t", f"must be 3 numbers (3 or 3x1), got shape {v.shape}")
    return v.reshape(3)


def metres_per_unit(units: str | float | None, fmt: str) -> float:
    """Metres per unit of a rig file's translations: ``units`` is a name of :data:`UNITS` ("m", "cm",
    "mm"), a positive number of metres per unit (as a number or text, e.g. "0.0254" for inches), or
    None for the format's default (:data:`DEFAULT_UNITS`; metres for formats not listed there).
    RigError (field ``units``) for anything else."""
    if units is None:
        units = DEFAULT_UNITS.get(fmt, "m")
    if isinstance(units, str):
        key = units.strip().lower()
        if key in UNITS:
            return UNITS[key]
        try:
            units = float(key)
        except ValueError:
            raise RigError(None, "units", f"{units!r} is not a unit ({', '.join(UNITS)}) nor a number of metres "
                                          f"per unit") from None
    f = float(units)
    if not (np.isfinite(f) and f > 0):
        raise RigError(None, "units", f"must be a positive number of metres per unit, got {units!r}")
    return f


# --- COLMAP text ------------------------------------------------------------------------------
# model -> (parameter names); distortion follows OpenCV's order
_COLMAP_MODELS = {
    "SIMPLE_PINHOLE": ("f", "cx", "cy"),
    "PINHOLE": ("fx", "fy", "cx", "cy"),
    "SIMPLE_RADIAL": ("f", "cx", "cy", "k1"),
    "RADIAL": ("f", "cx", "cy", "k1", "k2"),
    "OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"),
    "FULL_OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"),
}


def load_colmap_text(folder: str | Path) -> Rig:
    """Read COLMAP's ``cameras.txt`` + ``images.txt`` from ``folder``.

    COLMAP puts pixel (0, 0) at the top-left corner of the image, so the principal point moves by
    -0.5 px into our convention. Camera names are the image names.
    """
    folder = Path(folder)
    intrinsics = _colmap_cameras(folder / "cameras.txt")
    lines = [ln.rstrip("\n") for ln in (folder / "images.txt").read_text().splitlines() if not ln.startswith("#")]
    cams = []
    i = 0
    while i < len(lines):
        tok = lines[i].split()
        if not tok:
            i += 1
            continue
        if len(tok) < 10:
            raise RigError(None, "images.txt", f"line {lines[i]!r} is not 'IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME'")
        name = " ".join(tok[9:])
        try:
            q = np.array(tok[1:5], float)
            t = np.array(tok[5:8], float)
            cam_id = int(tok[8])
        except ValueError:
            raise RigError(name, "pose", f"unreadable numbers in {lines[i]!r}") from None
        if cam_id not in intrinsics:
            raise RigError(name, "CAMERA_ID", f"camera {cam_id} is not in cameras.txt")
        if not np.linalg.norm(q) > 0:
            raise RigError(name, "R", "zero quaternion")
        K, dist, w, h = intrinsics[cam_id]
        cams.append(Camera(name, K, quat_to_rotation(q), t, w, h, dist))
        i += 2  # the next line holds the image's 2D points (possibly empty)
    return Rig(tuple(cams))


def _colmap_cameras(path: Path) -> dict[int, tuple[np.ndarray, np.ndarray | None, int, int]]:
    out = {}
    for ln in path.read_text().splitlines():
        tok = ln.split()
        if not tok or ln.startswith("#"):
            continue
        cid, model = tok[0], tok[1]
        if model not in _COLMAP_MODELS:
            raise RigError(f"camera {cid}", "model", f"{model} is not supported ({', '.join(_COLMAP_MODELS)})")
        names = _COLMAP_MODELS[model]
        try:
            w, h = int(tok[2]), int(tok[3])
            vals = dict(zip(names, map(float, tok[4:])))
        except ValueError:
            raise RigError(f"camera {cid}", "params", f"unreadable numbers in {ln!r}") from None
        if len(tok) - 4 != len(names):
            raise RigError(f"camera {cid}", "params", f"{model} needs {len(names)} parameters, got {len(tok) - 4}")
        fx = vals.get("fx", vals.get("f"))
        fy = vals.get("fy", vals.get("f"))
        K = np.array([[fx, 0, vals["cx"] - 0.5], [0, fy, vals["cy"] - 0.5], [0, 0, 1]])
        dist = None
        if "k1" in vals:
            d = [vals.get(k, 0.0) for k in ("k1", "k2", "p1", "p2")]
            if model == "FULL_OPENCV":
                d += [vals[k] for k in ("k3", "k4", "k5", "k6")]
            dist = np.array(d)
        out[int(cid)] = (K, dist, w, h)
    return out


# --- OpenCV FileStorage -----------------------------------------------------------------------
_YAML_KEYS = {
    "K": ("K", "camera_matrix", "cameraMatrix"),
    "dist": ("dist", "distortion_coefficients", "dist_coeffs", "distCoeffs", "D"),
    "R": ("R", "rotation", "rvec"),
    "t": ("t", "T", "tvec", "translation"),
    "width": ("width", "image_width"),
    "height": ("height", "image_height"),
}


def load_opencv_yaml(path: str | Path) -> Rig:
    """Read an OpenCV FileStorage file (YAML or XML) in the layout of the module docstring."""
    path = Path(path)
    try:
        return _read_file_storage(path)
    except (cv2.error, SystemError) as exc:  # OpenCV's parser fails with these on malformed text
        cause = exc if isinstance(exc, cv2.error) else exc.__cause__
        detail = re.sub(r"^OpenCV\([^)]*\) \S+ error: \([^)]*\) ", "", " ".join(str(cause or exc).split()))
        raise RigError(None, "file", f"{path.name} is not a valid OpenCV FileStorage file ({detail})") from None


def _read_file_storage(path: Path) -> Rig:
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    if not fs.isOpened():
        raise RigError(None, "file", f"{path.name} is not a valid OpenCV FileStorage file")
    try:
        seq = fs.getNode("cameras")
        nodes = [seq.at(i) for i in range(seq.size())] if seq.isSeq() else [fs.root()]
        cams, files = [], []
        for i, node in enumerate(nodes):
            name_node = node.getNode("name")
            name = name_node.string() if not name_node.empty() else (f"#{i}" if seq.isSeq() else path.stem)
            cams.append(_camera_from_node(node, name))
            img = node.getNode("image")
            files.append(img.string() if not img.empty() else name)
    finally:
        fs.release()
    return Rig(tuple(cams), tuple(files))


def _camera_from_node(node: Any, name: str) -> Camera:
    def get(key: str, required: bool = True) -> Any:
        for alias in _YAML_KEYS[key]:
            n = node.getNode(alias)
            if not n.empty():
                return n
        if required:
            raise CameraError(name, key, f"missing (any of {', '.join(_YAML_KEYS[key])})")
        return None

    K = get("K").mat()
    rn = get("R")
    R = rn.mat()
    if R is None:
        raise CameraError(name, "R", "is not a matrix")
    if R.size == 3:
        R, _ = cv2.Rodrigues(R.astype(np.float64).reshape(3, 1))
    tn = get("t").mat()
    dn = get("dist", required=False)
    dist = dn.mat() if dn is not None else None
    return Camera(name, K, R, None if tn is None else tn.ravel(), get("width").real(), get("height").real(),
                  None if dist is None else dist.ravel())


# --- Middlebury -------------------------------------------------------------------------------
def load_middlebury_par(path: str | Path, width: int | None = None, height: int | None = None) -> Rig:
    """Read a Middlebury multi-view ``*_par.txt`` (``name k11..k33 r11..r33 t1 t2 t3`` per line,
    P = K [R | t], image origin top-left, after a first line with the count).

    The image size comes from ``width``/``height`` or, when not given, from the first image beside the file.
    """
    path = Path(path)
    rows = [ln.split() for ln in path.read_text().splitlines() if ln.strip()]
    if not rows:
        raise RigError(None, "file", f"{path} is empty")
    try:
        count = int(rows[0][0])
    except ValueError:
        raise RigError(None, "count", f"first line of {path.name} must be the number of views") from None
    entries = rows[1:]
    if len(entries) != count:
        raise RigError(None, "count", f"{path.name} announces {count} views but lists {len(entries)}")
    if width is None or height is None:
        first = path.parent / entries[0][0]
        shape = _image_shape(first)
        if shape is None:
            raise RigError(entries[0][0], "width", f"no width/height given and {first} is not a readable image")
        height, width = shape
    cams = []
    for tok in entries:
        if len(tok) != 22:
            raise RigError(tok[0], "line", f"expected a name and 21 numbers, got {len(tok) - 1} numbers")
        try:
            v = np.array(tok[1:], float)
        except ValueError:
            raise RigError(tok[0], "line", "unreadable numbers") from None
        cams.append(Camera(tok[0], v[:9].reshape(3, 3), v[9:18].reshape(3, 3), v[18:], width, height))
    return Rig(tuple(cams))


def rectified_rig(
    files: list[str], width: int, height: int, positions: list[float] | None = None, focal: float | None = None,
    baseline: float = 1.0,
) -> Rig:
    """A rectified stereo set with equal baselines along x (e.g. Middlebury Teddy/Art).

    View k sits at x = positions[k] * baseline (default positions 0, 1, 2, ...), R = I, all sharing
    K = [[f, 0, (w-1)/2], [0, f, (h-1)/2], [0, 0, 1]] with f = ``focal`` (default: the width).
    A disparity d between neighbouring views is then the depth z = f * baseline / d (units of the
    baseline); only these ratios matter for re-rendering.
    """
    pos = list(range(len(files))) if positions is None else list(positions)
    if len(pos) != len(files):
        raise RigError(None, "positions", f"{len(pos)} positions for {len(files)} views")
    f = float(focal) if focal is not None else float(width)
    K = np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1]])
    cams = tuple(Camera.from_center(Path(n).stem, K, np.eye(3), [p * baseline, 0, 0], width, height)
                 for n, p in zip(files, pos))
    return Rig(cams, tuple(files))


def load_middlebury_rectified(folder: str | Path, baseline: float = 1.0, focal: float | None = None) -> Rig:
    """A rectified Middlebury folder: views named ``im<k>`` or ``view<k>`` (k = position on the
    baseline), all the same size. See :func:`rectified_rig` for the geometry."""
    folder = Path(folder)
    views = []
    for p in sorted(folder.iterdir()):
        m = re.fullmatch(r"(?:im|view)(\d+)", p.stem)
        if m and p.suffix.lower() in IMAGE_EXTENSIONS:
            views.append((int(m.group(1)), p.name))
    if len(views) < 2:
        raise RigError(None, "cameras", f"{folder} holds fewer than 2 views named im<k> or view<k>")
    views.sort()
    shape = _image_shape(folder / views[0][1])
    if shape is None:
        raise RigError(views[0][1], "image", "unreadable")
    return rectified_rig([n for _, n in views], shape[1], shape[0], [k for k, _ in views], focal, baseline)


# --- dispatch and images ----------------------------------------------------------------------
def rig_format(path: str | Path) -> str:
    """The format :func:`load_rig` reads ``path`` as: "json" (ours), "camera_list" (a plain camera list),
    "opencv", "middlebury" (``*_par.txt``), "colmap" or "middlebury_rectified" (folders); RigError
    when none fits."""
    path = Path(path)
    if not path.exists():
        raise RigError(None, "file", f"{path} does not exist")
    if path.is_dir():
        for sub in (path, path / "sparse" / "0", path / "sparse"):
            if (sub / "cameras.txt").exists() and (sub / "images.txt").exists():
                return "colmap"
        return "middlebury" if any(path.glob("*_par.txt")) else "middlebury_rectified"
    suffix = path.suffix.lower()
    if suffix == ".json":
        return CAMERA_LIST if is_camera_list(_read_json(path)) else "json"
    if suffix in (".yml", ".yaml", ".xml"):
        return "opencv"
    if path.name.endswith("_par.txt"):
        return "middlebury"
    raise RigError(None, "file", f"{path.name}: unknown rig format (json, yml/yaml/xml, *_par.txt or a folder)")


def load_rig(path: str | Path, units: str | float | None = None, camera_type: str | None = None) -> Rig:
    """Read a rig in any supported format, chosen by what ``path`` is (:func:`rig_format`):

    ``*.json`` our JSON, or a plain camera list when its cameras have ``resolution``/``distCoef`` and
    no ``width``; ``*.yml``/``*.yaml``/``*.xml`` OpenCV FileStorage; ``*_par.txt`` Middlebury; a folder
    holding ``cameras.txt`` + ``images.txt`` (directly or in ``sparse/0``) COLMAP text, a ``*_par.txt``
    Middlebury, else ``im<k>``/``view<k>`` images a rectified Middlebury set.

    units: the unit of the file's translations (:func:`metres_per_unit`; default: centimetres for a
    camera list, metres otherwise); the rig comes back in metres. camera_type: for a camera list, keep
    only the cameras of that ``type`` (RigError for other formats).
    """
    path = Path(path)
    fmt = rig_format(path)
    scale = metres_per_unit(units, fmt)
    if camera_type is not None and fmt != CAMERA_LIST:
        raise RigError(None, "camera_type", "only a plain camera list has camera types")
    if fmt == CAMERA_LIST:
        return rig_from_camera_list(_read_json(path), scale, camera_type)
    if fmt == "json":
        rig = load_rig_json(path)
    elif fmt == "opencv":
        rig = load_opencv_yaml(path)
    elif fmt == "colmap":
        rig = next(load_colmap_text(sub) for sub in (path, path / "sparse" / "0", path / "sparse")
                   if (sub / "cameras.txt").exists() and (sub / "images.txt").exists())
    elif fmt == "middlebury":
        rig = load_middlebury_par(path if path.is_file() else sorted(path.glob("*_par.txt"))[0])
    else:
        rig = load_middlebury_rectified(path)
    return rig.rescaled(scale)


def load_uploaded_rig(files: Sequence[tuple[str, bytes]], width: int | None = None, height: int | None = None,
                      units: str | float | None = None, camera_type: str | None = None,
                      max_cameras: int | None = None, max_pixels: int | None = None) -> tuple[Rig, str]:
    """The rig (in metres) and its format's name from uploaded calibration files: (file name, bytes) pairs,
    names already safe (no folders). One file is read as :func:`load_rig` reads it (a Middlebury
    ``*_par.txt`` needs ``width``/``height``: an upload has no images beside it); several files only as
    COLMAP text (``cameras.txt`` + ``images.txt``). A rig whose cameras all stand at one place
    (:meth:`Rig.require_baseline`), with more than ``max_cameras`` cameras or a camera of more than ``max_pixels``
    pixels (width x height) is refused.

    Raises :class:`~workers.common.errors.InputError`: ``invalid_parameters`` for ``units`` that are no unit,
    else ``invalid_rig`` ("unusable calibration: ...", naming the uploaded files, never the temporary folder
    they were read from) or, for the limits, ``invalid_rig`` saying the limit.
    """
    try:
        metres_per_unit(units, CAMERA_LIST)
    except RigError as exc:
        raise InputError(f"units: {exc.problem}", "invalid_parameters") from None
    try:
        rig, fmt = _read_uploaded_rig(files, width, height, units, camera_type)
        rig.require_baseline()
    except ValueError as exc:  # RigError, CameraError, and the parsers' own (JSON, YAML, numbers)
        raise InputError(f"unusable calibration: {exc}", "invalid_rig") from None
    _check_rig_limits(rig, max_cameras, max_pixels)
    return rig, fmt


def _check_rig_limits(rig: Rig, max_cameras: int | None, max_pixels: int | None) -> None:
    if max_cameras is not None and len(rig) > max_cameras:
        raise InputError(f"the rig has {len(rig)} cameras; the limit is {max_cameras}", "invalid_rig")
    for cam in rig.cameras:
        if max_pixels is not None and cam.width * cam.height > max_pixels:
            raise InputError(f"camera {cam.name} is {cam.width}x{cam.height}, over the limit of {max_pixels:,} pixels",
                             "invalid_rig")


def _read_uploaded_rig(files: Sequence[tuple[str, bytes]], width: int | None, height: int | None,
                       units: str | float | None, camera_type: str | None) -> tuple[Rig, str]:
    names = sorted(name for name, _ in files)
    with tempfile.TemporaryDirectory(prefix="sweepcast-rig-") as tmp:
        folder = Path(tmp)
        try:
            for name, data in files:
                (folder / name).write_bytes(data)
            if len(names) > 1:
                if names != ["cameras.txt", "images.txt"]:
                    raise ValueError(f"several files are only understood as COLMAP text (cameras.txt + images.txt); "
                                     f"got {', '.join(names)}")
                return load_rig(folder, units, camera_type), "colmap"
            path = folder / names[0]
            if path.name in ("cameras.txt", "images.txt"):
                raise ValueError("COLMAP text needs both cameras.txt and images.txt")
            fmt = rig_format(path)
            if fmt == "middlebury":
                if width is None or height is None:
                    raise ValueError("a Middlebury *_par.txt has no image size: give the form fields width and "
                                     "height")
                if camera_type is not None:
                    raise ValueError("camera_type: only a plain camera list has camera types")
                return load_middlebury_par(path, width, height).rescaled(metres_per_unit(units, fmt)), fmt
            return load_rig(path, units, camera_type), fmt
        except ValueError as exc:  # RigError, CameraError, and the parsers' own
            raise ValueError(_without_folder(str(exc), folder)) from None


def _without_folder(message: str, folder: Path) -> str:
    """``message`` with every path inside ``folder`` shortened to the file's own name."""
    for form in {str(folder), str(folder.resolve())}:
        message = message.replace(form + "/", "").replace(form, "the upload")
    return message


def find_image(folder: Path, name: str) -> Path | None:
    """``folder/name`` or ``folder/name`` + a known image extension, whichever exists."""
    direct = folder / name
    if direct.is_file():
        return direct
    for ext in IMAGE_EXTENSIONS:
        p = folder / (name + ext)
        if p.is_file():
            return p
    return None


def load_images(rig: Rig, folder: str | Path, names: list[str] | None = None) -> list[np.ndarray]:
    """The rig's images from ``folder`` (uint8 (H, W, 3) BGR each, in rig order), by ``rig.image_files``
    or the given ``names``; a missing, unreadable or wrongly-sized image raises RigError naming the camera."""
    folder = Path(folder)
    names = names if names is not None else list(rig.image_files)
    images = []
    for cam, name in zip(rig.cameras, names):
        p = find_image(folder, name)
        if p is None:
            raise RigError(cam.name, "image", f"no image {name!r} in {folder}")
        img = cv2.imread(str(p), cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION)
        if img is None:
            raise RigError(cam.name, "image", f"{p} is not a readable image")
        if img.shape[:2] != (cam.height, cam.width):
            raise RigError(cam.name, "image size",
                           f"{p.name} is {img.shape[1]}x{img.shape[0]}, calibration says {cam.width}x{cam.height}")
        images.append(img)
    return images


def _image_shape(path: Path) -> tuple[int, int] | None:
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED) if path.is_file() else None
    return None if img is None else img.shape[:2]
