"""The configurator's HTTP API and its WebSocket: thin handlers over :class:`.session.LineSession`.

Every failure is answered as JSON ``{"error": "...", "kind": "..."}`` with a
status that says whose it is (400 bad input, 409 refused, 502/504 the servo,
503 the port), never a traceback.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import json
import logging
import sys
from collections.abc import Awaitable, Callable
from typing import Any

from starlette.requests import Request
from starlette.responses import JSONResponse, Response
from starlette.routing import Route, WebSocketRoute
from starlette.websockets import WebSocket, WebSocketDisconnect

from ..diagnose.system import missing_adapter_notes
from ..eeprom import Eeprom
from ..errors import (
    BadReply,
    BusClosed,
    IcsError,
    InvalidArgument,
    MalformedEeprom,
    PartialReply,
    PortLost,
    ReplyError,
    ReplyTimeout,
    SerialPortError,
    UnsafeOperation,
    VerifyError,
    error_text,
)
from ..policies.eeprom_backup import backup_file_name
from ..protocol import MAX_ID
from ..robot.safety import SafetyStop
from ..transports.listing import kondo_usb_without_port, list_serial_ports
from ..units import parse_id_list, plain_count
from ..user_files import parse_json
from .joints import RobotSession
from .live import LIVE_RATE_HZ
from .session import PAGE_NAME_MAX, JogFreedServo, LineSession, said_at_connect
from .views import field_rows

log = logging.getLogger("ics35_async.web")

Handler = Callable[[Request, LineSession], Awaitable[Any]]

# Page refresh over the WebSocket: fast while plotting, slow otherwise.
LIVE_PERIOD = 0.04
IDLE_PERIOD = 0.25
TELEMETRY_PERIOD = 1.0
# A live frame's parts that change at most a few times a second: sent when they change (the page keeps
# the last), so the 25 updates a second carry little more than the positions.
LIVE_SLOW_PARTS = ("targets", "current", "temperature", "watched", "offline", "held")


def _status_of(exc: BaseException) -> int:
    if isinstance(exc, (UnsafeOperation, SafetyStop)):  # (a safety stop standing refuses a move: nothing sent)
        return 409
    if isinstance(exc, (InvalidArgument, MalformedEeprom, ValueError, TypeError, KeyError)):
        return 400
    if isinstance(exc, ReplyTimeout):
        return 504
    if isinstance(exc, (ReplyError, VerifyError)):
        return 502
    if isinstance(exc, (PortLost, BusClosed, SerialPortError, OSError)):
        return 503
    return 500


def error_response(exc: BaseException, said: str | None = None, **more: Any) -> JSONResponse:
    """The page's error for ``exc``: its words (or ``said``, what the session made of it), kind and status,
    and ``more`` the page can act on."""
    status = _status_of(exc)
    if said is not None:
        message = said
    elif status == 500:
        log.error("internal error: %s: %s", type(exc).__name__, exc)
        message = f"internal error ({type(exc).__name__}: {exc}); the line is unchanged by this request"
    elif isinstance(exc, KeyError):
        message = f"missing {exc}"
    else:
        message = error_text(exc)
    for note in getattr(exc, "__notes__", ()):  # (what the session knows beyond the error: a write that went out)
        message = f"{message}; {note}"
    return JSONResponse({"error": message, "kind": type(exc).__name__, **more}, status_code=status)


async def no_reply_response(session: LineSession, exc: ReplyTimeout, *, look_at_other_rates: bool) -> JSONResponse:
    """A servo's page asked a servo that did not answer: why (:meth:`LineSession.no_reply`), and the rate
    it answers at instead (``answers_at``) when it does."""
    try:
        answer = await session.no_reply(exc, look_at_other_rates=look_at_other_rates)
    except (IcsError, OSError) as failed:  # the line itself failed while looking: that is the news
        return error_response(failed)
    return error_response(exc, answer.pop("error"), **answer)


# The POST routes that only read or open (a scan, a plan, a survey, a backup, a Connect, a live plot stopped): one
# cut short by the server's stop changed no servo.  Every other POST may have (a write, a move, a free, an Apply).
READS_ONLY = frozenset({"/api/connect", "/api/scan", "/api/id/survey", "/api/many/backup", "/api/live/stop"})


def may_change_servos(method: str, path: str) -> bool:
    """Whether a request of ``method`` to ``path`` may change a servo (what one cut short may have done in part)."""
    if method in ("GET", "HEAD", "OPTIONS"):
        return False
    return path not in READS_ONLY and not path.endswith("/plan")


def endpoint(handler: Handler, *, look_at_other_rates: bool = False) -> Callable[[Request], Awaitable[Response]]:
    """``handler`` answering JSON; a servo that did not answer is explained (:func:`no_reply_response`), and
    with ``look_at_other_rates`` looked for at the other baud rates.

    Only the EEPROM read looks: it is what the Servo page sends when a person opens it or presses Read, on
    purpose, to see a servo.  A search holds the line for a third of a second and reopens the port at each
    rate (some boards reset when it opens); after the position poll (twice a second), a jog, Free or Hold it
    would do so again and again while a servo has lost its power, and the page's other actions would wait.
    The session keeps what was found until the next Connect, so a page read again is told, not searched
    again (a button to ask for the search would leave the first look, the one that matters, to a person
    who does not know the servo may be at another rate).
    """

    @functools.wraps(handler)
    async def run(request: Request) -> Response:
        session: LineSession = request.app.state.session
        try:
            result = await handler(request, session)
        except ReplyTimeout as exc:
            if exc.servo_id is not None:
                session.lost_touch([exc.servo_id])  # (it may have restarted: free, elsewhere)
            if "servo_id" not in request.path_params:
                return error_response(exc)
            return await no_reply_response(session, exc, look_at_other_rates=look_at_other_rates)
        except (BadReply, PartialReply) as exc:  # (two servos sharing an ID, most often: said so)
            return error_response(exc, session.answered_garbled(exc))
        except (IcsError, OSError, ValueError, TypeError, KeyError) as exc:
            return error_response(exc)
        except Exception as exc:  # the page shows words, the terminal one line; never a traceback
            return error_response(exc)
        return result if isinstance(result, Response) else JSONResponse(result)

    return run


async def body(request: Request) -> dict[str, Any]:
    try:
        data = parse_json(await request.body())
    except json.JSONDecodeError as exc:
        raise InvalidArgument(f"the request is not JSON: {exc}") from None
    if not isinstance(data, dict):
        raise InvalidArgument("the request must be a JSON object")
    return data


def servo_id(request: Request) -> int:
    text = request.path_params["servo_id"]
    number = plain_count(text)
    if number is None or not 0 <= number <= MAX_ID:
        raise InvalidArgument(f"servo ID {text!r} is not 0..{MAX_ID}")
    return number


def int_of(data: dict[str, Any], key: str) -> int:
    value = data[key]
    if isinstance(value, bool) or not isinstance(value, int):
        raise InvalidArgument(f"{key} must be an integer, got {value!r}")
    return value


# --------------------------------------------------------------------------- the line


async def status(request: Request, session: LineSession) -> Any:
    return session.status()


async def ports(request: Request, session: LineSession) -> Any:
    try:
        found = list_serial_ports()
    except Exception as exc:  # pyserial's platform backend failed: say so
        return {"ports": [], "notes": [f"cannot list serial ports: {exc}"]}
    # (worded as ics35 ports and ics35 doctor word it)
    notes = missing_adapter_notes(
        found, kondo_usb_without_port(), linux=sys.platform.startswith("linux"), port=session.config.port
    )
    return {"ports": [p.to_dict() for p in found], "notes": notes}


async def connect(request: Request, session: LineSession) -> Any:
    data = await body(request)
    if data.get("robot_line") is not None:
        return await session.use_robot_line(data["robot_line"])
    try:
        return await session.connect(data.get("port"), data.get("baud"))
    except OSError as exc:  # (said with the hints the session found: a COM name off Windows, ...)
        return error_response(exc, said_at_connect(exc))


async def scan(request: Request, session: LineSession) -> Any:
    data = await body(request)
    ids = data.get("ids")
    if ids is not None and (not isinstance(ids, list) or not ids):
        raise InvalidArgument("name the IDs to scan as a list, e.g. [1, 2, 3], or none for all 32")
    return await session.scan(data.get("bauds"), ids)


# --------------------------------------------------------------------------- one servo


async def eeprom(request: Request, session: LineSession) -> Any:
    return await session.read_eeprom(servo_id(request))


async def ram(request: Request, session: LineSession) -> Any:
    return await session.read_ram(servo_id(request))


async def ram_write(request: Request, session: LineSession) -> Any:
    data = await body(request)
    name = data.get("param")
    return {"param": name, "value": await session.write_ram(servo_id(request), str(name), int_of(data, "value"))}


async def plan(request: Request, session: LineSession) -> Any:
    _, view = await session.plan(servo_id(request), await body(request))
    return view


async def write(request: Request, session: LineSession) -> Any:
    return await session.write(servo_id(request), await body(request))


async def backup(request: Request, session: LineSession) -> Any:
    sid = servo_id(request)
    doc = await session.backup(sid)
    return JSONResponse(doc, headers={"content-disposition": f'attachment; filename="{backup_file_name([sid])}"'})


def restore_edit(session: LineSession, sid: int, data: dict[str, Any]) -> dict[str, Any]:
    """The request's edit for servo ``sid``: the backup's fields (its ID only with ``restore_id``, its rate not with
    ``keep_baud``), from a file of several servos' backups the one of ``sid``."""
    wanted = {"restore_id": data.get("restore_id") is True, "keep_baud": data.get("keep_baud") is True}
    return {**data, **session.restore_edit(data.get("doc"), sid, **wanted)}


