"""RTSP cameras served by the tests themselves: H.264 over RTP, interleaved on the RTSP connection (TCP), with
RTCP sender reports that carry each camera's own wall clock.

A :class:`Camera` is triggered at the rig's common instants (``start + k / fps``, plus its capture jitter), draws
the trigger index ``k`` into its picture (:func:`draw_instant`, read back by :func:`read_instant`), stamps the frame
with its own clock (the true instant plus ``clock_offset``), encodes it (libx264 through PyAV) and sends it to every
client that has asked to PLAY, after ``network_jitter`` of delay. Its sender reports map that clock to the RTP
timestamps as a camera does (RFC 3550 6.4.1), so a reader that trusts them gets the camera's clock; with
``sender_reports=False`` it sends none (the reader must anchor its timestamps at arrival).

:class:`RtspServer` serves cameras at ``rtsp://127.0.0.1:PORT/NAME`` (OPTIONS, DESCRIBE, SETUP with TCP
interleaving only, PLAY, GET_PARAMETER, TEARDOWN: what FFmpeg's RTSP client sends). ``stop``/``start`` of one
camera drops its clients and refuses new ones (404) until it is back. :class:`SilentServer` accepts connections
and never answers.

Test and benchmark code only: the capture side under test (``app/capture``) reads these streams through PyAV as it reads a
real camera's.
"""
from __future__ import annotations

import base64
import contextlib
import random
import socket
import struct
import threading
import time
from dataclasses import dataclass, field
from fractions import Fraction

import av
import numpy as np

RTP_CLOCK = 90_000
NTP_EPOCH_OFFSET = 2_208_988_800  # seconds from 1900-01-01 (NTP) to 1970-01-01 (Unix)
MAX_RTP_PAYLOAD = 1400
INSTANT_BITS = 16
CELL = 8  # px: one bit of the drawn instant


def draw_instant(image: np.ndarray, k: int) -> None:
    """Draw ``k`` (0 <= k < 2**16) into the top rows of ``image`` (H, W, 3) uint8, in place: one CELL x CELL
    block per bit, white for 1, black for 0, most significant first, 8 bits a row (two rows). Survives H.264."""
    for bit in range(INSTANT_BITS):
        row, col = divmod(bit, 8)
        on = (k >> (INSTANT_BITS - 1 - bit)) & 1
        image[row * CELL:(row + 1) * CELL, col * CELL:(col + 1) * CELL] = 255 if on else 0


