"""ExifTool (Debian ``libimage-exiftool-perl``) kept running with ``-stay_open``: the maintained metadata
library behind the writes our own byte-level writers do not cover (PNG ``eXIf``, XMP sidecars) and
the reader of RAW files' embedded previews.

One ``exiftool -stay_open True -@ -`` process per thread is started on first use and fed one command
at a time: starting Perl for each file costs far more than a command on the open process
(``benchmarks/orientation_writers.py``, section orientation_writers). ExifTool never writes in place here:
it writes a new file next to the target (``-o``), which the caller moves over the original with
``os.replace`` (atomic on one file system).

It is optional: without it, JPEG, WebP and TIFF are still read and tagged by our own writers, and the
operations that need it raise :class:`ExifToolUnavailable` with a message saying what to install. Both of its
errors are :class:`~workers.common.errors.InputError`s: they depend on the file sent (a PNG, a RAW photo), the service
answers them with their status, a batch records them per photo, and retrying a job would not help.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import threading
import weakref
from dataclasses import dataclass

from workers.common.errors import InputError
from workers.common.spawn import dying_with_parent
from workers.settings import worker_settings

EXIFTOOL_ENV = "SWEEPCAST_EXIFTOOL"
"""Environment variable naming the exiftool binary (a name on PATH or a path); default ``exiftool``."""
COMMAND_TIMEOUT_S = 60.0
"""A single command that takes longer is abandoned and its process killed."""


class ExifToolUnavailable(InputError):
    """exiftool is not installed (or cannot run) and this file needs it: 503, the deployment's to mend."""

    code = "metadata_tool_unavailable"
    status = 503


class ExifToolError(InputError):
    """exiftool ran and refused this file (the message quotes its errors)."""

    code = "unwritable_metadata"
    status = 422


@dataclass(frozen=True)
class Result:
    """One exiftool command's outcome."""

    stdout: bytes
    stderr: str


def exiftool_binary() -> str:
    """The exiftool the environment names (``$SWEEPCAST_EXIFTOOL``), else ``exiftool``."""
    return worker_settings().exiftool.strip() or "exiftool"


def _stop(proc: subprocess.Popen) -> None:
    """Ask exiftool to stop, then kill it (its owner is gone or the interpreter is exiting)."""
    if proc.poll() is not None:
        return
    try:
        proc.stdin.write(b"-stay_open\nFalse\n")
        proc.stdin.flush()
        proc.wait(timeout=5)
    except (OSError, subprocess.SubprocessError, ValueError):
        proc.kill()
        proc.wait()


class _Process:
    """One ``-stay_open`` exiftool process (not thread-safe: one per thread). It is stopped when this object
    goes (its thread ended), at interpreter exit, and by the kernel when the starting thread dies."""

    def __init__(self, path: str) -> None:
        # stopped by the kernel when the starting thread ends: -stay_open does not stop at the end of its input,
        # so the process of a killed user would otherwise run on forever
        self._proc = subprocess.Popen(dying_with_parent([path, "-stay_open", "True", "-@", "-"]),
                                      stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        self._seq = 0
        self.close = weakref.finalize(self, _stop, self._proc)

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
        raise ExifToolError(f"exiftool refused this file: {'; '.join(errors)}")
    return result
