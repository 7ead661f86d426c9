"""The configurator's server: the Starlette app (pages, API, WebSocket, behind the token guard) and
running it with uvicorn on a socket bound before the URL is printed."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import signal
import socket
import sys
import threading
import webbrowser
from collections.abc import AsyncIterator, Callable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from types import FrameType
from typing import Any, Literal

from starlette.applications import Starlette
from starlette.middleware import Middleware
from starlette.responses import FileResponse, Response
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles

from ..errors import InvalidArgument, error_text
from ..running import _after_stop
from ..terminal import ctrl_c_typed
from .api import ROUTES, may_change_servos
from .config import LineConfig
from .joints import RobotSession, not_freed_at_start
from .security import TokenGuard, is_loopback
from .session import MISSING_AT_CONNECT, LineSession

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
    note: Callable[[str], None] | None = None,
) -> Starlette:
    """The app for ``session``; every request and WebSocket needs ``token`` (see :mod:`.security`).

    The line opens when the server starts; a port that cannot be opened is
    shown on the Line page (and given to ``warn``), where another can be chosen.
    With ``line_from_robot`` the pages start on the robot's first line instead.
    ``note`` hears of a robot the Robot page opened (the terminal said it was not open, or lost), of a lost line
    that stopped it, and at the server's end what it leaves the robot's joints in.
    """

    @contextlib.asynccontextmanager
    async def lifespan(app: Starlette) -> AsyncIterator[None]:
        if robot is not None:
            await robot.open()
            if warn is not None:
                for text in [*robot.flat_out_lines(), *robot.warnings]:
                    warn(text)
            if robot.error and warn is not None:
                # (the page's words point to its question; the terminal's say what it is and the other ways out)
                asking = robot.start_free_choice
                warn(not_freed_at_start(asking) if asking else robot.error)
                if line_from_robot:
                    # (the robot's lines are there, only not opened, where the Robot page asks its question)
                    then = (
                        "the Robot page's question, answered,"
                        if robot.start_free_choice
                        else "Reconnect on the Robot page, once the robot's lines are there,"
                    )
                    warn(
                        f"until the robot is open the pages work on {session.config.port} (the built-in simulator):"
                        f" {then} brings them to its first line (or choose a port on the Line page)"
                    )
        try:
            if robot is not None and robot.robot is not None and line_from_robot:
                await session.use_robot_line(next(iter(robot.description.lines)))
            else:
                await session.connect()
        except Exception as exc:
            if warn is not None:
                said = session.error or error_text(exc)  # (in the page's words: its Connect for a missing port)
                there = "or choose another port there" if said.endswith(MISSING_AT_CONNECT) else None
                warn(f"{session.config.port}: {said} ({there or 'choose another port on the Line page'})")
        if robot is not None and robot.robot is None and line_from_robot:
            session.robot_line_to_come = next(iter(robot.description.lines))
        try:
            yield
        finally:
            if robot is not None:
                await robot.close()
                # (the server leaves every joint as it is, held or free: said, as `play` says what it left)
                if note is not None and robot.left_words is not None:
                    note(f"the server leaves the robot's joints as they are: {robot.left_words}")
            await session.close()

    app = Starlette(
        routes=[Route("/", _index), *ROUTES, Mount("/static", _Revalidated(directory=STATIC), name="static")],
        middleware=[Middleware(TokenGuard, token=token, loopback_only_hosts=loopback)],
        lifespan=lifespan,
    )
    session.robot = robot
    if robot is not None:
        robot.tell = note
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


class _Answering:
    """The app, counting the requests it is still answering (WebSockets and the lifespan pass through): what a
    stop waits for, and what a second Ctrl-C cuts short.

    A request cut short before its answer began is answered 503 with the reason (:data:`STOPPING_REASON`): the
    person stopped the server, which is no fault of its own (uvicorn would answer 500 and log the cancellation).
    A change cut short (a request that may change a servo: :func:`~ics35_async.web.api.may_change_servos`) says
    it may be done in part (:data:`CUT_SHORT_REASON`): it was under way, and Many servos' Apply had written some
    servos when "the server is stopping" read as a refusal.
    """

    def __init__(self, app: Any) -> None:
        self.app = app
        self.requests = 0
        self.cutting_short = False  # (set by a second Ctrl-C, before the requests under way are cancelled)

    async def __call__(self, scope: Any, receive: Any, send: Any) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        answer_begun = False

        async def sending(message: Any) -> None:
            nonlocal answer_begun
            answer_begun = answer_begun or message["type"] == "http.response.start"
            await send(message)

        self.requests += 1
        try:
            await self.app(scope, receive, sending)
        except asyncio.CancelledError:
            if not self.cutting_short or answer_begun:
                raise  # (an answer under way can only be broken off: uvicorn closes its connection)
            changing = may_change_servos(scope["method"], scope["path"])
            await _stopping_answer(send, CUT_SHORT_REASON if changing else STOPPING_REASON)
        finally:
            self.requests -= 1


STOPPING_REASON = b"the server is stopping"
CUT_SHORT_REASON = (
    b"the server stopped while doing this: it may be done in part (some servos written, or a write not read back): "
    b"read the servos again once the server is back"
)


async def _stopping_answer(send: Any, reason: bytes) -> None:
    await send(
        {
            "type": "http.response.start",
            "status": 503,
            "headers": [
                (b"content-type", b"text/plain; charset=utf-8"),
                (b"content-length", str(len(reason)).encode()),
                (b"connection", b"close"),
            ],
        }
    )
    await send({"type": "http.response.body", "body": reason})


# How long a stop waits before it says what it waits for (a stop that ends sooner says nothing).
_SAY_WAITING_AFTER = 1.0


class _CutShort(logging.Filter):
    """uvicorn's report of a request a second Ctrl-C cancelled once its answer had begun ("Exception in ASGI
    application" and the CancelledError's traceback): the command's last line says what was cut short."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not (record.exc_info and record.exc_info[0] is asyncio.CancelledError)


