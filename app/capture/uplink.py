"""The uplink: frame sets to the service over the rig's live socket (``/v1/rigs/{id}/live``), acknowledgements back.

Each set is one binary message (:func:`workers.streaming.framing.pack_message`): the header ``{"seq", "sizes",
"captured": [capture time of each frame, s since the Unix epoch, rig order], "stale": [names of the cameras whose
frame is not of this instant], "tolerance": s, "background": bool}`` and one JPEG per camera in rig order. At most
``in_flight`` sets wait for their acknowledgement; a set made while the service is that far behind is dropped (the
next one is newer). A lost connection is opened again (0.25 s, doubling up to ``max_backoff_seconds``) by the
uplink's own thread while the cameras go on; sets made meanwhile are dropped and counted.
"""
from __future__ import annotations

import collections
import json
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Callable

from websockets.exceptions import ConnectionClosed, InvalidHandshake, InvalidStatus
from websockets.sync.client import ClientConnection, connect

from workers.streaming.framing import pack_message

from .assembly import FrameSet, black_jpeg
from .settings import CaptureSettings

POLICY_VIOLATION = 1008


class UplinkError(RuntimeError):
    """The service refused the live socket or cannot be reached (the message says which and why)."""


def live_url(server: str, rig_id: str) -> str:
    """The live socket's URL on ``server`` (``http(s)://host:port`` or ``ws(s)://...``)."""
    base = server.rstrip("/")
    if base.startswith("http"):
        base = "ws" + base[4:]
    return f"{base}/v1/rigs/{rig_id}/live"


