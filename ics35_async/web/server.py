"""The configurator's server: the Starlette app (pages, API, WebSocket, behind the token guard) and
running it with uvicorn on a socket bound before the URL is printed."""

from __future__ import annotations

import contextlib
import signal
import socket
import webbrowser
from collections.abc import AsyncIterator, Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from types import FrameType
from typing import Any

from starlette.applications import Starlette
from starlette.middleware import Middleware
from starlette.responses import FileResponse, Response
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles

from ..errors import InvalidArgument, error_text
from .api import ROUTES
from .config import LineConfig
from .joints import RobotSession
from .security import TokenGuard, is_loopback
from .session import LineSession

STATIC = Path(__file__).with_name("static")


@dataclass(frozen=True)
class Listen:
    host: str = "127.0.0.1"
    port: int = 0  # 0: a free port

    @classmethod
    def parse(cls, text: str) -> Listen:
        """``HOST:PORT``, ``HOST``, ``:PORT`` or ``PORT`` (IPv6 in brackets: ``[::1]:8080``)."""
        text = text.strip()
        host, port = text, ""
        if text.isdigit():
            host, port = "", text
        if text.startswith("["):
            host, _, rest = text[1:].partition("]")
            port = rest.removeprefix(":")
        elif text.count(":") == 1:
            host, port = text.split(":")
        if port and not (port.isdigit() and int(port) <= 65535):
            raise InvalidArgument(f"--listen {text}: the port must be a number 0..65535")
        return cls(host or "127.0.0.1", int(port or 0))

    @property
    def loopback(self) -> bool:
        return is_loopback(self.host)


# Each page's WebSocket is pinged this often, and closed when a ping goes this long unanswered: a page whose
# network went (a laptop asleep, Wi-Fi gone) closes nothing, and the motion it switched on goes off only once
# its socket is closed (see api.updates).  The browser answers pings itself, in a background tab too.
PAGE_PING_PERIOD = 1.0
PAGE_PING_TIMEOUT = 3.0


# The page runs only its own scripts and talks only to this server; no other site may frame it
# (a framed page could be clicked through by another site) or learn its address.
PAGE_HEADERS = {
    "cache-control": "no-store",
    "content-security-policy": "default-src 'self'; connect-src 'self'; img-src 'self' data: blob:; "
    "frame-ancestors 'none'; form-action 'self'; base-uri 'none'",
    "x-frame-options": "DENY",
    "referrer-policy": "no-referrer",
    "x-content-type-options": "nosniff",
}


class _Revalidated(StaticFiles):
    """The page's scripts and style, checked again (by their ETag) at each load: with no cache header a
    browser keeps a file for a tenth of its age, and after an upgrade would run the old app.js against
    the new server."""

    async def get_response(self, path: str, scope: Any) -> Response:
        response = await super().get_response(path, scope)
        response.headers["cache-control"] = "no-cache"
        return response


async def _index(request: object) -> Response:
    return FileResponse(STATIC / "index.html", headers=PAGE_HEADERS)


def create_app(
    session: LineSession,
    token: str,
    *,
    loopback: bool = True,
    warn: Callable[[str], None] | None = None,
    robot: RobotSession | None = None,
    line_from_robot: bool = False,
) -> Starlette:
    """The app for ``session``; every request and WebSocket needs ``token`` (see :mod:`.security`).

    The line opens when the server starts; a port that cannot be opened is
    shown on the Line page (and given to ``warn``), where another can be chosen.
    With ``line_from_robot`` the pages start on the robot's first line instead.
    """

    @contextlib.asynccontextmanager
    async def lifespan(app: Starlette) -> AsyncIterator[None]:
        if robot is not None:
            await robot.open()
            if warn is not None:
                for text in [*robot.flat_out_lines(), *robot.warnings]:
                    warn(text)
            if robot.error and warn is not None:
                warn(robot.error)
                if line_from_robot:
                    warn(
                        f"the pages start on {session.config.port} instead: once the robot's lines are "
                        "there, restart the command (or choose a port on the Line page)"
                    )
        try:
            if robot is not None and robot.robot is not None and line_from_robot:
                await session.use_robot_line(next(iter(robot.description.lines)))
            else:
                await session.connect()
        except Exception as exc:
            if warn is not None:
                warn(f"{session.config.port}: {error_text(exc)} (choose another port on the Line page)")
        try:
            yield
        finally:
            if robot is not None:
                await robot.close()
            await session.close()

    app = Starlette(
        routes=[Route("/", _index), *ROUTES, Mount("/static", _Revalidated(directory=STATIC), name="static")],
        middleware=[Middleware(TokenGuard, token=token, loopback_only_hosts=loopback)],
        lifespan=lifespan,
    )
    session.robot = robot
    app.state.session = session
    app.state.robot = robot
    return app


