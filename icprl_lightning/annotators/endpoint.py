"""Labels from a web endpoint (an LLM behind an HTTP API): ``HTTPAnnotator``.

For each pair the annotator fills a prompt template with the pair as text (``describe.py``: DarkRoom's
visited cells and goal, as in the paper's appendix "Use LLMs to label trajectory preference"), POSTs
``{"prompt": "<text>"}`` as JSON to ``url`` and reads the answer: the reply body, or its JSON field
``"answer"``, must be ``1``, ``2``, ``skip`` or ``equal`` (case and surrounding space ignored).

The endpoint is untrusted, so one try is bounded as a whole: ``timeout`` seconds from the connect to the
body's last byte (every read gets only what is left of that deadline, so a server dripping a byte at a time
fails like a silent one), and at most ``max_reply_bytes`` of body. The failures that are retried (with
``backoff · 2^k`` seconds before retry k) are listed in docs/reliability.md; another 4xx status, or a body that
is not an answer, fails at once: asking again would not change it. A redirect is followed only with
``follow_redirects=True``, by POSTing the prompt again: a redirect turned into a GET (what browsers do for
301/302/303) would drop it. Host name resolution is not bounded (the system resolver takes no timeout).

Template fields: trajectories ``{goal}``, ``{horizon}``, ``{trajectory_1}``, ``{trajectory_2}``,
``{grid}``; steps ``{goal}``, ``{position}``, ``{action_1}``, ``{action_2}``.
"""

from __future__ import annotations

import http.client
import io
import json
import socket
import ssl
import string
import time
from typing import Any
from urllib.parse import urljoin, urlsplit

import numpy as np

from icprl_lightning.annotators.base import Annotator, StepQueries, TrajectoryQueries
from icprl_lightning.annotators.describe import action_text, cell, goal_text, grid_text, path_text
from icprl_lightning.annotators.labels import EQUAL, FIRST, SECOND, SKIP, AnnotatorError
from icprl_lightning.validation import HyperparameterError, check_int, check_nonnegative, check_positive

TRAJECTORY_TEMPLATE = (
    "Two agents moved on a {grid_size}x{grid_size} grid for {horizon} steps. Each earns a reward of 1 for "
    "every step that ends on the goal cell {goal}. Cells are (x, y).\n"
    "Trajectory 1 visited: {trajectory_1}\n"
    "Trajectory 2 visited: {trajectory_2}\n"
    "Which trajectory reaches the goal sooner and stays on it longer (the higher total reward)? "
    'Answer with one word: "1", "2", "equal" or "skip".')
STEP_TEMPLATE = (
    "An agent is at cell {position} of a {grid_size}x{grid_size} grid; the goal is the cell {goal}. Cells are "
    "(x, y); up is y + 1, right is x + 1.\n"
    "Action 1: {action_1}\nAction 2: {action_2}\n"
    'Which action brings the agent closer to the goal? Answer with one word: "1", "2", "equal" or "skip".')
TRAJECTORY_FIELDS = {"goal", "horizon", "trajectory_1", "trajectory_2", "grid", "grid_size"}
STEP_FIELDS = {"goal", "position", "action_1", "action_2", "grid_size"}
ANSWERS = {"1": FIRST, "2": SECOND, "equal": EQUAL, "skip": SKIP}
REDIRECTS = {301, 302, 303, 307, 308}
MAX_REDIRECTS = 5  # hops followed within one try (and its one deadline)
RETRYABLE_CLIENT_ERRORS = {408, 429}  # Request Timeout, Too Many Requests: the same request may pass later
CHUNK = 8192


def _check_template(owner: str, key: str, template: str, fields: set[str]) -> str:
    if not isinstance(template, str):
        raise HyperparameterError(f"{owner}: {key} must be a string, got {type(template).__name__}")
    try:
        used = {name for _, name, _, _ in string.Formatter().parse(template) if name is not None}
    except ValueError as e:
        raise HyperparameterError(f"{owner}: {key} is not a valid format string: {e}") from e
    unknown = sorted(used - fields)
    if unknown:
        raise HyperparameterError(f"{owner}: {key} uses unknown field(s) {unknown}; known: {sorted(fields)}")
    return template


