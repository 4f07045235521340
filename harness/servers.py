"""Throw-away servers on loopback for tests and benchmarks: PostgreSQL, a Ray cluster and the service itself.

None of them outlives the process that started it, however that process ends:

- a normal exit, an exception or Ctrl-C leaves the ``with`` block, whose ``finally`` stops the server;
- a script wraps its work in :func:`exit_on_sigterm`: SIGTERM then raises SystemExit, so the same
  ``finally`` blocks run (not installed here for everyone: under pytest a SystemExit would only
  fail the running test, and the run would go on);
- any other death (SIGKILL, SIGTERM without that handler) runs nothing in the dying process, so each
  server has a watchdog process beside it (:func:`watch`) that stops it once its starter's pid is
  gone. The service, in its own process group, also gets SIGTERM from the kernel when the thread
  that started it dies (``setpriv --pdeathsig``, Linux): start servers from a thread that lives as
  long as they should.
"""
from __future__ import annotations

import contextlib
import glob
import os
import pwd
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

from workers.common.spawn import dying_with_parent


class Unavailable(RuntimeError):
    """The server cannot be started on this machine (the message says why)."""


# --- cleanup whatever ends the starter ---------------------------------------------------------------
ROOT = Path(__file__).resolve().parents[1]
CHECKOUT_KERNEL_CACHE = ROOT / "sweepcast-data" / "cache" / "numba"
"""The checkout's kernel cache: the tests use it (conftest), so servers started from here load the kernels an
earlier test compiled instead of compiling them."""
WATCH_PERIOD_S = 0.2


@contextlib.contextmanager
def exit_on_sigterm() -> Iterator[None]:
    """Inside the block SIGTERM raises SystemExit(143), so ``finally`` blocks (and ``with`` exits) run,
    as they do for Ctrl-C. Only where Python can (the main thread) and only over the default action:
    a handler the program installed itself is left alone."""
    if threading.current_thread() is not threading.main_thread() or signal.getsignal(signal.SIGTERM) != signal.SIG_DFL:
        yield
        return

    def _raise(signum: int, _frame: object) -> None:
        raise SystemExit(128 + signum)

    signal.signal(signal.SIGTERM, _raise)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


def start_watchdog(*, group: int | None = None, marker: str | None = None, grace_s: float = 20.0
                   ) -> subprocess.Popen:
    """A process that outlives this one and, if this one dies without stopping it (SIGKILL), ends
    process group ``group`` (SIGTERM to its leader, SIGKILL to the group after ``grace_s``) or every
    process whose command line mentions ``marker``. Stop it (terminate) once the server is down."""
    args = [str(os.getpid()), str(group or 0), marker or "", str(grace_s)]
    return subprocess.Popen([sys.executable, "-c", "import sys; from harness.servers import watch; watch(*sys.argv[1:])",
                             *args], cwd=ROOT, start_new_session=True,  # Ctrl-C on a terminal is not for it
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL)


def watch(parent: str, group: str, marker: str, grace_s: str) -> None:
    """The watchdog's body (see :func:`start_watchdog`): poll until ``parent`` is gone, then clean up.
    SIGTERM (the parent's clean exit) ends it without touching anything."""
    while os.getppid() == int(parent):
        time.sleep(WATCH_PERIOD_S)
    if int(group):
        stop_group(int(group), float(grace_s))
    if marker:
        kill_mentioning(marker)


def alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie waiting to be reaped does not)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return False


def stop_group(leader: int, grace_s: float, proc: subprocess.Popen | None = None) -> None:
    """SIGTERM to ``leader`` (it shuts its own children down), up to ``grace_s`` for it to end, then
    SIGKILL to its whole process group: what the leader left behind, or the leader itself when late.
    ``proc``: the leader's Popen when we are its parent (it is reaped)."""
    try:
        with contextlib.suppress(ProcessLookupError):
            os.kill(leader, signal.SIGTERM)
        deadline = time.monotonic() + grace_s
        while time.monotonic() < deadline and (proc.poll() is None if proc is not None else alive(leader)):
            time.sleep(0.1)
    finally:  # even when a second Ctrl-C cuts the wait short
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(leader, signal.SIGKILL)
        if proc is not None:
            proc.wait()


def kill_mentioning(text: str) -> None:
    """SIGKILL every process whose command line mentions ``text``."""
    for pid in processes_mentioning(text):
        if pid != os.getpid():
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.kill(pid, signal.SIGKILL)


