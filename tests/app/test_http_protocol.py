"""The API's HTTP connections (app.http_protocol): a client that never finishes its headers is answered 408 and
let go; a slow but whole request, or a kept-alive connection, is not."""
from __future__ import annotations

import json
import logging
import socket
import threading
import time

import pytest
import uvicorn

from app.http_protocol import http_protocol
from harness.servers import free_port

TIMEOUT = 0.6


async def echo_length(scope, receive, send):
    """Answers each request with the length of its body."""
    if scope["type"] != "http":
        return
    size = 0
    while True:
        message = await receive()
        size += len(message.get("body", b""))
        if not message.get("more_body"):
            break
    body = str(size).encode()
    await send({"type": "http.response.start", "status": 200,
                "headers": [(b"content-type", b"text/plain"), (b"content-length", str(len(body)).encode())]})
    await send({"type": "http.response.body", "body": body})


@pytest.fixture(scope="module")
def address():
    port = free_port()
    server = uvicorn.Server(uvicorn.Config(echo_length, host="127.0.0.1", port=port, log_level="warning",
                                           lifespan="off", http=http_protocol(TIMEOUT)))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 10
    while not server.started:
        assert time.monotonic() < deadline
        time.sleep(0.02)
    yield ("127.0.0.1", port)
    server.should_exit = True
    thread.join(10)


def connect(address) -> socket.socket:
    return socket.create_connection(address, timeout=5)


def read_response(sock: socket.socket) -> tuple[int, dict[str, str], bytes]:
    """One response: status, headers, body (by its content-length)."""
    data = b""
    while b"\r\n\r\n" not in data:
        chunk = sock.recv(4096)
        assert chunk, f"closed before a response: {data!r}"
        data += chunk
    head, body = data.split(b"\r\n\r\n", 1)
    lines = head.decode().split("\r\n")
    headers = {k.lower(): v.strip() for k, v in (line.split(":", 1) for line in lines[1:])}
    while len(body) < int(headers["content-length"]):
        body += sock.recv(4096)
    return int(lines[0].split()[1]), headers, body


def closed(sock: socket.socket) -> bool:
    sock.settimeout(2)
    try:
        return sock.recv(1) == b""
    except ConnectionResetError:
        return True


@pytest.mark.parametrize("sent", [b"", b"GET / HTTP/1.1\r\nHost: x\r\nX-Slow: "])
def test_headers_that_never_finish_get_408_json_and_the_connection_is_closed(address, sent, caplog):
    caplog.set_level(logging.WARNING, logger="sweepcast.limits")
    with connect(address) as sock:
        t = time.monotonic()
        sock.sendall(sent)
        status, headers, body = read_response(sock)
        waited = time.monotonic() - t
        assert status == 408 and headers["content-type"] == "application/json"
        assert json.loads(body)["error"] == "request_header_timeout"
        assert TIMEOUT * 0.9 <= waited < TIMEOUT + 2.0
        assert closed(sock)
    assert any("no whole request headers within 0.6 s" in r.getMessage() for r in caplog.records)


def test_trickled_headers_are_held_to_the_connection_deadline_not_reset_by_each_byte(address):
    with connect(address) as sock:
        t = time.monotonic()
        for byte in b"GET / HTTP/1.1\r\nHost: x\r\n":  # a byte every 50 ms: the whole line takes 1.3 s
            try:
                sock.sendall(bytes([byte]))
            except OSError:
                break
            time.sleep(0.05)
        status, _, _ = read_response(sock)
        assert status == 408 and time.monotonic() - t < TIMEOUT + 1.5


def test_a_kept_alive_connection_serves_requests_long_after_the_deadline_and_a_slow_body_is_left_to_the_app(address):
    with connect(address) as sock:
        sock.sendall(b"GET / HTTP/1.1\r\nHost: x\r\n\r\n")
        assert read_response(sock)[0] == 200
        time.sleep(TIMEOUT * 2)  # past the first request's deadline, within uvicorn's 5 s keep-alive
        sock.sendall(b"POST / HTTP/1.1\r\nHost: x\r\nContent-Length: 4\r\n\r\nab")
        time.sleep(TIMEOUT * 2)  # the headers are whole: a body's pace is the app's to judge
        sock.sendall(b"cd")
        status, _, body = read_response(sock)
        assert (status, body) == (200, b"4")
        sock.sendall(b"GET / HTTP/1.1\r\nHost: x\r\n")  # a following request that stalls in its headers
        assert read_response(sock)[0] == 408
        assert closed(sock)


def test_an_unparsable_request_gets_400_with_the_json_error_body(address):
    with connect(address) as sock:
        sock.sendall(b"NOT HTTP AT ALL\r\n\r\n")
        status, headers, body = read_response(sock)
        assert status == 400 and headers["content-type"] == "application/json"
        assert json.loads(body)["error"] == "bad_http_request"
        assert closed(sock)