def _is_http_url(url: Any) -> bool:
    """``url`` is http(s) with a host and, if any, a valid port (what ``_post`` can connect to)."""
    try:
        parts = urlsplit(url)
        return parts.scheme in ("http", "https") and bool(parts.hostname) and parts.port != 0
    except (TypeError, ValueError, AttributeError):  # not a string; a port that is not a number
        return False


def _check_url(owner: str, url: Any) -> str:
    if not isinstance(url, str) or not _is_http_url(url):
        raise HyperparameterError(f"{owner}: url must be http:// or https:// with a host (and a valid port), "
                                  f"got {url!r}")
    return url


def parse_answer(text: str, url: str) -> int:
    """The label code of a reply: plain ``1``/``2``/``skip``/``equal`` or JSON ``{"answer": ...}``."""
    text = text.strip()
    try:
        payload = json.loads(text)
    except (ValueError, RecursionError):  # RecursionError: JSON nested deeper than the parser's stack
        payload = text
    if isinstance(payload, dict):
        if "answer" not in payload:
            raise AnnotatorError(f"HTTPAnnotator: {url}: the reply is JSON without an 'answer' field: {text[:200]!r}")
        payload = payload["answer"]
    answer = str(payload).strip().strip("\"'.").lower() if isinstance(payload, (str, int)) else None
    if answer not in ANSWERS:
        raise AnnotatorError(f"HTTPAnnotator: {url}: the answer must be 1, 2, skip or equal (plain or as JSON "
                             f"{{\"answer\": ...}}), got {text[:200]!r}")
    return ANSWERS[answer]


def _remaining(deadline: float) -> float:
    """Seconds left before ``deadline`` (``time.monotonic``); a ``TimeoutError`` when none are."""
    remaining = deadline - time.monotonic()
    if remaining <= 0:
        raise TimeoutError("deadline passed")
    return remaining


class TryFailed(Exception):
    """One try went wrong in a way another try may not (the retry loop catches it); the text says how."""


class _DeadlineReader(io.RawIOBase):
    """Reads a socket, each read waiting only for what is left of the try's deadline."""

    def __init__(self, sock: socket.socket, deadline: float) -> None:
        # the socket's own unbuffered file: while it is open, closing the socket (http.client closes the
        # connection once the headers say it will close) waits for the body to be read
        self.sock, self.file, self.deadline = sock, sock.makefile("rb", buffering=0), deadline

    def readable(self) -> bool:
        return True

    def readinto(self, buffer: Any) -> int:
        self.sock.settimeout(_remaining(self.deadline))
        return self.file.readinto(buffer)

    def close(self) -> None:
        self.file.close()
        super().close()


class _DeadlineSocket:
    """The connected socket as ``http.client`` uses it (``sendall``, ``makefile``, ``close``), every send and
    read bounded by one deadline: a socket timeout alone bounds each read, so a drip of bytes never ends."""

    def __init__(self, sock: socket.socket, deadline: float) -> None:
        self.sock, self.deadline = sock, deadline

    def sendall(self, data: bytes) -> None:
        self.sock.settimeout(_remaining(self.deadline))
        self.sock.sendall(data)

    def makefile(self, mode: str = "rb", *args: Any, **kwargs: Any) -> io.BufferedReader:
        return io.BufferedReader(_DeadlineReader(self.sock, self.deadline))

    def close(self) -> None:
        self.sock.close()