@contextlib.contextmanager
def guarded(*, group: int | None = None, marker: str | None = None, grace_s: float = 20.0) -> Iterator[None]:
    """A watchdog for the block's servers (see :func:`start_watchdog`), stopped when the block ends."""
    dog = start_watchdog(group=group, marker=marker, grace_s=grace_s)
    try:
        yield
    finally:
        dog.terminate()
        dog.wait()


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def postgres_bin(name: str) -> str | None:
    found = shutil.which(name)
    if found:
        return found
    candidates = sorted(glob.glob(f"/usr/lib/postgresql/*/bin/{name}"))
    return candidates[-1] if candidates else None


@dataclass
class PostgresServer:
    """A throw-away PostgreSQL cluster (initdb + pg_ctl) that a test or benchmark can stop and start again on the
    same port and data (a database outage); see :func:`temp_postgres`."""

    url: str
    """``postgresql://sweepcast@127.0.0.1:PORT``"""
    data: Path
    prefix: list[str]
    options: str

    def stop(self) -> None:
        """Stop at once (``-m immediate``: what a crash or a killed container does; open connections break)."""
        subprocess.run([*self.prefix, postgres_bin("pg_ctl"), "-D", str(self.data), "-m", "immediate", "stop"],
                       capture_output=True)

    def start(self) -> None:
        subprocess.run([*self.prefix, postgres_bin("pg_ctl"), "-D", str(self.data), "-l",
                        str(self.data.parent / "log"), "-w", "-t", "60", "start", "-o", self.options],
                       check=True, capture_output=True)


@contextlib.contextmanager
def postgres_server() -> Iterator[PostgresServer]:
    """A PostgreSQL cluster in a temp dir, running; stopped and removed when the block ends."""
    initdb, pg_ctl = postgres_bin("initdb"), postgres_bin("pg_ctl")
    if not initdb or not pg_ctl:
        raise Unavailable("no PostgreSQL binaries (initdb, pg_ctl): install Debian's postgresql package")
    base = Path(tempfile.mkdtemp(prefix="sweepcast-pg-"))  # not below a root-only temp folder
    data, sockets = base / "data", base / "sock"
    sockets.mkdir()
    prefix: list[str] = []
    if os.geteuid() == 0:  # PostgreSQL refuses to run as root
        try:
            user = pwd.getpwnam("postgres")
        except KeyError:
            shutil.rmtree(base, ignore_errors=True)
            raise Unavailable("running as root and there is no 'postgres' user to run PostgreSQL as") from None
        for path in (base, sockets):
            shutil.chown(path, user.pw_uid, user.pw_gid)
        prefix = ["runuser", "-u", "postgres", "--"]
    port = free_port()
    server = PostgresServer(f"postgresql://sweepcast@127.0.0.1:{port}", data, prefix,
                            f"-p {port} -k {sockets} -c listen_addresses=127.0.0.1 -c fsync=off")
    # pg_ctl daemonises the server: it leaves our process tree, so it is found by its data folder.
    with guarded(marker=str(base)):
        try:
            subprocess.run([*prefix, initdb, "-D", str(data), "-U", "sweepcast", "--auth=trust", "--no-sync",
                            "-E", "UTF8"], check=True, capture_output=True)
            server.start()
            yield server
        finally:
            server.stop()
            shutil.rmtree(base, ignore_errors=True)


@contextlib.contextmanager
def temp_postgres() -> Iterator[str]:
    """A PostgreSQL cluster in a temp dir; yields ``postgresql://sweepcast@127.0.0.1:PORT``."""
    with postgres_server() as server:
        yield server.url


def create_database(server_url: str, name: str) -> str:
    """Create database ``name`` on ``server_url`` and return its URL."""
    import sqlalchemy

    admin = sqlalchemy.create_engine(server_url.replace("postgresql://", "postgresql+psycopg://") + "/postgres",
                                     isolation_level="AUTOCOMMIT")
    with admin.connect() as conn:
        conn.exec_driver_sql(f'CREATE DATABASE "{name}"')
    admin.dispose()
    return f"{server_url}/{name}"


def processes_mentioning(text: str) -> list[int]:
    pids = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                if text in (entry / "cmdline").read_bytes().decode(errors="replace"):
                    pids.append(int(entry.name))
            except OSError:
                pass
    return pids


