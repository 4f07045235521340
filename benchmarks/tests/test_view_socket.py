"""The benchmarks' wait for a view socket's frame: past text messages and other viewpoints' frames, failing on an
error message instead of waiting forever."""
from __future__ import annotations

import asyncio
import json

import pytest

from benchmarks.streaming import frame_reply
from workers.streaming.framing import pack_message


class Socket:
    def __init__(self, messages: list) -> None:
        self.messages = list(messages)

    async def recv(self):
        return self.messages.pop(0)


def frame(view_id: int) -> bytes:
    return pack_message({"type": "frame", "id": view_id}, [b"jpeg"])


def test_the_frame_of_the_viewpoint_asked_for_after_text_and_older_frames():
    ws = Socket([json.dumps({"type": "ready"}), frame(1), json.dumps({"type": "stats"}), frame(2), frame(3)])
    assert asyncio.run(frame_reply(ws, 2)) == frame(2)
    assert asyncio.run(frame_reply(ws)) == frame(3)


def test_an_error_message_ends_the_wait_with_the_server_s_words():
    ws = Socket([json.dumps({"type": "ready"}), json.dumps({"type": "error", "error": "no such recording"})])
    with pytest.raises(RuntimeError, match="no such recording"):
        asyncio.run(frame_reply(ws, 1))