def _server_class() -> type[Any]:
    import uvicorn

    class Server(uvicorn.Server):
        """uvicorn's server, but a stop signal the process was started ignoring stays ignored, and a second
        Ctrl-C quits at once with the servos left as the stop leaves them.

        A shell without job control (a script) starts ``ics35 web &`` with SIGINT ignored, so that the Ctrl-C
        typed for its foreground command is not for it; uvicorn puts its handlers in for SIGINT and SIGTERM
        whatever was there, and that Ctrl-C would stop the server too.  (The other commands keep such a
        signal ignored: see ics35_async.running._heard.)

        A stop lets what was under way end (an EEPROM write on its way is answered, written and read back),
        which takes as long as the longest request still being answered.  A second Ctrl-C meanwhile is "quit
        now", as for every ``ics35`` command: those requests are cancelled (answered 503, the server is stopping,
        when their answer had not begun), and the app's shutdown still runs
        (uvicorn's own "quit now" skipped it: a live plot's stream and a robot's motion were dropped mid-way,
        not stopped).  A later SIGTERM is the same stop.
        """

        answering: _Answering | None = None
        note: Callable[[str], None] | None = None
        cut_short = 0

        def __init__(self, config: uvicorn.Config) -> None:
            super().__init__(config)
            self.ignored = {sig for sig in _STOPPING if signal.getsignal(sig) is signal.SIG_IGN}

        def handle_exit(self, sig: int, frame: FrameType | None) -> None:
            if sig in self.ignored:
                return
            if sig == signal.SIGINT:
                ctrl_c_typed()  # (what is said next clears the echoed ^C first)
            if not self.should_exit:
                super().handle_exit(sig, frame)
            elif sig == signal.SIGINT:
                self.force_exit = True  # (uvicorn's shutdown stops waiting for what is being answered)

        async def shutdown(self, sockets: list[socket.socket] | None = None) -> None:
            saying = asyncio.create_task(self._say_what_the_stop_waits_for())
            try:
                await super().shutdown(sockets)
            finally:
                saying.cancel()
            if self.force_exit and not self.lifespan.shutdown_event.is_set():
                # Forced out before the app's shutdown, which uvicorn then skips: the requests still being
                # answered are cancelled first (they would find the line closed under them), then it runs.
                self.cut_short = self.answering.requests if self.answering is not None else 0
                if self.answering is not None:
                    self.answering.cutting_short = True
                left = [task for task in self.server_state.tasks if not task.done()]
                quiet = _CutShort()
                logging.getLogger("uvicorn.error").addFilter(quiet)
                try:
                    for task in left:
                        task.cancel()
                    if left:
                        await asyncio.wait(left)
                finally:
                    logging.getLogger("uvicorn.error").removeFilter(quiet)
                await self.lifespan.shutdown()

        async def _say_what_the_stop_waits_for(self) -> None:
            await asyncio.sleep(_SAY_WAITING_AFTER)
            requests = self.answering.requests if self.answering is not None else 0
            if requests and not self.force_exit and self.note is not None:
                which = "a request" if requests == 1 else f"{requests} requests"
                self.note(f"stopping: waiting for {which} still being answered (Ctrl-C again: stop at once)")

    return Server


_STOPPING = (signal.SIGINT, signal.SIGTERM)