def read_instant(image: np.ndarray) -> int:
    """The ``k`` that :func:`draw_instant` drew into ``image`` (BGR or grey, any size it fits)."""
    grey = image if image.ndim == 2 else image.mean(axis=2)
    k = 0
    for bit in range(INSTANT_BITS):
        row, col = divmod(bit, 8)
        centre = grey[row * CELL + CELL // 2 - 1:row * CELL + CELL // 2 + 1, col * CELL + CELL // 2 - 1:col * CELL + CELL // 2 + 1]
        k = (k << 1) | int(centre.mean() > 127)
    return k


@dataclass
class Camera:
    """One simulated camera (see the module docstring). Times in seconds; ``picture(k)`` gives the picture of
    trigger ``k`` before the instant is drawn into it ((height, width, 3) uint8 BGR; default a grey ramp)."""

    name: str
    width: int = 160
    height: int = 120
    fps: float = 25.0
    clock_offset: float = 0.0
    capture_jitter: float = 0.0
    network_jitter: float = 0.0
    sender_reports: bool = True
    picture: object = None
    access_units: list[bytes] | None = None
    """Pre-encoded H.264 access units (Annex B) sent in a loop instead of encoding live (the benchmark's cameras:
    no encoder on the measured cores; a client joining waits for the loop's next IDR). The first must be an IDR."""
    seed: int = 0
    sent: dict[int, float] = field(default_factory=dict)
    """trigger index -> true capture instant (``time.time()`` clock) of every frame encoded."""

    def __post_init__(self) -> None:
        self._rng = random.Random(self.seed)
        self._clients: list[_Client] = []
        self._lock = threading.Lock()
        self._running = threading.Event()
        self._thread: threading.Thread | None = None
        self._keyframe = threading.Event()
        self.ssrc = self._rng.getrandbits(32)
        self._seq = self._octets = self._packets = 0
        self.parameter_sets = self._parameter_sets()

    # --- the camera's clock ---------------------------------------------------------------------------
    def clock(self, true_time: float) -> float:
        """This camera's wall clock (s since the Unix epoch) at the true instant ``true_time``."""
        return true_time + self.clock_offset

    def rtp_time(self, true_time: float) -> int:
        return int(round(self.clock(true_time) * RTP_CLOCK)) & 0xFFFFFFFF

    # --- running --------------------------------------------------------------------------------------
    def start(self, epoch: float) -> None:
        """Capture at ``epoch + k / fps`` from the next such instant on (frames keep their trigger index)."""
        if self._running.is_set():
            return
        self._running.set()
        self._thread = threading.Thread(target=self._run, args=(epoch,), name=f"camera-{self.name}", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop capturing and drop every client (as a camera that loses power does)."""
        self._running.clear()
        if self._thread is not None:
            self._thread.join(timeout=5)
        with self._lock:
            clients, self._clients = self._clients, []
        for c in clients:
            c.close()

    @property
    def running(self) -> bool:
        return self._running.is_set()

    def add_client(self, client: "_Client") -> None:
        with self._lock:
            self._clients.append(client)
        self._keyframe.set()  # a new client needs an IDR picture to start decoding

    def remove_client(self, client: "_Client") -> None:
        with self._lock:
            if client in self._clients:
                self._clients.remove(client)

    def _encoder(self) -> av.VideoCodecContext:
        enc = av.CodecContext.create("libx264", "w")
        enc.width, enc.height, enc.pix_fmt = self.width, self.height, "yuv420p"
        enc.time_base = Fraction(1, RTP_CLOCK)
        enc.framerate = Fraction(self.fps).limit_denominator(1000)
        enc.options = {"preset": "ultrafast", "tune": "zerolatency", "g": str(int(self.fps * 2)),
                       "x264-params": "repeat-headers=1"}  # SPS/PPS with every IDR: a late client can start there
        return enc

    def _parameter_sets(self) -> tuple[bytes, bytes]:
        if self.access_units:
            nals = split_nals(self.access_units[0])
            return next(n for n in nals if n[0] & 0x1F == 7), next(n for n in nals if n[0] & 0x1F == 8)
        enc = self._encoder()
        frame = av.VideoFrame.from_ndarray(np.zeros((self.height, self.width, 3), np.uint8), format="bgr24")
        frame.pts = 0
        nals = [n for p in [*enc.encode(frame), *enc.encode(None)] for n in split_nals(bytes(p))]
        sps = next(n for n in nals if n[0] & 0x1F == 7)
        pps = next(n for n in nals if n[0] & 0x1F == 8)
        return sps, pps

    def _run(self, epoch: float) -> None:
        enc = None if self.access_units else self._encoder()
        period = 1.0 / self.fps
        k = max(0, int(np.ceil((time.time() - epoch) / period)))
        last_report = 0.0
        while self._running.is_set():
            trigger = epoch + k * period
            captured = trigger + self._rng.uniform(-self.capture_jitter, self.capture_jitter)
            delay = captured - time.time()
            if delay > 0:
                time.sleep(delay)
            elif delay < -period:  # fell behind (a loaded machine): skip to the next trigger, as a camera drops frames
                k = int(np.ceil((time.time() - epoch) / period))
                continue
            payload = self._encoded(enc, k, captured)
            self.sent[k] = captured
            if self.network_jitter:
                time.sleep(self._rng.uniform(0, self.network_jitter))
            now = time.time()
            if self.sender_reports and now - last_report >= 1.0:
                self._broadcast(1, self._sender_report(now))
                last_report = now
            if payload:
                for packet in self._rtp_packets(split_nals(payload), self.rtp_time(captured)):
                    self._broadcast(0, packet)
            k += 1

    def _encoded(self, enc: av.VideoCodecContext | None, k: int, captured: float) -> bytes:
        """Trigger ``k``'s access unit: the next of the loop, or its picture (instant drawn in) encoded now."""
        if enc is None:
            return self.access_units[k % len(self.access_units)]
        image = self._picture(k)
        draw_instant(image, k & 0xFFFF)
        frame = av.VideoFrame.from_ndarray(image, format="bgr24")
        frame.pts = int(round(self.clock(captured) * RTP_CLOCK))
        if self._keyframe.is_set():
            self._keyframe.clear()
            frame.pict_type = av.video.frame.PictureType.I
        return b"".join(bytes(p) for p in enc.encode(frame))

    def _picture(self, k: int) -> np.ndarray:
        if callable(self.picture):
            return np.ascontiguousarray(self.picture(k), dtype=np.uint8).copy()
        ramp = np.linspace(40, 215, self.width, dtype=np.float32)[None, :, None]
        shift = (k * 3) % 60
        return np.broadcast_to(ramp + shift, (self.height, self.width, 3)).astype(np.uint8).copy()

    # --- RTP and RTCP -----------------------------------------------------------------------------------
    def _rtp_packets(self, nals: list[bytes], timestamp: int) -> list[bytes]:
        """RFC 6184 packetisation: one NAL unit per packet, or fragmentation units (FU-A) for large ones; the
        marker bit on the access unit's last packet."""
        payloads: list[bytes] = []
        for nal in nals:
            if len(nal) <= MAX_RTP_PAYLOAD:
                payloads.append(nal)
                continue
            indicator = (nal[0] & 0xE0) | 28
            body = nal[1:]
            for start in range(0, len(body), MAX_RTP_PAYLOAD):
                first, last = start == 0, start + MAX_RTP_PAYLOAD >= len(body)
                header = (0x80 if first else 0) | (0x40 if last else 0) | (nal[0] & 0x1F)
                payloads.append(bytes([indicator, header]) + body[start:start + MAX_RTP_PAYLOAD])
        out = []
        for i, payload in enumerate(payloads):
            marker = 0x80 if i == len(payloads) - 1 else 0
            out.append((struct.pack(">BBHII", 0x80, marker | 96, self._next_seq(), timestamp, self.ssrc)
                        + payload, len(payload)))
        self._octets += sum(n for _, n in out)
        self._packets += len(out)
        return [p for p, _ in out]

    def _next_seq(self) -> int:
        self._seq = (self._seq + 1) & 0xFFFF
        return self._seq

    def _sender_report(self, true_now: float) -> bytes:
        """An RTCP SR (RFC 3550 6.4.1): this camera's clock now as NTP, and the RTP timestamp of that instant."""
        ntp = self.clock(true_now) + NTP_EPOCH_OFFSET
        seconds = int(ntp)
        fraction = int((ntp - seconds) * (1 << 32)) & 0xFFFFFFFF
        return struct.pack(">BBHIIIIII", 0x80, 200, 6, self.ssrc, seconds, fraction, self.rtp_time(true_now),
                           self._packets, self._octets)

    def _broadcast(self, channel: int, packet: bytes) -> None:
        with self._lock:
            clients = list(self._clients)
        for c in clients:
            if c.playing:
                c.send_interleaved(channel, packet)


def encode_loop(images: list[np.ndarray], fps: float, gop: int, bit_rate: int | None = None) -> list[bytes]:
    """``images`` ((H, W, 3) uint8 BGR) as H.264 access units for :attr:`Camera.access_units`: an IDR every
    ``gop`` frames (the loop starts with one), SPS/PPS with each, no B-frames; ``bit_rate`` (bits/s): an IP camera's
    constant bit rate instead of x264's default quality."""
    height, width = images[0].shape[:2]
    enc = av.CodecContext.create("libx264", "w")
    enc.width, enc.height, enc.pix_fmt = width, height, "yuv420p"
    enc.time_base = Fraction(1, RTP_CLOCK)
    enc.framerate = Fraction(fps).limit_denominator(1000)
    enc.options = {"preset": "veryfast", "tune": "zerolatency", "g": str(gop), "keyint_min": str(gop),
                   "x264-params": "repeat-headers=1:scenecut=0"}
    if bit_rate:
        enc.bit_rate = bit_rate
        enc.options = {**enc.options, "maxrate": str(bit_rate), "bufsize": str(bit_rate // 2)}
    units = []
    for i, image in enumerate(images):
        frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(image), format="bgr24")
        frame.pts = i
        units += [bytes(p) for p in enc.encode(frame)]
    units += [bytes(p) for p in enc.encode(None)]
    return units


def split_nals(data: bytes) -> list[bytes]:
    """The NAL units of an Annex B byte stream (start codes removed)."""
    parts = data.replace(b"\x00\x00\x00\x01", b"\x00\x00\x01").split(b"\x00\x00\x01")
    return [p.rstrip(b"\x00") if i < len(parts) - 1 else p for i, p in enumerate(parts) if p]


class _Client:
    """One RTSP connection: its requests are answered on its own thread; frames are written by the camera's."""

    def __init__(self, server: "RtspServer", conn: socket.socket) -> None:
        self.server = server
        self.conn = conn
        self.camera: Camera | None = None
        self.playing = False
        self._send_lock = threading.Lock()
        self.closed = False

    def send_interleaved(self, channel: int, packet: bytes) -> None:
        try:
            with self._send_lock:
                self.conn.sendall(struct.pack(">BBH", 0x24, channel, len(packet)) + packet)
        except OSError:
            self.close()

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        if self.camera is not None:
            self.camera.remove_client(self)
        with contextlib.suppress(OSError):
            self.conn.shutdown(socket.SHUT_RDWR)
        with contextlib.suppress(OSError):
            self.conn.close()

    def serve(self) -> None:
        buf = b""
        try:
            while not self.closed:
                while buf[:1] == b"$":  # the client's own RTCP (receiver reports), interleaved: skipped
                    if len(buf) < 4:
                        break
                    size = struct.unpack(">H", buf[2:4])[0]
                    if len(buf) < 4 + size:
                        break
                    buf = buf[4 + size:]
                end = buf.find(b"\r\n\r\n")
                if buf[:1] != b"$" and end >= 0:
                    head, buf = buf[:end].decode("latin-1"), buf[end + 4:]
                    lines = head.split("\r\n")
                    headers = {k.strip().lower(): v.strip() for k, v in (l.split(":", 1) for l in lines[1:] if ":" in l)}
                    body_len = int(headers.get("content-length", 0))
                    while len(buf) < body_len:
                        buf += self._recv()
                    buf = buf[body_len:]
                    self._answer(lines[0].split(" "), headers)
                    continue
                buf += self._recv()
        except (OSError, ConnectionError):
            pass
        finally:
            self.close()

    def _recv(self) -> bytes:
        data = self.conn.recv(65536)
        if not data:
            raise ConnectionError("closed")
        return data

    def _reply(self, cseq: str, status: str = "200 OK", headers: dict[str, str] | None = None, body: str = "") -> None:
        lines = [f"RTSP/1.0 {status}", f"CSeq: {cseq}", *(f"{k}: {v}" for k, v in (headers or {}).items())]
        if body:
            lines.append(f"Content-Length: {len(body.encode())}")
        with self._send_lock:
            self.conn.sendall(("\r\n".join(lines) + "\r\n\r\n" + body).encode())

    def _answer(self, request: list[str], headers: dict[str, str]) -> None:
        method, url = request[0], request[1] if len(request) > 1 else ""
        cseq = headers.get("cseq", "0")
        name = url.split("://", 1)[-1].split("/", 1)[-1].split("/")[0] if "/" in url.split("://", 1)[-1] else ""
        camera = self.server.cameras.get(name)
        if method == "OPTIONS":
            self._reply(cseq, headers={"Public": "OPTIONS, DESCRIBE, SETUP, PLAY, GET_PARAMETER, TEARDOWN"})
        elif camera is None or not camera.running:
            self._reply(cseq, "404 Not Found")
        elif method == "DESCRIBE":
            self._reply(cseq, headers={"Content-Type": "application/sdp", "Content-Base": f"{url.rstrip('/')}/"},
                        body=self._sdp(camera))
        elif method == "SETUP":
            if "TCP" not in headers.get("transport", "").upper():
                self._reply(cseq, "461 Unsupported Transport")
                return
            self.camera = camera
            self._reply(cseq, headers={"Transport": "RTP/AVP/TCP;unicast;interleaved=0-1",
                                       "Session": "cafe0001;timeout=60"})
        elif method == "PLAY":
            self._reply(cseq, headers={"Session": "cafe0001", "Range": "npt=0.000-"})
            self.playing = True
            camera.add_client(self)
            if camera.sender_reports:  # the first report at once: a reader knows the camera's clock from the start
                self.send_interleaved(1, camera._sender_report(time.time()))
        elif method in ("GET_PARAMETER", "SET_PARAMETER"):
            self._reply(cseq, headers={"Session": "cafe0001"})
        elif method == "TEARDOWN":
            self._reply(cseq, headers={"Session": "cafe0001"})
            self.close()
        else:
            self._reply(cseq, "405 Method Not Allowed")

    @staticmethod
    def _sdp(camera: Camera) -> str:
        sps, pps = camera.parameter_sets
        sets = ",".join(base64.b64encode(x).decode() for x in (sps, pps))
        return ("v=0\r\no=- 0 0 IN IP4 127.0.0.1\r\ns=sweepcast test camera\r\nc=IN IP4 0.0.0.0\r\nt=0 0\r\n"
                "m=video 0 RTP/AVP 96\r\na=rtpmap:96 H264/90000\r\n"
                f"a=fmtp:96 packetization-mode=1;profile-level-id={sps[1:4].hex()};sprop-parameter-sets={sets}\r\n"
                "a=control:track0\r\n")


class RtspServer:
    """Serves ``cameras`` (by name) on one loopback port; a context manager."""

    def __init__(self, cameras: list[Camera], port: int = 0) -> None:
        self.cameras = {c.name: c for c in cameras}
        self._sock = socket.create_server(("127.0.0.1", port))
        self.port = self._sock.getsockname()[1]
        self._clients: list[_Client] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._accept, name="rtsp-server", daemon=True)

    def url(self, name: str) -> str:
        return f"rtsp://127.0.0.1:{self.port}/{name}"

    def __enter__(self) -> "RtspServer":
        self._thread.start()
        epoch = time.time()
        for c in self.cameras.values():
            c.start(epoch)
        self.epoch = epoch
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        for c in self.cameras.values():
            c.stop()
        with contextlib.suppress(OSError):
            self._sock.close()
        for c in list(self._clients):
            c.close()

    def _accept(self) -> None:
        for conn in accepted(self._sock, self._stop):
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            client = _Client(self, conn)
            self._clients.append(client)
            threading.Thread(target=client.serve, name="rtsp-client", daemon=True).start()


def accepted(sock: socket.socket, stop: threading.Event):
    """The connections ``sock`` accepts until ``stop`` is set or it is closed."""
    sock.settimeout(0.2)
    while not stop.is_set():
        try:
            conn, _ = sock.accept()
        except TimeoutError:
            continue
        except OSError:
            return
        yield conn


class SilentServer:
    """A TCP port that accepts connections and never says a word (a camera that hangs); a context manager."""

    def __init__(self) -> None:
        self._sock = socket.create_server(("127.0.0.1", 0))
        self.port = self._sock.getsockname()[1]
        self.accepted: list[socket.socket] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._accept, daemon=True)

    def url(self, name: str = "cam") -> str:
        return f"rtsp://127.0.0.1:{self.port}/{name}"

    def __enter__(self) -> "SilentServer":
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        with contextlib.suppress(OSError):
            self._sock.close()
        for s in self.accepted:
            with contextlib.suppress(OSError):
                s.close()

    def _accept(self) -> None:
        for conn in accepted(self._sock, self._stop):
            self.accepted.append(conn)  # held open, never read or written
