"""HTTPAnnotator against a loopback server that misbehaves in every way we could think of.

The server (127.0.0.1 only) reads each POST, then answers by the request's path with raw bytes: slow
drips, stalls, truncated and reset bodies, replies that are not HTTP, redirects, errors then success,
bodies too large or not answers. Each case ends in the right label or in ONE one-line ``AnnotatorError``
naming the URL, after the expected number of tries, and no try outlives its deadline. Every server-side
wait is bounded (``HANDLER_TIMEOUT``), its threads are daemons, and a watchdog stops it if a test hangs.
"""

from __future__ import annotations

import json
import re
import socket
import socketserver
import struct
import threading
import time
from collections.abc import Callable

import numpy as np
import pytest
from factories import darkroom_data

from icprl_lightning.annotators import EQUAL, FIRST, SECOND, SKIP, AnnotatorError, HTTPAnnotator, StepQueries

DEADLINE = 0.5  # the annotator's timeout in these tests
RETRIES = 2  # so a retried failure is asked 3 times
MAX_BYTES = 4096
HANDLER_TIMEOUT = 3.0  # no handler waits longer on its client
PROMPT_FIELD = "prompt"


def reply(status: str = "200 OK", body: bytes = b"", headers: dict[str, object] | None = None) -> bytes:
    """A raw HTTP/1.1 reply; Content-Length is the body's unless ``headers`` say otherwise."""
    headers = {"Content-Length": len(body), **(headers or {})}
    head = "".join(f"{k}: {v}\r\n" for k, v in headers.items() if v is not None)
    return f"HTTP/1.1 {status}\r\n{head}\r\n".encode() + body


def chunked(*parts: bytes, end: bool = True) -> bytes:
    body = b"".join(b"%x\r\n%s\r\n" % (len(p), p) for p in parts) + (b"0\r\n\r\n" if end else b"")
    return reply(headers={"Content-Length": None, "Transfer-Encoding": "chunked"}) + body


def drip(sock: socket.socket, data: bytes, every: float = 0.05) -> None:
    """One byte per ``every`` seconds: each read finishes far inside the deadline, the whole reply does not."""
    for i in range(len(data)):
        sock.sendall(data[i:i + 1])
        time.sleep(every)


def wait_for_close(sock: socket.socket) -> None:
    """Send nothing; return when the client hangs up (or after HANDLER_TIMEOUT)."""
    while sock.recv(4096):
        pass


def reset(sock: socket.socket) -> None:
    """Close with a TCP RST (SO_LINGER on, 0 s) instead of an orderly FIN."""
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    sock.close()


def send(data: bytes) -> Callable[[socket.socket, int], None]:
    return lambda sock, n: sock.sendall(data)


def redirect(code: int, location: str) -> Callable[[socket.socket, int], None]:
    return send(reply(f"{code} Moved", headers={"Location": location}))


def first_fails(failure: Callable[[socket.socket, int], None]) -> Callable[[socket.socket, int], None]:
    """``failure`` on the first request of a path, a good answer ("1") after it."""
    def behave(sock: socket.socket, n: int) -> None:
        return failure(sock, n) if n == 1 else sock.sendall(reply(body=b"1"))
    return behave


def stuffed(sock: socket.socket, n: int) -> None:
    """An endless-looking chunked body (80 KB, bounded) for a client that stops at MAX_BYTES."""
    sock.sendall(reply(headers={"Content-Length": None, "Transfer-Encoding": "chunked"}))
    for _ in range(20):
        sock.sendall(b"1000\r\n" + b"x" * 4096 + b"\r\n")