@contextlib.contextmanager
def ray_cluster(worker_nodes: int = 2, cpus_per_node: int = 1, resources: str = '{"sweepcast_worker": 1}'
                ) -> Iterator[str]:
    """A Ray head without task CPUs plus ``worker_nodes`` nodes, as `ray start` makes them; yields its address."""
    temp = tempfile.mkdtemp(prefix="scray-")  # short: Ray's socket paths must fit 107 bytes
    port = free_port()
    env = {**os.environ, "RAY_AUTH_MODE": "disabled", "RAY_USAGE_STATS_ENABLED": "0"}
    ray = str(Path(sys.executable).parent / "ray")
    common = [f"--temp-dir={temp}", "--disable-usage-stats"]
    # `ray start` daemonises its nodes: they leave our process tree, so they are found by their temp dir.
    with guarded(marker=temp):
        try:
            subprocess.run([ray, "start", "--head", f"--port={port}", "--num-cpus=0", "--include-dashboard=false",
                            *common], check=True, capture_output=True, env=env, timeout=120)
            for _ in range(worker_nodes):
                subprocess.run([ray, "start", f"--address=127.0.0.1:{port}", f"--num-cpus={cpus_per_node}",
                                f"--resources={resources}", *common], check=True, capture_output=True, env=env,
                               timeout=120)
            yield f"127.0.0.1:{port}"
        finally:
            kill_mentioning(temp)
            shutil.rmtree(temp, ignore_errors=True)


@dataclass
class ServedApp:
    """``python -m app serve`` running as a child process."""

    base: str
    """http://127.0.0.1:<port>"""
    proc: subprocess.Popen
    log: Path | None

    def log_tail(self, chars: int = 3000) -> str:
        return self.log.read_text(errors="replace")[-chars:] if self.log is not None and self.log.exists() else ""

    def wait_ready(self, timeout: float = 180.0) -> None:
        """Until ``/readyz`` answers 200; RuntimeError (with the log's tail) when the server exits or is late."""
        import httpx

        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"the server exited with code {self.proc.returncode}; log: {self.log_tail()}")
            try:
                if httpx.get(f"{self.base}/readyz", timeout=2.0).status_code == 200:
                    return
            except httpx.HTTPError:
                pass
            time.sleep(0.25)
        raise RuntimeError(f"the server was not ready after {timeout:.0f} s; log: {self.log_tail()}")


@contextlib.contextmanager
def serve_app(env: dict[str, str | None], log: Path | None = None, args: tuple[str, ...] = (), wait: bool = True,
              ready_timeout: float = 180.0, python: str = sys.executable, cwd: Path = ROOT) -> Iterator[ServedApp]:
    """Run the service (``python -m app serve`` in ``cwd``: default this checkout's, another environment's
    ``python`` in a folder outside it runs that environment's install) on a free port with ``env`` over this
    environment (None removes a variable; model fetching and Ray usage stats off), its output to ``log`` (else
    discarded); wait for ``/readyz`` unless ``wait`` is False. On leaving the block, or when this process dies (see the module docstring), the
    server and everything it started (its own process group: Ray's processes, workers) are stopped:
    SIGTERM, then SIGKILL to the group after 30 s (20 s when the watchdog does it)."""
    port = free_port()
    merged = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0", "SWEEPCAST_FETCH_MODELS": "false", **env}
    env = {k: v for k, v in merged.items() if v is not None}
    out = open(log, "wb") if log is not None else subprocess.DEVNULL
    try:
        proc = subprocess.Popen(dying_with_parent([python, "-m", "app", "serve", "--port", str(port), *args]),
                                cwd=cwd, env=env, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                start_new_session=True)
        dog = start_watchdog(group=proc.pid)
        try:
            app = ServedApp(f"http://127.0.0.1:{port}", proc, log)
            if wait:
                app.wait_ready(ready_timeout)
            yield app
        finally:
            try:
                stop_group(proc.pid, 30.0, proc)
            finally:  # only once the server is down: until then it still guards against our SIGKILL
                dog.terminate()
                dog.wait()
    finally:
        if log is not None:
            out.close()