class Uplink:
    """The live socket of rig ``rig_id`` on ``server`` (see the module docstring). ``report(message)`` hears of
    every error the service answers and every lost or regained connection."""

    def __init__(self, server: str, rig_id: str, key: str | None, settings: CaptureSettings,
                 report: Callable[[str], None] = lambda message: None) -> None:
        self.url = live_url(server, rig_id)
        self.headers = {"Authorization": f"Bearer {key}"} if key else {}
        self.settings = settings
        self.report = report
        self.hello: dict[str, Any] | None = None
        self.cameras: list[dict[str, Any]] = []
        self._ws: ClientConnection | None = None
        self._lock = threading.Lock()
        self._pending: dict[int, float] = {}
        self._stop = threading.Event()
        self._encoder = ThreadPoolExecutor(max_workers=4, thread_name_prefix="jpeg")  # cv2 releases the GIL
        self._thread: threading.Thread | None = None
        self._black: dict[int, bytes] = {}
        self.seq = 0
        self.sent = 0
        self.acked = 0
        self.dropped = 0
        self.reconnects = 0
        self.errors: collections.Counter[str] = collections.Counter()
        self.ack_ms: collections.deque[float] = collections.deque(maxlen=100)
        self.acks: collections.deque[dict[str, Any]] = collections.deque(maxlen=100)

    # --- connection -----------------------------------------------------------------------------------------
    def open(self) -> dict[str, Any]:
        """Connect once and return the service's hello (its ``cameras``: name, width, height in rig order);
        UplinkError when refused or unreachable. Then keeps the connection (reconnecting) on its own thread."""
        self._connect()
        self._thread = threading.Thread(target=self._run, name="uplink", daemon=True)
        self._thread.start()
        return self.hello

    def _connect(self) -> None:
        try:
            ws = connect(self.url, additional_headers=self.headers, max_size=None, compression=None,
                         open_timeout=self.settings.open_timeout_seconds)
        except InvalidStatus as exc:
            raise UplinkError(f"{self.url}: the service answered HTTP {exc.response.status_code}") from None
        except (OSError, InvalidHandshake, TimeoutError) as exc:
            raise UplinkError(f"{self.url}: cannot reach the service ({exc})") from None
        try:
            message = json.loads(ws.recv(timeout=self.settings.open_timeout_seconds))
            if message.get("type") == "error":
                raise UplinkError(f"{self.url}: {message.get('detail') or message.get('error')}")
        except ConnectionClosed as exc:
            raise UplinkError(f"{self.url}: the service closed the socket ({exc.rcvd.reason if exc.rcvd else exc})") from None
        except TimeoutError:
            ws.close()
            raise UplinkError(f"{self.url}: the service said nothing within {self.settings.open_timeout_seconds:g} s") from None
        self.hello = message
        self.cameras = message["cameras"]
        with self._lock:
            self._pending.clear()
            self._ws = ws

    def close(self) -> None:
        self._stop.set()
        with self._lock:
            ws, self._ws = self._ws, None
        if ws is not None:
            ws.close()
        if self._thread is not None:
            self._thread.join(timeout=5)
        self._encoder.shutdown(wait=False)

    @property
    def connected(self) -> bool:
        return self._ws is not None

    def unacknowledged(self) -> tuple[int, float]:
        """How many sets wait for their acknowledgement, and for how long the oldest has (s; 0 when none)."""
        with self._lock:
            oldest = min(self._pending.values(), default=None)
            count = len(self._pending)
        return count, (time.monotonic() - oldest if oldest is not None else 0.0)

    def _run(self) -> None:
        """Read acknowledgements; when the connection is lost, open it again with backoff."""
        backoff = 0.25
        while not self._stop.is_set():
            ws = self._ws
            if ws is not None:
                try:
                    for text in ws:
                        self._answer(json.loads(text))
                    reason = "the service closed the socket"
                except ConnectionClosed as exc:
                    reason = f"the connection was lost ({exc.rcvd.reason if exc.rcvd and exc.rcvd.reason else exc})"
                except (OSError, ValueError) as exc:
                    reason = f"the connection failed ({exc})"
                with self._lock:
                    self._ws = None
                if self._stop.is_set():
                    return
                self.report(f"service: {reason}; connecting again")
            if self._stop.wait(backoff):
                return
            try:
                self._connect()
            except UplinkError as exc:
                backoff = min(backoff * 2, self.settings.max_backoff_seconds)
                self.report(f"service: {exc}; trying again in {backoff:g} s")
                continue
            backoff = 0.25
            self.reconnects += 1
            self.report("service: connected again")

    def _answer(self, message: dict[str, Any]) -> None:
        kind = message.get("type")
        if kind not in ("ack", "error"):
            return
        seq = message.get("seq")
        with self._lock:
            sent_at = self._pending.pop(seq, None) if isinstance(seq, int) else None
        if kind == "ack":
            self.acked += 1
            if sent_at is not None:
                self.ack_ms.append((time.monotonic() - sent_at) * 1e3)
            self.acks.append(message)
        else:
            code = message.get("error", "error")
            self.errors[code] += 1
            self.report(f"service: set {seq} refused: {code}: {message.get('detail', '')}")

    # --- sending --------------------------------------------------------------------------------------------
    def send(self, frame_set: FrameSet, tolerance: float, background: bool = False) -> bool:
        """Send ``frame_set`` (tolerance in s); False when it was dropped (not connected, or ``in_flight`` sets
        still unacknowledged)."""
        with self._lock:
            ready = self._ws is not None and len(self._pending) < self.settings.in_flight
        if not ready:
            self.dropped += 1
            return False
        jpegs = list(self._encoder.map(self._jpeg, range(len(self.cameras)), frame_set.frames))
        captured = [t if t is not None else frame_set.instant for t in frame_set.captured]
        self.seq += 1
        header = {"seq": self.seq, "sizes": [len(j) for j in jpegs], "captured": captured,
                  "stale": [c["name"] for c, s in zip(self.cameras, frame_set.stale) if s],
                  "tolerance": tolerance, "background": background}
        message = pack_message(header, jpegs)
        with self._lock:
            ws = self._ws
            if ws is None:
                self.dropped += 1
                return False
            self._pending[self.seq] = time.monotonic()
        try:
            ws.send(message)
        except (ConnectionClosed, OSError):
            with self._lock:
                self._pending.pop(self.seq, None)
            self.dropped += 1
            return False
        self.sent += 1
        return True

    def _jpeg(self, camera: int, frame: Any) -> bytes:
        if frame is not None:
            return frame.jpeg(self.settings.jpeg_quality)
        if camera not in self._black:
            c = self.cameras[camera]
            self._black[camera] = black_jpeg((c["width"], c["height"]))
        return self._black[camera]
