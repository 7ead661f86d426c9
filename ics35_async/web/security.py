"""Who may use the configurator: the holder of the token, from this site only (the page moves motors).

* A random token is printed in the URL; the first visit with ``?token=...``
  stores it in an HttpOnly, ``SameSite=Strict`` cookie and redirects to the
  same page without it (so it does not linger in the address bar).
* Every request and WebSocket without the token is refused: 401 when none
  was given, 403 when a wrong one was.
* State-changing requests (anything but GET/HEAD) must be JSON and, when the
  browser names an Origin, come from this server's own origin: a form or a
  script on another site cannot change a servo (no CSRF).  The SameSite
  cookie alone would already keep another site's requests token-less.
* A WebSocket's Origin must be this server's own (browsers do not apply CORS
  to WebSockets; this is the check they leave to the server).
* Bound to loopback, the Host header must name loopback too: a DNS-rebinding
  page that points its own name at 127.0.0.1 is refused.
"""

from __future__ import annotations

import hmac
import json
import os
import secrets
from collections.abc import Awaitable, Callable, MutableMapping
from http.cookies import SimpleCookie
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs, urlencode

from ..errors import InvalidArgument

Scope = MutableMapping[str, Any]
Message = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]
ASGIApp = Callable[[Scope, Receive, Send], Awaitable[None]]

COOKIE = "ics35_token"
TOKEN_ENV = "ICS35_WEB_TOKEN"
MIN_TOKEN_LEN = 16
LOOPBACK_NAMES = frozenset({"127.0.0.1", "localhost", "::1", "[::1]"})
SAFE_METHODS = frozenset({"GET", "HEAD"})


def new_token() -> str:
    return secrets.token_urlsafe(24)


def load_token(token_file: str | None = None) -> str:
    """The token from ``token_file``, else from $ICS35_WEB_TOKEN, else a new random one."""
    if token_file is not None:
        try:
            token = Path(token_file).read_text().strip()
        except OSError as exc:
            raise InvalidArgument(f"cannot read the token file {token_file}: {exc.strerror or exc}") from None
        source = f"the token file {token_file}"
    else:
        token = os.environ.get(TOKEN_ENV, "").strip()
        source = f"${TOKEN_ENV}"
        if not token:
            return new_token()
    if len(token) < MIN_TOKEN_LEN or not token.isascii() or any(c.isspace() or c in ";,\"'&?#" for c in token):
        raise InvalidArgument(
            f"{source} must hold a token of at least {MIN_TOKEN_LEN} printable characters without spaces, "
            "quotes, ; , & ? or #"
        )
    return token


def is_loopback(host: str) -> bool:
    return host in LOOPBACK_NAMES or host.startswith("127.")


def _headers(scope: Scope) -> dict[str, str]:
    return {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope.get("headers", [])}


def _host_name(host_header: str) -> str:
    if host_header.startswith("["):
        return host_header.split("]")[0] + "]"
    return host_header.rsplit(":", 1)[0] if ":" in host_header else host_header


class TokenGuard:
    """ASGI middleware applying the rules above to every HTTP request and WebSocket."""

    def __init__(self, app: ASGIApp, token: str, *, loopback_only_hosts: bool = True) -> None:
        self.app = app
        self.token = token
        self.loopback_only_hosts = loopback_only_hosts

    def _matches(self, given: str | None) -> bool:
        return given is not None and hmac.compare_digest(given.encode(), self.token.encode())

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        kind = scope["type"]
        if kind not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        headers = _headers(scope)
        host = headers.get("host", "")
        if self.loopback_only_hosts and not is_loopback(_host_name(host)):
            await self._refuse(scope, send, 403, f"host {host!r} is not this machine's loopback address")
            return
        query = parse_qs(scope.get("query_string", b"").decode("latin-1"))
        from_query = query.get("token", [None])[0]
        cookie = SimpleCookie(headers.get("cookie", ""))
        from_cookie = cookie[COOKIE].value if COOKIE in cookie else None
        given = from_query if from_query is not None else from_cookie
        if given is None:
            await self._refuse(
                scope, send, 401, "no token: open the URL `ics35 web` printed (it carries the token)", "NoToken"
            )
            return
        if not self._matches(given):
            await self._refuse(scope, send, 403, "wrong token: open the URL `ics35 web` printed", "WrongToken")
            return
        origin = headers.get("origin")
        own = f"{'https' if scope.get('scheme') in ('https', 'wss') else 'http'}://{host}"
        if kind == "websocket":
            if origin != own:
                await self._refuse(scope, send, 403, f"WebSocket from another origin ({origin}) refused")
                return
        elif scope["method"] not in SAFE_METHODS:
            if origin is not None and origin != own:
                await self._refuse(scope, send, 403, f"request from another site ({origin}) refused")
                return
            if not headers.get("content-type", "").startswith("application/json"):
                await self._refuse(scope, send, 415, "changes are sent as JSON by the configurator's own page")
                return
        elif from_query is not None:
            await self._set_cookie_and_redirect(scope, send, query)
            return
        await self.app(scope, receive, send)

    async def _set_cookie_and_redirect(self, scope: Scope, send: Send, query: dict[str, list[str]]) -> None:
        rest = {k: v for k, v in query.items() if k != "token"}
        location = scope.get("path", "/") + (f"?{urlencode(rest, doseq=True)}" if rest else "")
        cookie = f"{COOKIE}={self.token}; Path=/; HttpOnly; SameSite=Strict"
        await send(
            {
                "type": "http.response.start",
                "status": 303,
                "headers": [(b"location", location.encode()), (b"set-cookie", cookie.encode()),
                            (b"cache-control", b"no-store"), (b"content-length", b"0")],
            }
        )  # fmt: skip
        await send({"type": "http.response.body", "body": b""})

    async def _refuse(self, scope: Scope, send: Send, status: int, reason: str, kind: str = "Refused") -> None:
        if scope["type"] == "websocket":
            # Closing before accepting makes the server answer the handshake with 403.
            await send({"type": "websocket.close", "code": 1008, "reason": reason[:120]})
            return
        if scope.get("path", "").startswith("/api/"):
            # As the API's other errors are (its kind: a page left open over a restart tells a stale token by it).
            body, content_type = json.dumps({"error": reason, "kind": kind}).encode(), b"application/json"
        else:
            body, content_type = f"{status}: {reason}\n".encode(), b"text/plain; charset=utf-8"
        await send(
            {
                "type": "http.response.start",
                "status": status,
                "headers": [(b"content-type", content_type), (b"content-length", str(len(body)).encode())],
            }
        )
        await send({"type": "http.response.body", "body": body})