class FaultyProxy:
    """A TCP proxy on loopback in front of a server (an object store, a database), whose answer a test or a
    benchmark switches at run time to inject a fault:

    - ``"pass"``: forwards both ways (the server as it is);
    - ``"refuse"``: closes every connection at once and cuts the open ones (the server unreachable);
    - ``"hang"``: accepts connections and never answers (a frozen server: clients time out);
    - ``"slowdown"``: answers every HTTP request ``503 SlowDown`` with S3's XML error body (an overloaded store).

    Use as a context manager; ``address`` is ``127.0.0.1:PORT``."""

    MODES = ("pass", "refuse", "hang", "slowdown")

    def __init__(self, upstream: str) -> None:
        import asyncio

        host, port = upstream.rsplit(":", 1)
        self.upstream = (host, int(port))
        self.mode = "pass"
        self.port = free_port()
        self.address = f"127.0.0.1:{self.port}"
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="faulty-proxy", daemon=True)
        self._open: set = set()

    def set(self, mode: str) -> None:
        if mode not in self.MODES:
            raise ValueError(f"unknown mode {mode!r}")
        self.mode = mode
        if mode != "pass":  # open connections see the fault too, not only new ones
            self._loop.call_soon_threadsafe(self._cut_open)

    def _cut_open(self) -> None:
        for writer in list(self._open):
            writer.transport.abort() if self.mode == "refuse" else writer.transport.pause_reading()

    def __enter__(self) -> "FaultyProxy":
        import asyncio

        self._thread.start()
        started = asyncio.run_coroutine_threadsafe(
            asyncio.start_server(self._client, "127.0.0.1", self.port), self._loop)
        self._server = started.result(10)
        return self

    def __exit__(self, *exc: object) -> None:
        import asyncio

        async def close() -> None:
            self._server.close()
            for writer in list(self._open):
                writer.transport.abort()
            tasks = [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)

        asyncio.run_coroutine_threadsafe(close(), self._loop).result(10)
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(10)

    async def _client(self, reader, writer) -> None:
        import asyncio

        mode = self.mode
        if mode == "refuse":
            writer.transport.abort()
            return
        if mode == "hang":
            self._open.add(writer)
            try:
                await reader.read()  # until the client gives up
            finally:
                self._open.discard(writer)
                writer.transport.abort()
            return
        if mode == "slowdown":
            await self._slow_down(reader, writer)
            return
        try:
            up_reader, up_writer = await asyncio.open_connection(*self.upstream)
        except OSError:
            writer.transport.abort()
            return
        self._open.update((writer, up_writer))
        try:
            await asyncio.gather(self._pipe(reader, up_writer), self._pipe(up_reader, writer))
        finally:
            self._open.difference_update((writer, up_writer))
            writer.transport.abort()
            up_writer.transport.abort()

    async def _pipe(self, reader, writer) -> None:
        try:
            while data := await reader.read(65536):
                if self.mode == "hang":  # frozen: hold everything from now on
                    await asyncio_forever()
                writer.write(data)
                await writer.drain()
        except (ConnectionError, OSError):
            pass
        finally:
            writer.transport.abort()

    async def _slow_down(self, reader, writer) -> None:
        body = (b'<?xml version="1.0" encoding="UTF-8"?><Error><Code>SlowDown</Code>'
                b'<Message>Please reduce your request rate.</Message></Error>')
        try:
            while self.mode == "slowdown":  # a kept-alive connection ends with the fault
                head = await reader.readuntil(b"\r\n\r\n")
                length = 0
                for line in head.split(b"\r\n"):
                    if line.lower().startswith(b"content-length:"):
                        length = int(line.split(b":", 1)[1])
                if length:
                    await reader.readexactly(length)
                writer.write(b"HTTP/1.1 503 Slow Down\r\nContent-Type: application/xml\r\nContent-Length: "
                             + str(len(body)).encode() + b"\r\n\r\n" + body)
                await writer.drain()
        except Exception:  # noqa: BLE001 - the client went away or sent something else: done with it
            pass
        finally:
            writer.transport.abort()


async def asyncio_forever() -> None:
    import asyncio

    await asyncio.Event().wait()


@contextlib.contextmanager
def serve_in_thread(settings: object) -> Iterator[str]:
    """The service with ``settings`` in this process (uvicorn in a thread, so a test sees its log records) on a
    free loopback port: its base URL, once ``/readyz`` answers 200 (or after 60 s)."""
    import httpx
    import uvicorn

    from app.http_protocol import http_protocol
    from app.main import create_app

    port = free_port()
    server = uvicorn.Server(uvicorn.Config(create_app(settings), host="127.0.0.1", port=port, log_level="warning",
                                           http=http_protocol(settings.header_timeout_seconds)))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    base = f"http://127.0.0.1:{port}"
    try:
        with httpx.Client(base_url=base, timeout=30) as http:
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline:
                try:
                    if http.get("/readyz").status_code == 200:
                        break
                except httpx.TransportError:
                    pass
                time.sleep(0.1)
        yield base
    finally:
        server.should_exit = True
        thread.join(30)


def stalled_websocket(base: str, path: str) -> socket.socket:
    """A WebSocket opened by hand on a socket with a tiny receive buffer, whose owner will never read again (a
    frozen tab, a hostile client): only the handshake's answer is read, byte by byte, so no frame is taken off it.
    ``base``: http://host:port; ``path``: the socket's path and query."""
    import base64
    from urllib.parse import urlsplit

    url = urlsplit(base)
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.connect((url.hostname, url.port))
    key = base64.b64encode(os.urandom(16)).decode()
    sock.sendall(f"GET {path} HTTP/1.1\r\nHost: {url.netloc}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                 f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n".encode())
    answer = b""
    while not answer.endswith(b"\r\n\r\n"):
        answer += sock.recv(1)
    if not answer.startswith(b"HTTP/1.1 101"):
        sock.close()
        raise RuntimeError(f"no WebSocket: {answer[:200]!r}")
    return sock