class HTTPAnnotator(Annotator):
    """One POST per pair to ``url``; see the module docstring.

    Args:
        url: the endpoint (``http://`` or ``https://``).
        template: the prompt of a trajectory pair (a ``str.format`` template; default: DarkRoom's).
        step_template: the prompt of a step pair.
        timeout: seconds one try may take, from the connect to the reply's last byte.
        retries: further tries after a failed one (module docstring: which failures).
        backoff: seconds before the first retry, doubled on each next one.
        grid_size: the DarkRoom grid's side, for the prompt.
        follow_redirects: POST the prompt again to a redirect's ``Location`` (at most 5 hops); when False a
            redirect is a failed try.
        max_reply_bytes: the largest reply body read; a longer one is a failed try.
    """

    def __init__(self, url: str, template: str = TRAJECTORY_TEMPLATE, step_template: str = STEP_TEMPLATE,
                 timeout: float = 30.0, retries: int = 3, backoff: float = 1.0, grid_size: int = 10,
                 follow_redirects: bool = False, max_reply_bytes: int = 65536) -> None:
        owner = type(self).__name__
        self.url = _check_url(owner, url)
        self.template = _check_template(owner, "template", template, TRAJECTORY_FIELDS)
        self.step_template = _check_template(owner, "step_template", step_template, STEP_FIELDS)
        self.timeout = check_positive(owner, "timeout", timeout)
        self.retries = check_int(owner, "retries", retries, 0)
        self.backoff = check_nonnegative(owner, "backoff", backoff)
        self.grid_size = check_int(owner, "grid_size", grid_size, 1)
        if not isinstance(follow_redirects, bool):
            raise HyperparameterError(f"{owner}: follow_redirects must be true or false, got {follow_redirects!r}")
        self.follow_redirects = follow_redirects
        self.max_reply_bytes = check_int(owner, "max_reply_bytes", max_reply_bytes, 1)

    def label_steps(self, queries: StepQueries, rng: np.random.Generator) -> np.ndarray:
        tasks = queries.tasks
        return np.array([self.ask(self.step_template.format(
            goal=goal_text(None if tasks is None else tasks[i]), position=cell(queries.states[i]),
            action_1=action_text(queries.actions[i]), action_2=action_text(queries.alt_actions[i]),
            grid_size=self.grid_size)) for i in range(len(queries.states))], dtype=np.uint8)

    def label_trajectories(self, queries: TrajectoryQueries, rng: np.random.Generator) -> np.ndarray:
        tasks = queries.tasks
        out = []
        for i in range(len(queries.states_a)):
            task = None if tasks is None else tasks[i]
            out.append(self.ask(self.template.format(
                goal=goal_text(task), horizon=queries.states_a.shape[1], grid_size=self.grid_size,
                trajectory_1=path_text(queries.states_a[i]), trajectory_2=path_text(queries.states_b[i]),
                grid=grid_text(queries.states_a[i], queries.states_b[i], task, self.grid_size))))
        return np.array(out, dtype=np.uint8)

    def ask(self, prompt: str) -> int:
        """POST one prompt and parse its answer, retrying failed tries (module docstring)."""
        data = json.dumps({"prompt": prompt}).encode()
        tries, reason = self.retries + 1, ""
        for attempt in range(tries):
            if attempt:
                time.sleep(self.backoff * 2 ** (attempt - 1))
            try:
                body = self._try(data)
                text = body.decode("utf-8")
            except TryFailed as e:
                reason = str(e)
            except UnicodeDecodeError as e:
                reason = f"the reply body is not UTF-8 text (byte {e.start}: {body[e.start:e.start + 1]!r})"
            else:
                return parse_answer(text, self.url)
        raise AnnotatorError(f"HTTPAnnotator: {self.url}: {reason} ({tries} {'try' if tries == 1 else 'tries'})")

    def _try(self, data: bytes) -> bytes:
        """One try under one deadline: POST, follow redirects if asked, return the 2xx body or raise."""
        deadline, url = time.monotonic() + self.timeout, self.url
        for _ in range(MAX_REDIRECTS + 1):
            status, reason, location, body = self._post(url, data, deadline)
            if status not in REDIRECTS:
                return body
            if not self.follow_redirects:
                raise TryFailed(f"redirected (HTTP {status}) to {location!r}, which would not receive the prompt "
                                "(follow_redirects=True POSTs it there)")
            target = urljoin(url, location or "")
            if not location or not _is_http_url(target):
                raise TryFailed(f"HTTP {status} {reason} with no http(s) Location to follow (got {location!r})")
            url = target
        raise TryFailed(f"more than {MAX_REDIRECTS} redirects (last to {url})")

    def _post(self, url: str, data: bytes, deadline: float) -> tuple[int, str, str | None, bytes]:
        """POST ``data`` to ``url``: (status, reason, Location, body); only a 2xx reply's body is read."""
        parts = urlsplit(url)
        host = f"[{parts.hostname}]" if ":" in parts.hostname else parts.hostname  # an IPv6 literal
        kind = http.client.HTTPSConnection if parts.scheme == "https" else http.client.HTTPConnection
        phase, response = "connecting", None
        try:
            connection = kind(host, parts.port, timeout=_remaining(deadline))
            try:
                connection.connect()
                connection.sock = _DeadlineSocket(connection.sock, deadline)
                phase = "sending the prompt"
                connection.request("POST", (parts.path or "/") + (f"?{parts.query}" if parts.query else ""),
                                   body=data, headers={"Content-Type": "application/json"})
                phase = "waiting for the status line and headers"
                response = connection.getresponse()
                status, location = response.status, response.getheader("Location")
                if 200 <= status < 300:
                    return status, response.reason, location, self._read_body(response)
                if 400 <= status < 500 and status not in RETRYABLE_CLIENT_ERRORS:
                    raise AnnotatorError(f"HTTPAnnotator: {url}: answered HTTP {status} {response.reason}")
                if status not in REDIRECTS:
                    raise TryFailed(f"answered HTTP {status} {response.reason}")
                return status, response.reason, location, b""
            finally:
                if response is not None:
                    response.close()
                connection.close()
        except (TryFailed, AnnotatorError):
            raise
        except TimeoutError:  # socket timeouts are TimeoutError too
            raise TryFailed(f"no complete reply within the {self.timeout:g} s deadline ({phase})") from None
        except http.client.RemoteDisconnected:
            raise TryFailed(f"the server closed the connection without a reply ({phase})") from None
        except http.client.BadStatusLine as e:
            raise TryFailed(f"not an HTTP reply (it began {str(e)[:80]!r})") from None
        except http.client.HTTPException as e:  # header lines too long or too many, unknown protocol
            raise TryFailed(f"malformed HTTP reply ({type(e).__name__}: {str(e)[:120]})") from None
        except ConnectionRefusedError:
            raise TryFailed("connection refused") from None
        except (ConnectionResetError, ConnectionAbortedError, BrokenPipeError):
            raise TryFailed(f"connection reset by the server ({phase})") from None
        except ssl.SSLError as e:
            raise TryFailed(f"TLS error: {e}") from None
        except OSError as e:  # unknown host, unreachable network, ...
            raise TryFailed(f"connection failed ({phase}): {e}") from None

    def _read_body(self, response: http.client.HTTPResponse) -> bytes:
        """The whole body, at most ``max_reply_bytes``, checked against its Content-Length."""
        expected, limit = response.length, self.max_reply_bytes  # length: None when chunked or close-delimited
        if expected is not None and expected > limit:
            raise TryFailed(f"reply body of {expected} bytes (Content-Length) exceeds max_reply_bytes = {limit}")
        body = bytearray()
        of = "" if expected is None else f" of {expected}"
        try:
            while chunk := response.read1(CHUNK):
                body += chunk
                if len(body) > limit:
                    raise TryFailed(f"reply body exceeds max_reply_bytes = {limit}")
        except TimeoutError:
            raise TryFailed(f"no complete reply within the {self.timeout:g} s deadline (reading the body: "
                            f"{len(body)}{of} bytes received)") from None
        except http.client.IncompleteRead:
            raise TryFailed(f"chunked reply cut short or malformed after {len(body)} bytes") from None
        except (ConnectionResetError, ConnectionAbortedError):
            raise TryFailed(f"connection reset after {len(body)}{of} bytes of the body") from None
        if expected is not None and len(body) < expected:
            raise TryFailed(f"reply truncated after {len(body)}{of} bytes")
        return bytes(body)

    def init_args(self) -> dict[str, Any]:
        return {"url": self.url, "template": self.template, "step_template": self.step_template,
                "timeout": self.timeout, "retries": self.retries, "backoff": self.backoff,
                "grid_size": self.grid_size, "follow_redirects": self.follow_redirects,
                "max_reply_bytes": self.max_reply_bytes}