async def restore_plan(request: Request, session: LineSession) -> Any:
    sid = servo_id(request)
    edit = restore_edit(session, sid, await body(request))
    _, view = await session.plan(sid, edit)
    return {**view, "saved_id": edit["saved_id"], "file_holds": edit["file_holds"]}


async def restore(request: Request, session: LineSession) -> Any:
    sid = servo_id(request)
    return await session.write(sid, restore_edit(session, sid, await body(request)))


async def free(request: Request, session: LineSession) -> Any:
    return {"position": await session.free(servo_id(request))}


async def hold(request: Request, session: LineSession) -> Any:
    return {"position": await session.hold(servo_id(request))}


async def motion(request: Request, session: LineSession) -> Any:
    sid, data = servo_id(request), await body(request)
    position = None
    if data.get("enabled") is True:
        position = await session.enable_motion(sid, data.get("page"))  # (the page's name: see updates)
    else:
        session.disable_motion(sid)
    return {
        "enabled": sid in session.motion_enabled,
        "limits": session.check_limits(sid),
        "position": position,
        "motion_switches": session.motion_switches,  # (a status counting fewer is from before this answer)
    }


async def position(request: Request, session: LineSession) -> Any:
    return await session.read_position(servo_id(request))


async def move(request: Request, session: LineSession) -> Any:
    try:
        return {"position": await session.move(servo_id(request), int_of(await body(request), "position"))}
    except JogFreedServo as exc:  # (the page shows the servo free where it stands, not at its last target)
        return error_response(exc, kind="UnsafeOperation", freed=True, position=exc.position)  # (its kind as ever)