# path -> what the server does after reading the request (socket, how many times this path was asked)
BEHAVIORS: dict[str, Callable[[socket.socket, int], None]] = {
    "plain": send(reply(body=b"2")),
    "json_chunked": send(chunked(b'{"answer": ', b'" Equal "}')),
    "close_delimited": send(b"HTTP/1.0 200 OK\r\n\r\nskip"),
    "continue_then_ok": send(b"HTTP/1.1 100 Continue\r\n\r\n" + reply(body=b"1")),
    "extra_bytes_after_body": send(reply(body=b"1garbage", headers={"Content-Length": 1})),
    "slow_within_deadline": lambda sock, n: (time.sleep(0.1), drip(sock, reply(body=b"2"), every=0.003)),
    "flaky_500": first_fails(send(reply("500 Internal Server Error"))),
    "flaky_reset": first_fails(lambda sock, n: reset(sock)),
    "flaky_truncated": first_fails(send(reply(body=b"1", headers={"Content-Length": 5}))),
    "target": send(reply(body=b"1")),
    **{f"redirect_{code}": redirect(code, "/target") for code in (301, 302, 303, 307, 308)},
    "redirect_absolute": lambda sock, n: sock.sendall(reply("302 Found", headers={
        "Location": f"http://127.0.0.1:{sock.getsockname()[1]}/target"})),
    "redirect_loop": redirect(302, "/redirect_loop"),
    "redirect_ftp": redirect(302, "ftp://127.0.0.1/target"),
    "redirect_nowhere": send(reply("302 Found")),
    "redirect_bad_port": redirect(307, "http://127.0.0.1:port/target"),
    "slow_drip": lambda sock, n: (sock.sendall(reply(headers={"Content-Length": 40})), drip(sock, b"2" * 40)),
    "drip_headers": lambda sock, n: drip(sock, reply(body=b"1", headers={"X-Pad": "p" * 40})),
    "stall_after_headers": lambda sock, n: (sock.sendall(reply(headers={"Content-Length": 10})),
                                            wait_for_close(sock)),
    "stall": lambda sock, n: wait_for_close(sock),
    "truncated": send(reply(body=b"abc", headers={"Content-Length": 10})),
    "no_reply": lambda sock, n: None,
    "garbage": send(b"\x00\x01garbage\xff\r\n\r\n"),
    "http09": send(b"1"),
    "reset_mid_body": lambda sock, n: (sock.sendall(reply(body=b"abc", headers={"Content-Length": 10})),
                                       time.sleep(0.05), reset(sock)),
    "chunked_cut": send(chunked(b"12345", end=False)[:-5]),  # chunk "5" announced, "12" sent, then closed
    "chunked_bad_size": send(reply(headers={"Content-Length": None, "Transfer-Encoding": "chunked"}) + b"zz\r\n"),
    "huge_declared": send(reply(headers={"Content-Length": 10**12})),
    "huge_chunked": stuffed,
    "huge_close_delimited": send(b"HTTP/1.0 200 OK\r\n\r\n" + b"1" * 20000),
    "header_flood": send(reply(body=b"1", headers={f"X-H{i}": i for i in range(150)})),
    "long_status_line": send(b"HTTP/1.1 200 " + b"x" * 70000 + b"\r\n\r\n"),
    "status_500": send(reply("500 Internal Server Error")),
    "status_503": send(reply("503 Service Unavailable", b"busy")),
    "status_429": send(reply("429 Too Many Requests")),
    "status_304": send(reply("304 Not Modified")),
    "status_404": send(reply("404 Not Found", b"no such page")),
    "status_401": send(reply("401 Unauthorized")),
    "wrong_content": send(reply(body=b"<html><body>It depends.</body></html>",
                                headers={"Content-Type": "text/html"})),
    "json_without_answer": send(reply(body=b'{"label": 1}')),
    "deep_json": send(reply(body=b"[" * 3000)),
    "empty_body": send(reply(body=b"")),
    "not_utf8": send(reply(body=b"\xff\xfe1")),
}


class Handler(socketserver.BaseRequestHandler):
    def handle(self) -> None:
        sock = self.request
        sock.settimeout(HANDLER_TIMEOUT)
        try:
            data = b""
            while b"\r\n\r\n" not in data:
                more = sock.recv(65536)
                if not more:
                    return
                data += more
            head, body = data.split(b"\r\n\r\n", 1)
            lines = head.decode("latin-1").split("\r\n")
            length = next(int(v) for k, _, v in (h.partition(":") for h in lines[1:]) if k.lower() == "content-length")
            while len(body) < length:
                body += sock.recv(65536)
            path = lines[0].split()[1].lstrip("/")
            with self.server.lock:
                self.server.log.append((path, json.loads(body)[PROMPT_FIELD]))
                n = sum(p == path for p, _ in self.server.log)
            BEHAVIORS[path](sock, n)
        except OSError:
            pass  # the client gave up first (its deadline), or the case itself reset the connection


class Server(socketserver.ThreadingTCPServer):
    daemon_threads = True
    allow_reuse_address = True


