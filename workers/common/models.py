"""Third-party model files the service can use: fetched on request, verified by SHA-256, kept in the data folder.

The project ships no model it did not write. A model listed here is downloaded from its publisher by
``sweepcast models fetch NAME`` (or installed from a local copy with ``--from``), checked against the
pinned SHA-256 and size, and written atomically to ``<data_dir>/models/``; a setting that points
elsewhere (e.g. ``SWEEPCAST_ORIENTATION_YUNET_MODEL``) always wins over what is installed there.
"""
from __future__ import annotations

import hashlib
import os
import tempfile
import urllib.request
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO


class ModelError(Exception):
    """A model could not be fetched or did not match its pinned checksum (nothing was installed)."""


@dataclass(frozen=True)
class ModelFile:
    name: str
    filename: str
    url: str
    sha256: str
    size: int
    """Bytes; a download larger than this is cut off and refused."""
    license: str
    used_for: str


YUNET = ModelFile(
    name="yunet",
    filename="face_detection_yunet_2023mar.onnx",
    url="https://github.com/opencv/opencv_zoo/raw/main/models/face_detection_yunet/face_detection_yunet_2023mar.onnx",
    sha256="8f2383e4dd3cfbb4553ea8718107fc0423210dc964f9f4280604804ed2552fa4",
    size=232_589,
    license="MIT (OpenCV Zoo, YuNet by Shiqi Yu et al.)",
    used_for="orientation: the 'combined' face detector, the default once installed",
)
MODELS: dict[str, ModelFile] = {YUNET.name: YUNET}


MODELS_DIR_ENV = "SWEEPCAST_MODELS_DIR"
"""Where a worker process finds the installed models (the service passes ``<data_dir>/models``)."""


def models_dir(data_dir: Path) -> Path:
    return Path(data_dir) / "models"


def installed_in(model: ModelFile, folder: Path | None) -> Path | None:
    """The model's file in ``folder`` (a models folder), or None when there is none (or no folder)."""
    path = Path(folder) / model.filename if folder is not None else None
    return path if path is not None and path.is_file() else None


def installed(model: ModelFile, data_dir: Path) -> Path | None:
    """The model's file in ``data_dir``'s model folder, or None when it is not installed."""
    return installed_in(model, models_dir(data_dir))


def _copy_checked(model: ModelFile, source: BinaryIO, out: BinaryIO) -> None:
    digest = hashlib.sha256()
    total = 0
    while chunk := source.read(1 << 16):
        total += len(chunk)
        if total > model.size:
            raise ModelError(f"{model.name}: the source is larger than the expected {model.size} bytes")
        digest.update(chunk)
        out.write(chunk)
    if total != model.size or digest.hexdigest() != model.sha256:
        raise ModelError(f"{model.name}: checksum mismatch (got {total} bytes, sha256 {digest.hexdigest()}; "
                         f"expected {model.size} bytes, sha256 {model.sha256})")


def _open_source(model: ModelFile, source: str | Path | None, timeout: float) -> BinaryIO:
    where = str(source) if source is not None else model.url
    try:
        if where.startswith(("http://", "https://")):
            return urllib.request.urlopen(where, timeout=timeout)  # noqa: S310 - the scheme is checked above
        return open(where, "rb")
    except OSError as exc:  # URLError and HTTPError are OSErrors
        raise ModelError(f"{model.name}: cannot read {where}: {exc}") from None


def install(model: ModelFile, data_dir: Path, source: str | Path | None = None, timeout: float = 30.0) -> Path:
    """Fetch ``model`` from ``source`` (a file path or an http(s) URL; default the publisher's URL),
    verify it, and move it into place. Returns the installed path. Raises ModelError, leaving any
    previously installed copy as it was."""
    folder = models_dir(data_dir)
    folder.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{model.filename}.", dir=folder)
    try:
        with os.fdopen(fd, "wb") as out, _open_source(model, source, timeout) as src:
            try:
                _copy_checked(model, src, out)
            except OSError as exc:
                raise ModelError(f"{model.name}: download interrupted: {exc}") from None
        target = folder / model.filename
        os.replace(tmp, target)
        return target
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