# --------------------------------------------------------------------------- ID, many, live, traffic


async def id_survey(request: Request, session: LineSession) -> Any:
    return await session.survey()


async def id_write(request: Request, session: LineSession) -> Any:
    return await session.renumber(int_of(await body(request), "new_id"))


async def many_apply(request: Request, session: LineSession) -> Any:
    data = await body(request)
    ids = data.get("ids")
    if not isinstance(ids, list) or not ids:
        raise InvalidArgument("choose at least one servo")
    return {"results": await session.apply_to_many(ids, data)}


async def ids_in_text(request: Request, session: LineSession) -> Any:
    """The IDs a box's text names, by the command line's rule (``units.parse_id_list``): the pages keep none of
    their own."""
    return {"ids": parse_id_list(request.query_params.get("text", ""))}


async def many_fields(request: Request, session: LineSession) -> Any:
    """Each EEPROM field's unit, range and meaning, as the Servo page shows them (the Many servos page's table)."""
    return {"fields": field_rows(Eeprom.factory())}


async def many_last(request: Request, session: LineSession) -> Any:
    return {"last": session.many_last}


async def many_backup(request: Request, session: LineSession) -> Any:
    ids = (await body(request)).get("ids")
    if not isinstance(ids, list) or not ids:
        raise InvalidArgument("choose at least one servo")
    doc = await session.backup_many(ids)
    name = backup_file_name(ids)
    return JSONResponse(doc, headers={"content-disposition": f'attachment; filename="{name}"'})


async def live_start(request: Request, session: LineSession) -> Any:
    data = await body(request)
    ids = data.get("ids")
    if not isinstance(ids, list) or not ids:
        raise InvalidArgument("choose at least one servo to plot")
    rate_hz = data.get("rate_hz")
    view = await session.start_live(
        ids, LIVE_RATE_HZ if rate_hz is None else rate_hz, free_ics35=data.get("free_ics35", False)
    )
    return {**session.status(), "kept_held": view.kept_held, "left_out": view.left_out}


async def live_stop(request: Request, session: LineSession) -> Any:
    await session.stop_live()
    return session.status()


async def live(request: Request, session: LineSession) -> Any:
    return None if session.live is None else session.live.snapshot()


def joints_of(request: Request) -> RobotSession:
    robot: RobotSession | None = request.app.state.robot
    if robot is None:
        raise InvalidArgument("no robot: start with `ics35 web --robot ROBOT.toml`")
    return robot


