"""The one way the service reads zip archives a user sent: checked before and while reading.

A zip declares its members' sizes but nothing makes them true, and a few megabytes of deflate
can expand to gigabytes. :class:`SafeZip` therefore checks, on opening:

- the central directory: the member count it declares and its size in bytes (``zipfile`` builds
  one object per entry it holds, so a huge directory costs memory before any check could run);
- every member: a relative name (no absolute path, drive letter, ``..`` part or NUL), not a
  symlink, not encrypted, a declared size within ``max_member_bytes`` and a compression ratio
  within ``max_ratio`` (members from 1 MiB on: small ones cannot hurt);
- the declared sizes together within ``max_total_bytes``;

and :meth:`SafeZip.read` stream-reads a member with a cap of its declared size (at most
``max_member_bytes``), so a header that lies is caught rather than trusted, and counts what it
read against ``max_total_bytes``.

Every problem raises the caller's error type (``error``, default :class:`ZipInputError`, an
:class:`~workers.common.errors.InputError`: 422 ``invalid_archive``), with a message that names the archive by the
label the caller gives (the client's file name, never a server path).
"""
from __future__ import annotations

import io
import os
import stat
import struct
import zipfile
import zlib
from dataclasses import dataclass, fields
from pathlib import Path
from typing import BinaryIO, Callable

from workers.common.errors import InputError
from workers.settings import WorkerSettings, worker_settings

MiB = 1 << 20
_CHUNK = MiB
_RATIO_FROM_BYTES = MiB
_DIRECTORY_BYTES_PER_MEMBER = 256
"""Central-directory budget per allowed member: 46 bytes of fixed fields plus name and extras."""
_EOCD, _ZIP64_LOCATOR, _ZIP64_EOCD = b"PK\x05\x06", b"PK\x06\x07", b"PK\x06\x06"
_READ_ERRORS = (zipfile.BadZipFile, zlib.error, EOFError, NotImplementedError, RuntimeError, OSError)


class ZipInputError(InputError):
    """A zip archive that is damaged, unsafe or over a limit; the message says which and why."""

    code = "invalid_archive"


@dataclass(frozen=True)
class ZipLimits:
    """Limits of one archive. Each can be set by ``SWEEPCAST_<FIELD>`` (as the service's settings of
    the same names, which the service passes to its workers)."""

    max_zip_members: int = 200_000
    """Files in one archive (a recording: up to 64 cameras x 3000 frames)."""
    max_zip_member_bytes: int = 512 * MiB
    """Uncompressed size of one member."""
    max_zip_total_bytes: int = 4096 * MiB
    """Uncompressed size of all members together."""
    max_zip_ratio: float = 200.0
    """Uncompressed / compressed size of one member (members from 1 MiB on)."""

    @classmethod
    def from_settings(cls, settings: WorkerSettings) -> "ZipLimits":
        """The ``max_zip_*`` fields of ``settings`` (the service's settings include them)."""
        return cls(*(getattr(settings, f.name) for f in fields(cls)))

    @classmethod
    def from_env(cls) -> "ZipLimits":
        """The limits of this process: ``$SWEEPCAST_MAX_ZIP_MEMBERS`` etc. (:mod:`workers.settings`), else the defaults."""
        return cls.from_settings(worker_settings())


