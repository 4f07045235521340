"""The text-line gate's network in 8-bit integers, for a library that trades a few text decisions for speed.

The gate (:mod:`workers.orientation.textlines`) runs on every photo that no face decides, so its network is most of what
such a photo costs. onnxruntime's static quantization (QDQ format: per-channel signed 8-bit weights, unsigned 8-bit
activations whose ranges come from a calibration run) turns rapidocr's float model into one that runs on the CPU's
integer dot-product instructions (VNNI) in ~0.6x the time (31 against 50 ms a 480 x 352 copy, one core of this project's
AMD EPYC machine; on an Intel Xeon, with the float network's denormals flushed (:mod:`workers.common.denormals`), 41
against 53 ms, ~0.8x). Its map is close to the float one but not the same: in a run of ``benchmarks.orientation_text``
with it as the gate (2026-12-06, 10:32-11:17 UTC), the gate found lines in 589 of 608 text trials where the float one
had found 595 (the run before), looked closer at small print in 18 rather than 29, and the engine decided 454 of the 500
held-out text trials where with the float gate and the same decoding it decided 459 (that engine's trials, 11:29-11:35
UTC; 0 wrong either way), while the median CPU of a photo with neither faces nor text fell from ~100 to 83 ms. So it is
a setting (``SWEEPCAST_ORIENTATION_GATE_PRECISION``: ``int8``, or ``auto`` for 8 bits where the CPU has VNNI), not the
default. Used only screening photos (8 bits first, the float network on any photo with a line in it) it saved nothing:
the screen's pass costs about as much as it saves, since a third of the photos go on. Without VNNI (AVX2 alone)
onnxruntime's signed-weight kernels may saturate and are no faster than the float ones, so ``auto`` keeps the float
model there (:func:`int8_fast`).

The calibration images are generated here (:func:`calibration_pages`): pages and scenes with lines of text at many
sizes, contrasts and both axes, over paper, gradients and textures. No photo of the benchmarks shapes the ranges.

The 8-bit model is built once per machine (a few seconds) into the model cache (``SWEEPCAST_MODEL_CACHE_DIR``,
default ``~/.cache/sweepcast/models``), named by the float model's digest, this recipe and onnxruntime's version, and
checked against the float model on the calibration pages before it is used (:data:`AGREEMENT`); a model that fails
the check, or a machine where it cannot be built, keeps the float model and says why (:func:`gate_model`).
"""
from __future__ import annotations

import contextlib
import hashlib
import os
import platform
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator, Literal

import cv2
import numpy as np

Precision = Literal["auto", "int8", "float"]
RECIPE = 1
"""Bumped whenever the calibration or the quantization's options change (a new cache entry)."""
CALIBRATION_PAGES = 32
AGREEMENT = 0.85
"""The integer model is used when, over the calibration pages, its text pixels (probability >= 0.3) and the float
model's overlap at least this much (intersection over union)."""
VNNI_FLAGS = ("avx512_vnni", "avx_vnni")


@dataclass(frozen=True)
class GateModel:
    """The model file the gate runs, its precision (``int8`` or ``float``) and why that one."""

    path: Path
    precision: Literal["int8", "float"]
    detail: str


def one_core_session(model: Path | bytes):
    """An onnxruntime session of ``model`` (a file, or a model's bytes) on one core (callers run photos in parallel
    processes, one core each)."""
    import onnxruntime

    options = onnxruntime.SessionOptions()
    options.intra_op_num_threads = 1
    options.inter_op_num_threads = 1
    options.log_severity_level = 3
    source = model if isinstance(model, bytes) else str(model)
    return onnxruntime.InferenceSession(source, options, providers=["CPUExecutionProvider"])


def int8_fast() -> bool:
    """Whether this CPU has integer dot-product instructions onnxruntime uses for 8-bit convolutions (x86 VNNI)."""
    if platform.machine().lower() not in ("x86_64", "amd64"):
        return False
    try:
        flags = next((line for line in Path("/proc/cpuinfo").read_text().splitlines() if line.startswith("flags")), "")
    except OSError:
        return False
    return any(flag in flags.split() for flag in VNNI_FLAGS)