async def robot_view(request: Request, session: LineSession) -> Any:
    robot: RobotSession | None = request.app.state.robot
    return None if robot is None else robot.view()


async def robot_motion(request: Request, session: LineSession) -> Any:
    robot, data = joints_of(request), await body(request)
    enabled, page = data.get("enabled") is True, data.get("page")  # (the page's name: see updates)
    if enabled:
        await robot.ready_for_motion()  # (readings, then a gone page's stop: the check below holds for the switch)
        session.refuse_absent_page(page, "again")
    await robot.set_motion(enabled, page if enabled and isinstance(page, str) else None)
    return robot.view()


async def robot_reopen(request: Request, session: LineSession) -> Any:
    robot = joints_of(request)
    data = await body(request)
    await robot.reopen(data.get("lost_joints"), data.get("start_free"))
    # The pages follow the line to the reopened robot (or go to the one they stood in for, the robot not open at
    # the start).
    line = session.robot_line or session.robot_line_to_come
    if line is not None and robot.robot is not None:
        await session.use_robot_line(line)
    return robot.view()


async def robot_move(request: Request, session: LineSession) -> Any:
    robot, data = joints_of(request), await body(request)
    pose = data.get("pose")
    if not isinstance(pose, dict):
        raise InvalidArgument("pose must be an object of joint: degrees")
    await robot.move(pose, data.get("duration", 0.5))
    return robot.view()


async def robot_play(request: Request, session: LineSession) -> Any:
    robot, data = joints_of(request), await body(request)
    await robot.play(data.get("motion"), data.get("speed", 1.0))
    return robot.view()


async def robot_stop(request: Request, session: LineSession) -> Any:
    robot = joints_of(request)
    await robot.press_stop()
    return robot.view()


async def robot_reset_trip(request: Request, session: LineSession) -> Any:
    robot = joints_of(request)
    robot.reset_trip((await body(request)).get("joint"))
    return robot.view()


async def robot_free(request: Request, session: LineSession) -> Any:
    robot = joints_of(request)
    await robot.free((await body(request)).get("joint"))
    return robot.view()


async def traffic(request: Request, session: LineSession) -> Any:
    since = request.query_params.get("since", "0")
    return {"entries": session.traffic.since(int(since) if since.isdigit() else 0)}


async def updates(ws: WebSocket) -> None:
    """Push the line's status, scan progress, telemetry, live frames and traffic to one page.

    The status, the scan's progress and a live frame's slow parts are sent
    to a page when they differ from what it was last sent.  The page names
    itself (``/ws?page=NAME``, a random name of its own): while this socket is
    open that page is there, and once it closes (the tab closed, or the
    server's pings unanswered: the page's network gone) the motion the page
    switched on goes off (:meth:`LineSession.page_gone`).
    """
    session: LineSession = ws.app.state.session
    name = ws.query_params.get("page")
    page = name if name and len(name) <= PAGE_NAME_MAX else None
    await ws.accept()
    if page is not None:
        session.page_came(page)
    gone = False

    def page_gone() -> None:
        # At once from the reader, which hears the socket close: the pushing loop may be waiting on a slow
        # round of reads meanwhile.  Once only, from either.
        nonlocal gone
        if page is not None and not gone:
            gone = True
            session.page_gone(page)

    watching_traffic = False
    seen = 0
    last_telemetry = 0.0
    telemetry_read = False  # the servos' values were read since the last push
    loop = asyncio.get_running_loop()
    sent: dict[object, Any] = {}  # what this page was sent last, by part
    live_sent: object = None  # the live view those parts came from (a new one sends them all)

    def fresh(part: object, value: Any) -> bool:
        if part in sent and sent[part] == value:
            return False
        sent[part] = value
        return True

    async def listen() -> None:
        nonlocal watching_traffic
        try:
            while True:
                message = await ws.receive_json()
                want = bool(isinstance(message, dict) and message.get("traffic"))
                if want != watching_traffic:
                    watching_traffic = want
                    (session.traffic.watch if want else session.traffic.unwatch)()
        finally:
            page_gone()

    listener = asyncio.create_task(listen())
    try:
        while not listener.done():
            update: dict[str, Any] = {}
            if telemetry_read:
                update["servos"] = session.servos_view()
                telemetry_read = False
            status = session.status()
            if fresh("status", status):
                update["status"] = status
            progress = {"done": session.progress.done, "total": session.progress.total}
            if session.progress.total and fresh("progress", progress):
                update["progress"] = progress
            if ws.app.state.robot is not None:
                update["robot"] = ws.app.state.robot.view()
            live = session.live
            if live is not None:
                if live is not live_sent:
                    live_sent = live
                    for part in LIVE_SLOW_PARTS:
                        sent.pop(("live", part), None)
                frame = live.snapshot()
                if frame is not None:
                    for part in LIVE_SLOW_PARTS:
                        if not fresh(("live", part), frame[part]):
                            del frame[part]
                update["live"] = frame
            if watching_traffic:
                entries = session.traffic.since(seen)
                if entries:
                    seen = entries[-1]["seq"]
                    update["traffic"] = entries[-500:]
            if update:
                await ws.send_json(update)
            if loop.time() - last_telemetry >= TELEMETRY_PERIOD and session.found:
                # Between two pushes, each taken just before it is sent: one taken before these reads
                # and sent after them would say what was before an answer the page got meanwhile (a box
                # the user ticked flipping back).  Their values go out at once, with the rest as it is then.
                with contextlib.suppress(IcsError):
                    await session.read_telemetry()  # none while a live stream runs: the table shows its values
                # The period counts from the round's end: a slow round (servos that stopped answering)
                # leaves the line to the page's own actions in between, not back to back with the next.
                last_telemetry = loop.time()
                telemetry_read = True
                continue
            await asyncio.sleep(LIVE_PERIOD if session.live is not None else IDLE_PERIOD)
    except (WebSocketDisconnect, RuntimeError):
        pass
    finally:
        listener.cancel()
        with contextlib.suppress(asyncio.CancelledError, WebSocketDisconnect, RuntimeError):
            await listener
        page_gone()
        if watching_traffic:
            session.traffic.unwatch()