def bind(listen: Listen) -> socket.socket:
    family = socket.AF_INET6 if ":" in listen.host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((listen.host, listen.port))
    except OSError as exc:
        sock.close()
        raise InvalidArgument(f"cannot listen on {listen.host}:{listen.port}: {exc.strerror or exc}") from None
    sock.listen(64)
    return sock


def url_of(sock: socket.socket, token: str) -> str:
    host, port = sock.getsockname()[:2]
    shown = f"[{host}]" if ":" in host else host
    if host in ("0.0.0.0", "::"):
        shown = "127.0.0.1" if host == "0.0.0.0" else "[::1]"
    return f"http://{shown}:{port}/?token={token}"


def _server_class() -> type[Any]:
    import uvicorn

    class Server(uvicorn.Server):
        """uvicorn's server, but a stop signal the process was started ignoring stays ignored, and a second one
        as it stops is the same stop.

        A shell without job control (a script) starts ``ics35 web &`` with SIGINT ignored, so that the Ctrl-C
        typed for its foreground command is not for it; uvicorn puts its handlers in for SIGINT and SIGTERM
        whatever was there, and that Ctrl-C would stop the server too.  (The other commands keep such a
        signal ignored: see ics35_async.running._heard.)

        uvicorn takes a second Ctrl-C for "quit now": the requests still being answered (an EEPROM write on its
        way) and the pages' connections were cancelled mid-way, the robot not brought to rest, and tracebacks
        filled the terminal.  A stop lets what was under way end (as every ``ics35`` command takes a second
        press for the first's stop): it takes as long as the longest request still being answered.
        """

        def __init__(self, config: uvicorn.Config) -> None:
            super().__init__(config)
            self.ignored = {sig for sig in _STOPPING if signal.getsignal(sig) is signal.SIG_IGN}

        def handle_exit(self, sig: int, frame: FrameType | None) -> None:
            if sig not in self.ignored and not self.should_exit:
                super().handle_exit(sig, frame)

    return Server


_STOPPING = (signal.SIGINT, signal.SIGTERM)


def serve(
    config: LineConfig,
    token: str,
    listen: Listen,
    *,
    open_browser: bool = True,
    announce: Callable[[str], None] = print,
    warn: Callable[[str], None] | None = None,
    robot_file: str | None = None,
    robot_options: Mapping[str, Any] | None = None,
    robot_start_pose: Mapping[str, float] | None = None,
    line_from_robot: bool = False,
) -> None:
    """Serve until Ctrl-C; ``announce`` gets the URL first (with the token in it), ``warn`` what goes wrong.

    ``robot_options``: what ``open_robot`` gets for every line of ``robot_file`` (e.g. ``adapter_latency``);
    ``robot_start_pose``: its ``start_pose`` (where the robot stands: those joints hold there from the start).
    ``line_from_robot``: the pages start on the robot's first line rather than ``config``'s port.
    """
    # A bad robot file is refused here, before binding.
    robot = None if robot_file is None else RobotSession(robot_file, robot_options, robot_start_pose)
    sock = bind(listen)
    app = create_app(
        LineSession(config), token, loopback=listen.loopback, warn=warn, robot=robot, line_from_robot=line_from_robot
    )
    url = url_of(sock, token)
    announce(url)  # the socket listens already: a browser that comes now waits in its backlog
    import uvicorn  # after the URL: it is the slower half of the start-up

    server = _server_class()(
        uvicorn.Config(
            app,
            log_level="warning",
            lifespan="on",
            ws="websockets-sansio",
            ws_ping_interval=PAGE_PING_PERIOD,
            ws_ping_timeout=PAGE_PING_TIMEOUT,
        )
    )
    if open_browser:
        with contextlib.suppress(Exception):
            webbrowser.open(url)
    try:
        server.run(sockets=[sock])
    finally:
        sock.close()