def cache_dir() -> Path:
    """Where built models are kept: the ``model_cache_dir`` setting (``SWEEPCAST_MODEL_CACHE_DIR``), else
    ``~/.cache/sweepcast/models``."""
    from workers.settings import worker_settings

    return worker_settings().model_cache_dir or Path.home() / ".cache" / "sweepcast" / "models"


def gate_model(source: Path, precision: Precision, to_input: Callable[[np.ndarray], np.ndarray]) -> GateModel:
    """The model the gate should run for ``precision`` (``auto``: 8-bit where :func:`int8_fast`): the integer model
    built from ``source`` (rapidocr's float ONNX file) when it can be built and passes the check, else ``source``.
    ``to_input`` turns a grey page ((H, W) uint8) into the network's input, as the gate prepares a photo."""
    if precision == "float":
        return GateModel(source, "float", "float model (SWEEPCAST_ORIENTATION_GATE_PRECISION=int8: 8-bit, faster)")
    if precision == "auto" and not int8_fast():
        return GateModel(source, "float", "float model: this CPU has no VNNI, where 8-bit is no faster")
    try:
        path = _cached_int8(source, to_input)
    except (ImportError, OSError, RuntimeError, ValueError) as exc:
        return GateModel(source, "float", f"float model: the 8-bit model could not be built ({exc})")
    if path is None:
        return GateModel(source, "float", "float model: the 8-bit model disagreed with it on the calibration pages")
    return GateModel(path, "int8", f"8-bit model built from {source.name} ({path})")


def _cached_int8(source: Path, to_input: Callable[[np.ndarray], np.ndarray]) -> Path | None:
    """The checked integer model of ``source`` from the cache, built there first when missing; None when it fails
    the check (remembered beside it, so that each process does not build it again)."""
    import onnxruntime

    digest = hashlib.sha256(source.read_bytes()).hexdigest()[:16]
    folder = cache_dir()
    folder.mkdir(parents=True, exist_ok=True)
    target = folder / f"{source.stem}.int8-{digest}-r{RECIPE}-ort{onnxruntime.__version__}.onnx"
    refused = target.with_suffix(".refused")
    with _exclusive(target.with_suffix(".lock")):  # one process builds; the others wait and use it
        if not target.is_file() and not refused.is_file():
            with tempfile.TemporaryDirectory(dir=folder) as work:
                built = quantize(source, Path(work), to_input)
                if agreement(source, built, to_input) >= AGREEMENT:
                    os.replace(built, target)
                else:
                    refused.write_text("the 8-bit model disagreed with the float model on the calibration pages\n")
    return target if target.is_file() else None


