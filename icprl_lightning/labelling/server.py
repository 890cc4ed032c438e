"""The labelling page's HTTP server: a Starlette app over one session (``make_app``), served by uvicorn.

Routes (each needs ``?token=``; anything else is a 404): ``GET /`` the page (CSS and JS inlined from
``assets/``, no CDN), ``GET /api/pair``, ``POST /api/answer``, ``POST /api/undo``. Safe by default
(docs/labelling.md): it binds 127.0.0.1; a wrong token is a 403 (compared in constant time); a ``Host`` other
than the loopback names a 400 (DNS rebinding); a body over ``MAX_BODY`` a 413, one not of exactly the expected
keys, types and patterns a 400; an answer to a pair the annotator is not shown, or a replayed nonce, a 409.
No route takes a path, so no parameter can name a file outside the session. A refused request writes nothing.
"""

from __future__ import annotations

import hmac
import json
import re
from importlib.resources import files
from typing import Any

from starlette.applications import Starlette
from starlette.middleware import Middleware
from starlette.middleware.trustedhost import TrustedHostMiddleware
from starlette.requests import Request
from starlette.responses import HTMLResponse, JSONResponse
from starlette.routing import Route

from icprl_lightning.labelling.answer_log import Refused
from icprl_lightning.labelling.session import Session

MAX_BODY = 4096
NAME = re.compile(r"[A-Za-z0-9_-]{1,40}")
NONCE = re.compile(r"[A-Za-z0-9_-]{8,64}")
PAIR = re.compile(r"[a-z_]{1,40}-[0-9]{5}")
ANSWER_KEYS = {"annotator": str, "pair": str, "label": str, "nonce": str, "response_ms": int}
UNDO_KEYS = {"annotator": str, "nonce": str}
LOOPBACK = ["127.0.0.1", "localhost", "[::1]"]


def page() -> str:
    """The page with its stylesheet and script inlined (the package's ``assets/``)."""
    assets = files("icprl_lightning.labelling") / "assets"
    html = (assets / "index.html").read_text()
    return (html.replace("/*STYLE*/", (assets / "style.css").read_text())
            .replace("/*SCRIPT*/", (assets / "draw.js").read_text() + (assets / "app.js").read_text()))


def _field(value: Any, name: str, pattern: re.Pattern) -> str:
    if not isinstance(value, str) or not pattern.fullmatch(value):
        raise Refused(f"{name} must match {pattern.pattern}, got {str(value)[:60]!r}")
    return value


async def _body(request: Request, keys: dict[str, type]) -> dict[str, Any]:
    """The request's JSON object, checked: size, syntax, exactly ``keys`` with their types."""
    declared = request.headers.get("content-length")
    if declared is not None and not declared.isdigit():
        raise Refused(f"Content-Length must be a number of bytes, got {declared[:20]!r}")
    if declared is not None and int(declared) > MAX_BODY:
        raise Refused(f"a request body holds at most {MAX_BODY} bytes", 413)
    raw = b""
    async for chunk in request.stream():
        raw += chunk
        if len(raw) > MAX_BODY:
            raise Refused(f"a request body holds at most {MAX_BODY} bytes", 413)
    try:
        body = json.loads(raw)
    except (json.JSONDecodeError, UnicodeDecodeError):
        raise Refused("the body is not JSON") from None
    if not isinstance(body, dict) or set(body) != set(keys):
        raise Refused(f"the body must be a JSON object with keys {sorted(keys)}")
    for key, kind in keys.items():
        if type(body[key]) is not kind:
            raise Refused(f"{key} must be a JSON {kind.__name__}, got {type(body[key]).__name__}")
    return body


def make_app(session: Session, token: str, allowed_hosts: list[str] | None = None) -> Starlette:
    """The app serving ``session`` to requests that carry ``token``."""

    def authorized(request: Request) -> bool:
        return hmac.compare_digest(request.query_params.get("token", "").encode(), token.encode())

    def pair_payload(annotator: str) -> dict[str, Any]:
        pair = session.log.current(annotator)
        # an open-ended session (an online agent's questions) is waiting, not done, when all are answered
        shown = ({"done": True, "waiting": getattr(session, "open_ended", False)} if pair is None
                 else session.show(pair))
        return {**shown, "progress": list(session.log.progress(annotator))}

    async def guarded(request: Request, handle: Any) -> Any:
        if not authorized(request):
            return JSONResponse({"error": "a valid ?token= is required"}, status_code=403)
        try:
            return await handle(request)
        except Refused as e:
            return JSONResponse({"error": str(e)}, status_code=e.status)

    async def index(request: Request) -> Any:
        async def handle(_: Request) -> HTMLResponse:
            return HTMLResponse(page(), headers={"Content-Security-Policy": "default-src 'self' 'unsafe-inline'",
                                                 "Referrer-Policy": "no-referrer"})
        return await guarded(request, handle)

    async def get_pair(request: Request) -> Any:
        async def handle(r: Request) -> JSONResponse:
            return JSONResponse(pair_payload(_field(r.query_params.get("annotator"), "annotator", NAME)))
        return await guarded(request, handle)

    async def post_answer(request: Request) -> Any:
        async def handle(r: Request) -> JSONResponse:
            body = await _body(r, ANSWER_KEYS)
            annotator = _field(body["annotator"], "annotator", NAME)
            if not 0 <= body["response_ms"] <= 86_400_000:
                raise Refused(f"response_ms must be in [0, 86400000], got {body['response_ms']}")
            session.log.answer(annotator, _field(body["pair"], "pair", PAIR), body["label"],
                               _field(body["nonce"], "nonce", NONCE), body["response_ms"])
            return JSONResponse(pair_payload(annotator))
        return await guarded(request, handle)

    async def post_undo(request: Request) -> Any:
        async def handle(r: Request) -> JSONResponse:
            body = await _body(r, UNDO_KEYS)
            annotator = _field(body["annotator"], "annotator", NAME)
            session.log.undo(annotator, _field(body["nonce"], "nonce", NONCE))
            return JSONResponse(pair_payload(annotator))
        return await guarded(request, handle)

    routes = [Route("/", index), Route("/api/pair", get_pair), Route("/api/answer", post_answer, methods=["POST"]),
              Route("/api/undo", post_undo, methods=["POST"])]
    return Starlette(routes=routes, middleware=[Middleware(TrustedHostMiddleware,
                                                           allowed_hosts=allowed_hosts or LOOPBACK)])