class SafeZip:
    """A zip archive checked on opening (see the module docstring); use as a context manager.

    ``source``: a path, an open binary file (seekable) or the bytes; ``label``: how messages name
    the archive; ``error``: the exception type raised (called with the message).
    """

    def __init__(self, source: str | Path | BinaryIO | bytes, limits: ZipLimits | None = None,
                 label: str = "the zip archive", error: Callable[[str], Exception] = ZipInputError) -> None:
        self.limits = limits or ZipLimits.from_env()
        self.label = label
        self._error = error
        self._read_total = 0
        self._owned: BinaryIO | None = None
        if isinstance(source, (str, Path)):
            fh = self._owned = open(source, "rb")  # noqa: SIM115 - closed by close()
        else:
            fh = io.BytesIO(source) if isinstance(source, bytes) else source
        try:
            self._check_directory(fh)
            try:
                self._zip = zipfile.ZipFile(fh)
            except (zipfile.BadZipFile, OSError, ValueError) as exc:
                raise self._fail(f"is not a readable zip archive ({exc})") from None
            self.members: list[zipfile.ZipInfo] = [i for i in self._zip.infolist() if not i.is_dir()]
            self._by_name = {i.filename: i for i in self.members}
            self._check_members()
        except BaseException:
            self.close()
            raise

    # --- use ---------------------------------------------------------------------------------
    @property
    def zipfile(self) -> zipfile.ZipFile:
        """The checked archive, for readers that take a ``ZipFile``. Reads through it are bounded
        by the checked declared sizes (``zipfile`` stops at a member's declared size and fails the
        CRC of a longer stream) but not counted against ``max_zip_total_bytes``: prefer :meth:`read`."""
        return self._zip

    def names(self) -> list[str]:
        """The file members' names, in archive order (directories left out)."""
        return [i.filename for i in self.members]

    def read(self, name: str) -> bytes:
        """A member's bytes, stream-read with a cap of its declared size."""
        info = self._by_name.get(name)
        if info is None:
            raise self._fail(f"has no member {name!r}")
        cap = min(info.file_size, self.limits.max_zip_member_bytes)
        chunks, size = [], 0
        try:
            with self._zip.open(info) as member:
                while chunk := member.read(min(_CHUNK, cap + 1 - size)):
                    size += len(chunk)
                    if size > cap:
                        raise self._fail(f"member {name!r} holds more than the {info.file_size:,} bytes its header "
                                         f"declares")
                    chunks.append(chunk)
        except _READ_ERRORS as exc:
            raise self._fail(f"member {name!r} cannot be read ({exc})") from None
        self._count(size)
        return b"".join(chunks)

    def close(self) -> None:
        zf = getattr(self, "_zip", None)
        if zf is not None:
            zf.close()
        if self._owned is not None:
            self._owned.close()

    def __enter__(self) -> "SafeZip":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- checks ------------------------------------------------------------------------------
    def _fail(self, problem: str) -> Exception:
        return self._error(f"{self.label} {problem}")

    def _count(self, size: int) -> None:
        self._read_total += size
        if self._read_total > self.limits.max_zip_total_bytes:
            raise self._fail(f"expands to more than the limit of {self.limits.max_zip_total_bytes:,} bytes")

    def _check_directory(self, fh: BinaryIO) -> None:
        """Refuse a central directory that declares too many members or is too large, before
        ``zipfile`` builds an object per entry."""
        try:
            count, size = _directory_extent(fh)
        except (OSError, struct.error, ValueError):
            return  # no end record found: zipfile.ZipFile reports the archive as unreadable
        limit = self.limits.max_zip_members
        if count > limit or size > limit * _DIRECTORY_BYTES_PER_MEMBER:
            raise self._fail(f"holds {count:,} members ({size:,} bytes of directory); the limit is {limit:,} members")

    def _check_members(self) -> None:
        lim = self.limits
        if len(self._zip.infolist()) > lim.max_zip_members:
            raise self._fail(f"holds {len(self._zip.infolist()):,} members; the limit is {lim.max_zip_members:,}")
        total = 0
        for info in self.members:
            self._check_member(info)
            total += info.file_size
        if total > lim.max_zip_total_bytes:
            raise self._fail(f"expands to {total:,} bytes; the limit is {lim.max_zip_total_bytes:,} bytes")

    def _check_member(self, info: zipfile.ZipInfo) -> None:
        name, lim = info.filename, self.limits
        problem = unsafe_name(name)
        if problem:
            raise self._fail(f"member {name!r} {problem}")
        if info.create_system == 3 and stat.S_ISLNK(info.external_attr >> 16):
            raise self._fail(f"member {name!r} is a symbolic link")
        if info.flag_bits & 0x1:
            raise self._fail(f"member {name!r} is encrypted")
        if info.file_size > lim.max_zip_member_bytes:
            raise self._fail(f"member {name!r} is {info.file_size:,} bytes uncompressed; the limit is "
                             f"{lim.max_zip_member_bytes:,} bytes")
        ratio = info.file_size / max(info.compress_size, 1)
        if info.file_size >= _RATIO_FROM_BYTES and ratio > lim.max_zip_ratio:
            raise self._fail(f"member {name!r} expands {ratio:,.0f} times (a zip bomb?); the limit is "
                             f"{lim.max_zip_ratio:g} times")


def unsafe_name(name: str) -> str | None:
    """Why a member name is unsafe to use as a relative path, or None when it is fine."""
    if "\x00" in name:
        return "has a NUL character in its name"
    if name.startswith(("/", "\\")) or (len(name) > 1 and name[1] == ":"):
        return "has an absolute path"
    if ".." in name.replace("\\", "/").split("/"):
        return "has a '..' part in its path"
    return None


def _directory_extent(fh: BinaryIO) -> tuple[int, int]:
    """(members, bytes) of the central directory, from the end record (ZIP64 when present)."""
    fh.seek(0, os.SEEK_END)
    end = fh.tell()
    tail_len = min(end, 22 + 0xFFFF + 20)  # end record + longest comment + ZIP64 locator
    fh.seek(end - tail_len)
    tail = fh.read(tail_len)
    at = tail.rfind(_EOCD)
    if at < 0 or at + 22 > len(tail):
        raise ValueError("no end of central directory record")
    count, size = struct.unpack_from("<HI", tail, at + 10)
    locator = at - 20
    if locator >= 0 and tail[locator:locator + 4] == _ZIP64_LOCATOR:
        fh.seek(struct.unpack_from("<Q", tail, locator + 8)[0])
        record = fh.read(56)
        if record[:4] == _ZIP64_EOCD:
            count, size = struct.unpack_from("<QQ", record, 32)
    return count, size