@contextlib.contextmanager
def _exclusive(lock: Path) -> Iterator[None]:
    import fcntl

    with open(lock, "a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def quantize(source: Path, work: Path, to_input: Callable[[np.ndarray], np.ndarray]) -> Path:
    """``source`` quantized (opset raised to 13 for per-channel scales, shapes inferred, QDQ, calibrated with MinMax on
    :func:`calibration_pages`) into ``work``; the new file's path."""
    import onnx
    from onnx import version_converter
    from onnxruntime.quantization import (CalibrationDataReader, QuantFormat, QuantType, quant_pre_process,
                                          quantize_static)

    model = onnx.load(str(source))
    if max((o.version for o in model.opset_import if o.domain in ("", "ai.onnx")), default=0) < 13:
        model = version_converter.convert_version(model, 13)
    upgraded, prepared, out = work / "opset13.onnx", work / "prepared.onnx", work / "int8.onnx"
    onnx.save(model, str(upgraded))
    quant_pre_process(str(upgraded), str(prepared), skip_symbolic_shape=True)
    name = model.graph.input[0].name

    class Pages(CalibrationDataReader):
        def __init__(self) -> None:
            self._pages = ({name: to_input(page)} for page in calibration_pages())

        def get_next(self) -> dict[str, np.ndarray] | None:
            return next(self._pages, None)

    quantize_static(str(prepared), str(out), Pages(), quant_format=QuantFormat.QDQ, activation_type=QuantType.QUInt8,
                    weight_type=QuantType.QInt8, per_channel=True)
    return out


def agreement(source: Path, built: Path, to_input: Callable[[np.ndarray], np.ndarray]) -> float:
    """Intersection over union of the text pixels (probability >= 0.3) of the two models over the calibration
    pages (1.0 when neither finds any)."""
    sessions = [one_core_session(p) for p in (source, built)]
    both = either = 0
    for page in calibration_pages():
        x = to_input(page)
        a, b = (s.run(None, {s.get_inputs()[0].name: x})[0] >= 0.3 for s in sessions)
        both += int(np.count_nonzero(a & b))
        either += int(np.count_nonzero(a | b))
    return both / either if either else 1.0


def calibration_pages(count: int = CALIBRATION_PAGES, seed: int = 0) -> Iterator[np.ndarray]:
    """``count`` generated grey images ((h, w) uint8, 480 x 352 or 352 x 480 px, the gate's working size): a
    background (paper, a gradient, a blurred texture or a dark surface), 0-14 lines of text in OpenCV's Hershey fonts
    at 0.3-2 times their size, dark on light or light on dark, some along the vertical axis, blurred and noised as a
    camera would."""
    rng = np.random.default_rng(seed)
    fonts = (cv2.FONT_HERSHEY_SIMPLEX, cv2.FONT_HERSHEY_PLAIN, cv2.FONT_HERSHEY_DUPLEX, cv2.FONT_HERSHEY_COMPLEX,
             cv2.FONT_HERSHEY_TRIPLEX, cv2.FONT_HERSHEY_COMPLEX_SMALL, cv2.FONT_HERSHEY_SCRIPT_SIMPLEX)
    words = ("the", "total", "invoice", "Station", "STOP", "Exit", "Open 9-17", "menu", "No. 42", "receipt",
             "Danke", "Sortie", "page 3", "CASH", "12.50", "Chapter", "Road", "www.example.org", "Tel 0123")
    for i in range(count):
        h, w = (352, 480) if i % 2 == 0 else (480, 352)
        page = np.ascontiguousarray(_background(rng, h, w, i % 4))
        light = float(page.mean()) > 110  # dark letters on it
        canvas = np.ascontiguousarray(page.T) if rng.random() < 0.25 else page  # lines along the vertical axis once turned back
        for _ in range(int(rng.integers(0, 15))):
            text = " ".join(rng.choice(words, size=int(rng.integers(1, 5))))
            colour = int(rng.integers(0, 90)) if light else int(rng.integers(170, 256))
            org = (int(rng.integers(0, canvas.shape[1] - 40)), int(rng.integers(15, canvas.shape[0])))
            cv2.putText(canvas, text, org, fonts[int(rng.integers(len(fonts)))], float(rng.uniform(0.3, 2.0)), colour,
                        int(rng.integers(1, 3)), cv2.LINE_AA)
        page = canvas.T if canvas.shape != page.shape else canvas
        page = cv2.GaussianBlur(page, (0, 0), float(rng.uniform(0.3, 1.2)))
        noisy = page.astype(np.float32) + rng.normal(0, float(rng.uniform(0, 6)), page.shape)
        yield np.clip(noisy, 0, 255).astype(np.uint8)


def _background(rng: np.random.Generator, h: int, w: int, kind: int) -> np.ndarray:
    """(h, w) uint8: paper (0), a gradient (1), a blurred random texture (2), a dark surface (3)."""
    if kind == 0:
        return np.full((h, w), int(rng.integers(190, 250)), np.uint8)
    if kind == 1:
        ramp = np.linspace(float(rng.uniform(0, 120)), float(rng.uniform(120, 255)), w, dtype=np.float32)
        return np.broadcast_to(ramp, (h, w)).astype(np.uint8)
    if kind == 2:
        noise = rng.uniform(0, 255, (h // 8 + 1, w // 8 + 1)).astype(np.float32)
        return cv2.resize(noise, (w, h), interpolation=cv2.INTER_CUBIC).clip(0, 255).astype(np.uint8)
    return np.full((h, w), int(rng.integers(10, 70)), np.uint8)