@contextlib.contextmanager
def _ctrl_c_stops(server: Any) -> Iterator[None]:
    """Ctrl-C is ``server``'s stop for the whole of its run, the event loop's making and closing included.

    uvicorn takes the stop signals over only while it serves; once stopped it hands the signal on to the
    handler it found, which was asyncio's runner's (it cancels the finished main task and raises
    KeyboardInterrupt), with Python's own back while the runner closes the loop.  A double Ctrl-C's second
    press landing there raised KeyboardInterrupt wherever the main thread was: inside uvloop's own step as a run
    of the loop ends (its self-pipe closed), it left the loop running and unclosable ("RuntimeError: Cannot
    close a running event loop", a traceback, exit code 1).  With this handler there instead (the runner then
    keeps out), a press before the server serves stops it as soon as it does, and uvicorn's handing on is the
    stop made: from then a press within a moment is the same stop (see ``running._AfterStop``), a later one
    Python's KeyboardInterrupt (a close that hangs can still be left).  Main thread, Python's handler only."""
    if (
        threading.current_thread() is not threading.main_thread()
        or signal.getsignal(signal.SIGINT) is not signal.default_int_handler
    ):
        yield  # (ignored, or the program's own handler: as uvicorn has it)
        return

    def on_sigint(signum: int, frame: FrameType | None) -> None:
        if server.should_exit:  # (uvicorn handing its stop on, or a press after it)
            _after_stop({signal.SIGINT: signal.default_int_handler})
            return
        server.handle_exit(signum, frame)

    signal.signal(signal.SIGINT, on_sigint)
    try:
        yield
    finally:
        if signal.getsignal(signal.SIGINT) is on_sigint:  # (not stopped by Ctrl-C: as it was)
            signal.signal(signal.SIGINT, signal.default_int_handler)


def _only_terminal_browsers() -> bool:
    # (macOS and Windows open their browsers without a display variable; elsewhere a graphical one needs one)
    if sys.platform in ("darwin", "win32") or os.environ.get("BROWSER"):
        return False
    return not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def _browser_opened(url: str) -> bool:
    """Whether the default browser took ``url``: False where none could be started (no display, no browser
    installed, ``$BROWSER`` failing), which :func:`webbrowser.open` says by returning False or by raising.

    Without a display (an ssh session) and without ``$BROWSER``, none is tried: all :mod:`webbrowser` finds
    there is a terminal browser (www-browser, lynx, w3m), which it runs in the foreground on the command's own
    terminal, the server waiting until it quits, on a page whose scripts it cannot run."""
    if _only_terminal_browsers():
        return False
    try:
        return webbrowser.open(url)
    except Exception:  # (whatever a platform's browser launcher raises: the address is printed all the same)
        return False


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
    robot_ask_before_freeing: bool = True,
    line_from_robot: bool = False,
    note: Callable[[str], None] | None = None,
    no_browser_opened: Callable[[], None] | None = None,
    loop: Literal["auto", "asyncio", "uvloop"] = "auto",
) -> int:
    """Serve until Ctrl-C; ``announce`` gets the URL first (with the token in it), ``warn`` what goes wrong
    (and, once bound beyond loopback, that any machine that reaches it and knows the token can move the servos),
    ``note`` what the server does as it stops (a stop that waits for requests still being answered, what it leaves
    the robot's joints in) and what befalls the robot meanwhile (the Robot page opened it, a lost line stopped it),
    ``no_browser_opened`` that ``open_browser`` was asked for and no browser could be opened (a headless machine,
    an ssh session): the address announced is then for the person to open.

    A stop lets the requests under way end; a second Ctrl-C meanwhile cuts them short (answered 503, "the server
    is stopping").  Either way the app's
    own shutdown then runs: the live plots and a playing motion stop as at any stop.  Returns how many requests
    a second Ctrl-C cut short (0: every one was answered).

    ``robot_options``: what ``open_robot`` gets for every line of ``robot_file`` (e.g. ``adapter_latency``);
    ``robot_start_pose``: its ``start_pose`` (where the robot stands: those joints hold there from the start).
    ``robot_ask_before_freeing``: its ICS 3.5 joints on serial lines that would start free (read by freeing them)
    wait for the Robot page's answer before the robot opens (see ``RobotSession``); False: freed at the start.
    ``line_from_robot``: the pages start on the robot's first line rather than ``config``'s port.
    ``loop``: the event loop (``auto``: uvloop when it is installed, else asyncio's).
    """
    # A bad robot file is refused here, before binding.
    robot = (
        None
        if robot_file is None
        else RobotSession(robot_file, robot_options, robot_start_pose, ask_before_freeing=robot_ask_before_freeing)
    )
    sock = bind(listen)
    if not listen.loopback and warn is not None:  # (once bound: not before a refusal to listen there)
        warn(
            f"serving on {listen.host}: any machine that can reach it and knows the token can move these servos; "
            "keep the URL private"
        )
    app = _Answering(
        create_app(
            LineSession(config),
            token,
            loopback=listen.loopback,
            warn=warn,
            robot=robot,
            line_from_robot=line_from_robot,
            note=note,
        )
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
            loop=loop,
        )
    )
    server.answering = app
    server.note = note
    if open_browser and not _browser_opened(url) and no_browser_opened is not None:
        no_browser_opened()
    try:
        with _ctrl_c_stops(server):
            server.run(sockets=[sock])
    except KeyboardInterrupt:
        if not server.should_exit:
            raise  # (a Ctrl-C before the server's handler was there)
        # (else a press the stop's moment over, as the runner closes the loop: the stop made all the same)
    finally:
        sock.close()
    return int(server.cut_short)
