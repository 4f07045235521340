"""Reading uploaded files within the configured limits."""
from __future__ import annotations

from fastapi import UploadFile

from app.errors import ApiError


def check_size(file: UploadFile, limit: int) -> None:
    """413 when an upload (already spooled by the form parser) is larger than ``limit`` bytes."""
    if file.size is not None and file.size > limit:
        raise ApiError(413, f"{file.filename or 'the file'} is {file.size} bytes; the limit is {limit}",
                       "payload_too_large")


async def read_upload(file: UploadFile, limit: int) -> bytes:
    check_size(file, limit)
    return await file.read()
