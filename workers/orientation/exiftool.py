"""ExifTool (Debian ``libimage-exiftool-perl``) kept running with ``-stay_open``: the maintained metadata
library behind the writes our own byte-level writers do not cover (PNG ``eXIf``, XMP sidecars) and
the reader of RAW files' embedded previews.

One ``exiftool -stay_open True -@ -`` process per thread is started on first use and fed one command
at a time; starting Perl costs ~110 ms a file, a command on the open process a few milliseconds
(``benchmarks/orientation.py``, section orientation_writers). ExifTool never writes in place here:
it writes a new file next to the target (``-o``), which the caller moves over the original with
``os.replace`` (atomic on one file system).

It is optional: without it, JPEG, WebP and TIFF are still read and tagged by our own writers, and the
operations that need it raise :class:`ExifToolUnavailable` with a message saying what to install.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import threading
from dataclasses import dataclass
from functools import lru_cache

EXIFTOOL_ENV = "SWEEPCAST_EXIFTOOL"
"""Environment variable naming the exiftool binary (a name on PATH or a path); default ``exiftool``."""
COMMAND_TIMEOUT_S = 60.0
"""A single command that takes longer is abandoned and its process killed."""


class ExifToolUnavailable(RuntimeError):
    """exiftool is not installed (or cannot run): the operation needs it."""


class ExifToolError(RuntimeError):
    """exiftool ran and reported an error for this file (message: its stderr)."""


@dataclass(frozen=True)
class Result:
    """One exiftool command's outcome."""

    stdout: bytes
    stderr: str


def exiftool_binary() -> str:
    """The exiftool the environment names (``$SWEEPCAST_EXIFTOOL``), else ``exiftool``."""
    return os.environ.get(EXIFTOOL_ENV, "").strip() or "exiftool"


@lru_cache(maxsize=4)
def exiftool_version(binary: str | None = None) -> str | None:
    """exiftool's version ("12.57"), or None when it is not installed or does not run."""
    path = shutil.which(binary or exiftool_binary())
    if path is None:
        return None
    try:
        out = subprocess.run([path, "-ver"], capture_output=True, text=True, timeout=20)
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() or None if out.returncode == 0 else None


class _Process:
    """One ``-stay_open`` exiftool process (not thread-safe: one per thread)."""

    def __init__(self, path: str) -> None:
        self._proc = subprocess.Popen([path, "-stay_open", "True", "-@", "-"], stdin=subprocess.PIPE,
                                      stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        self._seq = 0

    def alive(self) -> bool:
        return self._proc.poll() is None

    def run(self, args: list[str]) -> Result:
        self._seq += 1
        tag = self._seq
        for arg in args:
            if "\n" in arg:
                raise ValueError(f"exiftool argument contains a newline: {arg!r}")
        lines = [*args, "-echo4", f"{{done{tag}}}", f"-execute{tag}", ""]
        timer = threading.Timer(COMMAND_TIMEOUT_S, self._proc.kill)
        timer.start()
        try:
            self._proc.stdin.write("\n".join(lines).encode())
            self._proc.stdin.flush()
            stdout = self._read_until(self._proc.stdout, f"{{ready{tag}}}".encode())
            stderr = self._read_until(self._proc.stderr, f"{{done{tag}}}".encode())
        finally:
            timer.cancel()
        return Result(stdout, stderr.decode("utf-8", "replace").strip())

    @staticmethod
    def _read_until(stream, marker: bytes) -> bytes:
        buf = bytearray()
        while not buf.rstrip().endswith(marker):
            chunk = os.read(stream.fileno(), 65536)
            if not chunk:
                raise ExifToolUnavailable("exiftool stopped while running a command")
            buf += chunk
        body = bytes(buf.rstrip())
        return body[:-len(marker)]

    def close(self) -> None:
        try:
            self._proc.stdin.write(b"-stay_open\nFalse\n")
            self._proc.stdin.flush()
            self._proc.wait(timeout=5)
        except (OSError, subprocess.SubprocessError, ValueError):
            self._proc.kill()


_local = threading.local()


def run(args: list[str]) -> Result:
    """Run one exiftool command (its arguments, one per list item) on this thread's process.

    Raises ExifToolUnavailable when exiftool is not installed and ExifToolError when it reports an
    error (``Error: ...`` on stderr); warnings are returned in ``stderr``.
    """
    binary = exiftool_binary()
    path = shutil.which(binary)
    if path is None:
        raise ExifToolUnavailable(f"exiftool ({binary!r}) is not installed: install the Debian package "
                                  f"libimage-exiftool-perl or set ${EXIFTOOL_ENV}")
    proc: _Process | None = getattr(_local, "proc", None)
    if proc is None or not proc.alive():
        proc = _local.proc = _Process(path)
    try:
        result = proc.run(args)
    except ExifToolUnavailable:
        _local.proc = None
        raise
    errors = [line for line in result.stderr.splitlines() if line.startswith("Error")]
    if errors:
        raise ExifToolError("; ".join(errors))
    return result
