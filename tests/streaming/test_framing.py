"""Binary messages: header + payload, and live frame sets split per camera."""
import struct

import pytest

from workers.streaming.framing import FramingError, pack_message, unpack_frame_set, unpack_message

NAMES = ["cam00", "cam01", "cam02"]


def test_pack_then_unpack_round_trips():
    data = pack_message({"type": "frame", "id": 7}, [b"\xff\xd8abc", b"def"])
    assert struct.unpack(">I", data[:4])[0] == len(b'{"type":"frame","id":7}')
    header, payload = unpack_message(data)
    assert header == {"type": "frame", "id": 7}
    assert bytes(payload) == b"\xff\xd8abcdef"


def test_frame_set_is_split_in_rig_order_even_when_sent_in_another():
    data = pack_message({"sizes": [1, 2, 3], "cameras": ["cam02", "cam00", "cam01"], "seq": 4, "background": True},
                        [b"c", b"aa", b"bbb"])
    fs = unpack_frame_set(data, NAMES)
    assert fs.jpegs == [b"aa", b"bbb", b"c"]
    assert fs.seq == 4 and fs.background is True


@pytest.mark.parametrize("data, problem", [
    (b"\x00\x00", "4-byte header length"),
    (struct.pack(">I", 100) + b"{}", "runs past the end"),
    (struct.pack(">I", 3) + b"{x}", "not UTF-8 JSON"),
    (struct.pack(">I", 2) + b"[]", "JSON object"),
    (pack_message({"sizes": [1, 1]}, [b"a", b"b"]), "holds 2 images; the rig has 3 cameras"),
    (pack_message({"sizes": [1, 1, 1]}, [b"a", b"b"]), "add up to 3 bytes but the payload has 2"),
    (pack_message({"sizes": [1, 0, 1]}, [b"a", b"b"]), "positive integers"),
    (pack_message({}, [b"abc"]), "needs 'sizes'"),
    (pack_message({"sizes": [1, 1, 1], "cameras": ["cam00", "cam00", "x"]}, [b"a", b"b", b"c"]), "name each rig camera"),
    (pack_message({"sizes": [1, 1, 1], "background": "yes"}, [b"a", b"b", b"c"]), "true or false"),
])
def test_malformed_frame_sets_say_what_is_wrong(data, problem):
    with pytest.raises(FramingError, match=problem):
        unpack_frame_set(data, NAMES)


def test_a_header_nested_too_deeply_is_a_framing_error():
    head = b"[" * 30000 + b"]" * 30000  # within the header limit, beyond the parser's recursion limit
    with pytest.raises(FramingError, match="nested too deeply"):
        unpack_message(struct.pack(">I", len(head)) + head)


def test_a_channel_to_a_peer_that_left_stops_sending_without_raising():
    import asyncio

    from starlette.websockets import WebSocketDisconnect

    from app.routers.rig_sockets import Channel

    class Gone:  # a socket whose peer closed before the server's hello
        sent = 0

        async def send_text(self, text):
            Gone.sent += 1
            raise WebSocketDisconnect(code=1006)

        async def close(self, code, reason):
            raise AssertionError("no close after the peer left")

    async def run():
        channel = Channel(Gone())
        await channel.json({"type": "hello"})
        await channel.error("x", "y")
        await channel.close(1000, "bye")
        return channel.closed

    assert asyncio.run(run()) and Gone.sent == 1
