"""Frame sets of recordings for viewers that render in their browser: atlases made once per (recording, frame,
source factor, format) and kept in a bounded in-memory cache of the API process, so that many viewers asking for
the same frame set cost one encode. Their URLs never change (a recording is immutable), so the browser and any
proxy cache them too (the route sends ``Cache-Control: immutable`` and an ETag)."""
from __future__ import annotations

import asyncio
from collections import OrderedDict
from dataclasses import dataclass

from workers.streaming.browser import encode_atlas, frame_atlas
from workers.streaming.recording import RecordingArchive
from workers.streaming.store import archive_key
from workers.sweep.rig import Rig

ATLAS_VERSION = 1
"""Part of every ETag: bump it when the atlas layout or encoding changes."""


@dataclass(frozen=True)
class AtlasKey:
    """One encoded frame set: ``frame`` an index or "background"."""

    recording_id: str
    frame: int | str
    factor: int
    image_format: str
    quality: int

    @property
    def etag(self) -> str:
        quality = self.quality if self.image_format == "jpeg" else 0
        return f'"{self.recording_id}.{self.frame}.{self.factor}.{self.image_format}{quality}.v{ATLAS_VERSION}"'


class AtlasCache:
    """Encoded atlases, least recently used out past ``max_bytes``; concurrent requests for one key wait for
    the first one's encode instead of encoding it again."""

    def __init__(self, max_bytes: int) -> None:
        self.max_bytes = max_bytes
        self._items: OrderedDict[AtlasKey, bytes] = OrderedDict()
        self._pending: dict[AtlasKey, asyncio.Future] = {}
        self.bytes = 0
        self.encoded = 0

    async def get(self, key: AtlasKey, make) -> bytes:
        """The atlas of ``key``, from the cache or from ``make()`` (an awaitable factory of bytes)."""
        if key in self._items:
            self._items.move_to_end(key)
            return self._items[key]
        if key in self._pending:
            return await asyncio.shield(self._pending[key])
        future = asyncio.get_running_loop().create_future()
        self._pending[key] = future
        try:
            data = await make()
        except BaseException as exc:
            future.set_exception(exc)
            future.exception()  # retrieved: a failure nobody else awaited is not logged as unhandled
            raise
        finally:
            self._pending.pop(key, None)
        future.set_result(data)
        self.encoded += 1
        self._items[key] = data
        self.bytes += len(data)
        while self.bytes > self.max_bytes and len(self._items) > 1:
            _, old = self._items.popitem(last=False)
            self.bytes -= len(old)
        return data


def build_atlas(store, rig: Rig, key: AtlasKey) -> bytes:
    """Read, shrink, undistort, tile and encode one frame set of a stored recording (blocking; CPU)."""
    archive = RecordingArchive(store.local_path(archive_key(key.recording_id)))
    try:
        images = archive.backgrounds() if key.frame == "background" else archive.frame_set(int(key.frame))
    finally:
        archive.close()
    return encode_atlas(frame_atlas(images, rig, key.factor), key.image_format, key.quality)
