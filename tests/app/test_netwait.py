"""Waiting for a port (a Ray node for its head, the head for its Redis) instead of ray start's 40 s between tries."""
import socket
import subprocess
import sys
import threading
import time

import pytest

from app import netwait
from app.netwait import split_address, wait_for_gcs, wait_for_port
from harness.servers import free_port


def test_addresses_are_host_and_port_with_or_without_a_scheme():
    assert split_address("ray-head:6379") == ("ray-head", 6379)
    assert split_address("redis://redis:6379/") == ("redis", 6379)
    assert split_address("[::1]:80") == ("::1", 80)
    for bad in ("ray-head", ":6379", "host:port"):
        with pytest.raises(ValueError):
            split_address(bad)


def test_the_wait_ends_soon_after_the_port_opens_and_gives_up_at_its_timeout(caplog):
    port = free_port()
    server = socket.socket()
    opened_at: list[float] = []

    def open_late() -> None:
        time.sleep(1.5)
        server.bind(("127.0.0.1", port))
        server.listen()
        opened_at.append(time.monotonic())

    threading.Thread(target=open_late, daemon=True).start()
    with caplog.at_level("INFO", logger="sweepcast.netwait"):
        waited = wait_for_port(f"127.0.0.1:{port}", 30, "the test server")
    try:
        assert waited is not None and waited >= 1.4
        assert time.monotonic() - opened_at[0] < 1.5  # within a try (0.5 s) and a connect of it
        assert [r.getMessage().split(" at ")[0] for r in caplog.records] == ["waiting for the test server",
                                                                             "the test server"]
    finally:
        server.close()
    assert wait_for_port(f"127.0.0.1:{free_port()}", 1.0, "nothing") is None
    assert wait_for_port(f"no-such-host.invalid:{port}", 0.5, "an unknown name") is None


def test_wait_for_says_which_address_is_wrong_and_fails_on_a_closed_port():
    run = lambda *a: subprocess.run([sys.executable, "-m", "app", "wait-for", *a], capture_output=True, text=True,  # noqa: E731
                                    timeout=60)
    bad = run("ray-head")
    assert bad.returncode == 2 and "'ray-head' is not host:port" in bad.stderr
    closed = run(f"127.0.0.1:{free_port()}", "--timeout", "1")
    assert closed.returncode == 1 and "did not answer in 1 s" in closed.stderr
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen()
        assert run(f"127.0.0.1:{server.getsockname()[1]}").returncode == 0


def test_a_redis_is_waited_for_until_it_has_loaded_its_data():
    """A fake Redis that answers PING with -LOADING twice, then +PONG: the wait ends on the third connection."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen()
    replies = [b"-LOADING Redis is loading the dataset in memory\r\n"] * 2 + [b"+PONG\r\n"]
    served: list[bytes] = []

    def serve() -> None:
        for reply in replies:
            conn, _ = server.accept()
            with conn:
                served.append(conn.recv(64))
                conn.sendall(reply)

    threading.Thread(target=serve, daemon=True).start()
    try:
        waited = wait_for_port(f"127.0.0.1:{server.getsockname()[1]}", 30, "the test Redis", redis=True)
    finally:
        server.close()
    assert waited is not None and waited >= 0.9 and served == [b"PING\r\n"] * 3


def test_a_ray_head_is_waited_for_until_its_gcs_answers_not_only_its_port(tmp_path, monkeypatch, caplog):
    """The head's port is open from the start; a stand-in ``ray`` whose health-check hangs once (cut at the check's
    timeout), fails once and then answers: the wait ends on the third check, and says why it waited."""
    calls = tmp_path / "calls"
    fake_ray = tmp_path / "ray"
    fake_ray.write_text(f"""#!/bin/sh
echo "$*" >> {calls}
n=$(wc -l < {calls})
[ "$n" -eq 1 ] && exec sleep 30
[ "$n" -eq 2 ] && exit 1
exit 0
""")
    fake_ray.chmod(0o755)
    monkeypatch.setattr(netwait, "GCS_CHECK_S", 1.0)
    with socket.socket() as head:
        head.bind(("127.0.0.1", 0))
        head.listen()
        address = f"127.0.0.1:{head.getsockname()[1]}"
        with caplog.at_level("INFO", logger="sweepcast.netwait"):
            waited = wait_for_gcs(address, 30, str(fake_ray))
        assert waited is not None and waited >= 1.9  # the hung check (1 s) and two half-second pauses
        assert calls.read_text().splitlines() == [f"health-check --address {address} --skip-version-check"] * 3
        assert "no answer in 1 s" in caplog.text and "answers after" in caplog.text
        assert wait_for_gcs(address, 1.5, "false") is None  # a GCS that never answers: given up at the timeout
    assert wait_for_gcs(f"127.0.0.1:{free_port()}", 0.5, str(fake_ray)) is None  # no port, no check
    assert len(calls.read_text().splitlines()) == 3


def test_wait_for_prints_the_address_it_reached_so_the_next_program_need_not_look_it_up():
    """``sweepcast wait-for --print-reached localhost:PORT``: the IP:PORT its connection reached, on stdout (the image's
    Ray head hands that to its GCS instead of Redis's name)."""
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen()
        port = server.getsockname()[1]
        done = subprocess.run([sys.executable, "-m", "app", "wait-for", "--timeout", "5", "--print-reached",
                               f"localhost:{port}"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == f"127.0.0.1:{port}"