ROUTES = [
    Route("/api/status", endpoint(status)),
    Route("/api/ports", endpoint(ports)),
    Route("/api/connect", endpoint(connect), methods=["POST"]),
    Route("/api/scan", endpoint(scan), methods=["POST"]),
    Route("/api/servo/{servo_id}/eeprom", endpoint(eeprom, look_at_other_rates=True)),
    Route("/api/servo/{servo_id}/ram", endpoint(ram)),
    Route("/api/servo/{servo_id}/ram/write", endpoint(ram_write), methods=["POST"]),
    Route("/api/servo/{servo_id}/plan", endpoint(plan), methods=["POST"]),
    Route("/api/servo/{servo_id}/write", endpoint(write), methods=["POST"]),
    Route("/api/servo/{servo_id}/backup", endpoint(backup)),
    Route("/api/servo/{servo_id}/restore/plan", endpoint(restore_plan), methods=["POST"]),
    Route("/api/servo/{servo_id}/restore", endpoint(restore), methods=["POST"]),
    Route("/api/servo/{servo_id}/free", endpoint(free), methods=["POST"]),
    Route("/api/servo/{servo_id}/hold", endpoint(hold), methods=["POST"]),
    Route("/api/servo/{servo_id}/motion", endpoint(motion), methods=["POST"]),
    Route("/api/servo/{servo_id}/position", endpoint(position)),
    Route("/api/servo/{servo_id}/move", endpoint(move), methods=["POST"]),
    Route("/api/id/survey", endpoint(id_survey), methods=["POST"]),
    Route("/api/id/write", endpoint(id_write), methods=["POST"]),
    Route("/api/many/apply", endpoint(many_apply), methods=["POST"]),
    Route("/api/many/backup", endpoint(many_backup), methods=["POST"]),
    Route("/api/many/last", endpoint(many_last)),
    Route("/api/many/fields", endpoint(many_fields)),
    Route("/api/ids", endpoint(ids_in_text)),
    Route("/api/live/start", endpoint(live_start), methods=["POST"]),
    Route("/api/live/stop", endpoint(live_stop), methods=["POST"]),
    Route("/api/live", endpoint(live)),
    Route("/api/traffic", endpoint(traffic)),
    Route("/api/robot", endpoint(robot_view)),
    Route("/api/robot/motion", endpoint(robot_motion), methods=["POST"]),
    Route("/api/robot/move", endpoint(robot_move), methods=["POST"]),
    Route("/api/robot/play", endpoint(robot_play), methods=["POST"]),
    Route("/api/robot/stop", endpoint(robot_stop), methods=["POST"]),
    Route("/api/robot/free", endpoint(robot_free), methods=["POST"]),
    Route("/api/robot/reset_trip", endpoint(robot_reset_trip), methods=["POST"]),
    Route("/api/robot/reopen", endpoint(robot_reopen), methods=["POST"]),
    WebSocketRoute("/ws", updates),
]