@pytest.fixture(scope="module")
def server():
    srv = Server(("127.0.0.1", 0), Handler)
    srv.log, srv.lock = [], threading.Lock()
    thread = threading.Thread(target=srv.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    thread.start()
    watchdog = threading.Timer(120, srv.shutdown)  # stops the server even if a test hangs
    watchdog.daemon = True
    watchdog.start()
    yield srv, f"http://127.0.0.1:{srv.server_address[1]}"
    watchdog.cancel()
    srv.shutdown()
    srv.server_close()
    thread.join(5)


def asked(srv, path: str, want: int) -> int:
    """How many requests ``path`` received, waiting briefly for handler threads to log ``want``."""
    stop = time.monotonic() + 2
    while True:
        with srv.lock:
            got = sum(p == path for p, _ in srv.log)
        if got >= want or time.monotonic() > stop:
            return got


def annotator(url: str, **kwargs) -> HTTPAnnotator:
    return HTTPAnnotator(url, **{"timeout": DEADLINE, "retries": RETRIES, "backoff": 0.01,
                                 "max_reply_bytes": MAX_BYTES, **kwargs})


def step_pair() -> StepQueries:
    return StepQueries(np.array([[2.0, 5.0]], np.float32), np.array([3]), np.array([4]), np.zeros(1), np.zeros(1),
                       np.array([[7, 5]]))


LABELS = [("plain", SECOND, 1), ("json_chunked", EQUAL, 1), ("close_delimited", SKIP, 1),
          ("continue_then_ok", FIRST, 1), ("extra_bytes_after_body", FIRST, 1), ("slow_within_deadline", SECOND, 1),
          ("flaky_500", FIRST, 2), ("flaky_reset", FIRST, 2), ("flaky_truncated", FIRST, 2)]


@pytest.mark.parametrize(("path", "label", "requests"), LABELS)
def test_answers_and_recoveries_give_the_label(server, path, label, requests):
    srv, url = server
    assert annotator(f"{url}/{path}").label_steps(step_pair(), None).tolist() == [label]
    assert asked(srv, path, requests) == requests


TRIES = RETRIES + 1
DEADLINE_PASSED = "no complete reply within the 0.5 s deadline"
FAILURES = [  # path, what the one error says, requests the server saw
    ("slow_drip", DEADLINE_PASSED + " \\(reading the body: \\d+ of 40 bytes received\\)", TRIES),
    ("drip_headers", DEADLINE_PASSED + " \\(waiting for the status line and headers\\)", TRIES),
    ("stall_after_headers", DEADLINE_PASSED + " \\(reading the body: 0 of 10 bytes received\\)", TRIES),
    ("stall", DEADLINE_PASSED + " \\(waiting for the status line and headers\\)", TRIES),
    ("truncated", "reply truncated after 3 of 10 bytes", TRIES),
    ("no_reply", "the server closed the connection without a reply", TRIES),
    ("garbage", "not an HTTP reply \\(it began '\\\\x00\\\\x01garbage", TRIES),
    ("http09", "not an HTTP reply \\(it began '1'\\)", TRIES),
    ("reset_mid_body", "connection reset", TRIES),
    ("chunked_cut", "chunked reply cut short or malformed after 2 bytes", TRIES),
    ("chunked_bad_size", "chunked reply cut short or malformed after 0 bytes", TRIES),
    ("huge_declared", "reply body of 1000000000000 bytes \\(Content-Length\\) exceeds max_reply_bytes = 4096", TRIES),
    ("huge_chunked", "reply body exceeds max_reply_bytes = 4096", TRIES),
    ("huge_close_delimited", "reply body exceeds max_reply_bytes = 4096", TRIES),
    ("header_flood", "malformed HTTP reply \\(HTTPException: got more than 100 headers\\)", TRIES),
    ("long_status_line", "malformed HTTP reply \\(LineTooLong: got more than 65536 bytes", TRIES),
    ("not_utf8", "the reply body is not UTF-8 text \\(byte 0: b'\\\\xff'\\)", TRIES),
    ("status_500", "answered HTTP 500 Internal Server Error", TRIES),
    ("status_503", "answered HTTP 503 Service Unavailable", TRIES),
    ("status_429", "answered HTTP 429 Too Many Requests", TRIES),
    ("status_304", "answered HTTP 304 Not Modified", TRIES),
    *[(f"redirect_{code}", f"redirected \\(HTTP {code}\\) to '/target', which would not receive the prompt "
       "\\(follow_redirects=True POSTs it there\\)", TRIES) for code in (301, 302, 307)],
    # not retried: asking again would not change these
    ("status_404", "answered HTTP 404 Not Found$", 1),
    ("status_401", "answered HTTP 401 Unauthorized$", 1),
    ("wrong_content", "the answer must be 1, 2, skip or equal .* got '<html><body>It depends", 1),
    ("json_without_answer", "the reply is JSON without an 'answer' field: '{\"label\": 1}'", 1),
    ("deep_json", "the answer must be 1, 2, skip or equal .* got '\\[\\[\\[", 1),
    ("empty_body", "the answer must be 1, 2, skip or equal .* got ''", 1),
]


@pytest.mark.parametrize(("path", "message", "requests"), FAILURES, ids=[f[0] for f in FAILURES])
def test_each_fault_is_one_clear_error_naming_the_url(server, path, message, requests):
    srv, url = server
    start = time.monotonic()
    with pytest.raises(AnnotatorError) as info:
        annotator(f"{url}/{path}").label_steps(step_pair(), None)
    elapsed = time.monotonic() - start
    text = str(info.value)
    assert "\n" not in text and text.startswith(f"HTTPAnnotator: {url}/{path}: "), text
    suffix = f" ({TRIES} tries)" if requests == TRIES else ""
    assert text.endswith(suffix), text
    assert re.search(message, text.removesuffix(suffix)), text
    assert asked(srv, path, requests) == requests
    assert elapsed < requests * DEADLINE + 1.0, elapsed  # each try ends at its deadline (a drip lasts 2 s a try)


@pytest.mark.parametrize("code", [301, 302, 303, 307, 308])
def test_a_followed_redirect_posts_the_prompt_to_the_new_address(server, code):
    srv, url = server
    with srv.lock:
        before = len(srv.log)
    y = annotator(f"{url}/redirect_{code}", follow_redirects=True).label_steps(step_pair(), None)
    assert y.tolist() == [FIRST]
    with srv.lock:
        (first, prompt), (second, again) = srv.log[before:]
    assert (first, second) == (f"redirect_{code}", "target") and again == prompt and "cell (2, 5)" in prompt


def test_an_unfollowed_redirect_never_reaches_its_target(server):
    srv, url = server
    with srv.lock:
        before = len(srv.log)
    with pytest.raises(AnnotatorError, match="redirected \\(HTTP 307\\)"):
        annotator(f"{url}/redirect_307").label_steps(step_pair(), None)
    with srv.lock:
        assert [p for p, _ in srv.log[before:]] == ["redirect_307"] * TRIES


def test_an_absolute_redirect_is_followed_and_bad_ones_are_errors(server):
    srv, url = server
    assert annotator(f"{url}/redirect_absolute", follow_redirects=True).label_steps(step_pair(), None) == [FIRST]
    cases = [("redirect_loop", "more than 5 redirects", TRIES * 6),
             ("redirect_ftp", "HTTP 302 Moved with no http\\(s\\) Location to follow \\(got 'ftp://", TRIES),
             ("redirect_nowhere", "HTTP 302 Found with no http\\(s\\) Location to follow \\(got None\\)", TRIES),
             ("redirect_bad_port", "HTTP 307 Moved with no http\\(s\\) Location .*'http://127.0.0.1:port/", TRIES)]
    for path, message, requests in cases:
        with pytest.raises(AnnotatorError, match=f"^HTTPAnnotator: {url}/{path}: {message}.*\\({TRIES} tries\\)$"):
            annotator(f"{url}/{path}", follow_redirects=True).label_steps(step_pair(), None)
        assert asked(srv, path, requests) == requests


def test_a_refused_connection_is_retried_then_one_error():
    with socket.socket() as probe:  # a port nobody listens on: bind, read it, close
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    url = f"http://127.0.0.1:{port}/label"
    with pytest.raises(AnnotatorError, match=f"^HTTPAnnotator: {url}: connection refused \\(3 tries\\)$"):
        annotator(url).label_steps(step_pair(), None)


def test_one_try_is_never_retried_with_retries_zero(server):
    srv, url = server
    with pytest.raises(AnnotatorError, match="answered HTTP 500 Internal Server Error \\(1 try\\)$"):
        annotator(f"{url}/status_500", retries=0).label_steps(step_pair(), None)


def test_a_failing_endpoint_stops_data_generation_with_its_one_error(server, tmp_path):
    """Data generation calls ``label_steps`` inside ``prepare_data``: the user sees the annotator's error
    (one line, naming the URL), and no dataset is left behind."""
    _, url = server
    dm = darkroom_data(root_dir=str(tmp_path), annotator=annotator(f"{url}/truncated", retries=0),
                       trajectories_per_task=2, val_trajectories_per_task=1, eval_contexts_per_task=1,
                       calibration_episodes=2, n_train_tasks=2, n_test_tasks=1, progress=False)
    with pytest.raises(AnnotatorError, match=f"^HTTPAnnotator: {url}/truncated: reply truncated after 3 of 10 bytes "
                                             "\\(1 try\\)$"):
        dm.prepare_data()
    assert not dm.path.exists()
