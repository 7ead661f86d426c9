"""Library errors in a person's words: what went wrong on the line, and what to check or pass."""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Awaitable, Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from .. import errors
from ..diagnose.system import check_holders
from ..policies.failure_kinds import echo_setting_wrong, id0_top_bit_differs
from ..transports import carries_line_settings
from ..transports.platforms import misnamed_port_hints, permission_hint, port_group, port_names_hint
from ..transports.wire_device import example_port, is_url, url_scheme
from ._console import err, no_servo_among, say
from ._loop import run_loop
from ._settings import CliError, ExitCode, Settings

if TYPE_CHECKING:
    from ..bus import Bus

NO_REPLY_HINTS = (
    "check the servo has power (6-12 V on the servo line, not just USB)",
    "check the wiring and the servo ID (ics35 scan tries every ID at every baud rate)",
    "a servo powered up with its signal line low starts in PWM mode: set its PWMINH flag and power-cycle",
)


def lost_port_hints(port: str) -> list[str]:
    """What to look at when ``port`` went away: the USB adapter, but not for the built-in simulator (its error says
    it was unplugged) nor for a pty (``ics35 sim``'s, a bridge's: no adapter behind it)."""
    from ..diagnose.system import is_pseudo_terminal

    if url_scheme(port) == "sim":
        return []
    # (a link outside /dev that is gone: `ics35 sim` and socat remove theirs as they stop; an adapter's name is
    # under /dev, and Windows names ports, COM3, that are no paths)
    gone_link = (
        sys.platform != "win32" and not is_url(port) and not port.startswith("/dev/") and not os.path.lexists(port)
    )
    if is_pseudo_terminal(port) or gone_link:
        return ["a pseudo-terminal: is the simulator or bridge that served it (ics35 sim, socat) still running?"]
    return ["is the USB adapter still plugged in?"]


def translate(settings: Settings, exc: errors.IcsError) -> CliError:
    """The person-facing form of a library error."""
    text = settings.as_given(errors.error_text(exc))
    if isinstance(exc, errors.PortPermissionDenied):
        if sys.platform.startswith("linux"):
            # The port's own group: dialout on Debian, Ubuntu and Fedora, uucp on Arch and others.
            group = port_group(settings.port) or "dialout"
            return CliError(
                ExitCode.PORT,
                text,
                f"on Linux: sudo usermod -aG {group} $USER, then log out and in again (check with: groups)",
            )
        return CliError(ExitCode.PORT, text, permission_hint())
    if isinstance(exc, errors.PortNotFound):
        # The library's message already says where to look, or what a misnamed port meant (sim:/x, ttyUSB0), or
        # that the port was a simulator's (no adapter to look for), for callers who see no hints.
        told = port_names_hint() in text or misnamed_port_hints(settings.port) or "ics35 sim" in text
        return CliError(ExitCode.PORT, text, *([] if told else [f"list ports with: {port_names_hint()}"]))
    if isinstance(exc, errors.PortBusy):
        # (the library's text names the program where it can; doctor's advice for it, as doctor gives it)
        fixes = [f.fix for f in check_holders(Path("/"), settings.port, own_pid=os.getpid()) if f.fix]
        return CliError(
            ExitCode.PORT, text, *(fixes or ["close the other program (another ics35, a serial monitor, ModemManager)"])
        )
    if isinstance(exc, errors.DirectionControlNotSupported):
        return CliError(
            ExitCode.PORT,
            text,
            "an ICS adapter switches direction itself: drop --direction",
            "a DIY interface on a UART without RS-485 mode: use a transceiver with automatic direction control",
        )
    if isinstance(exc, errors.SerialPortError):
        return CliError(ExitCode.PORT, text, *bridge_hints(settings))
    if isinstance(exc, errors.PortLost | errors.ClosedByPortLoss):
        if is_network_link(settings.port):
            return CliError(ExitCode.PORT, text, *bridge_hints(settings))
        return CliError(ExitCode.COMMUNICATION, text, *lost_port_hints(settings.port))
    if isinstance(exc, errors.BusClosed):
        return CliError(ExitCode.COMMUNICATION, text)
    if isinstance(exc, errors.UnsafeOperation):
        return CliError(ExitCode.REFUSED, f"refused: {text}")
    if isinstance(exc, errors.InvalidArgument):
        if is_url(settings.port) and "cannot open" in text:
            return CliError(
                ExitCode.PORT, text, f"ports are serial devices ({example_port()}), pyserial URLs or sim://"
            )
        return CliError(ExitCode.USAGE, f"{text} (nothing was written)")  # (some come after reads: not "sent")
    if isinstance(exc, errors.ReplyError) and echo_setting_wrong(exc, settings.echo):
        if settings.echo:
            return CliError(
                ExitCode.COMMUNICATION,
                f"{text}: the first byte back is a servo's reply, not the echo of the command sent",
                "this interface does not loop TX back to RX: pass --no-echo",
            )
        return CliError(
            ExitCode.COMMUNICATION,
            f"{text}: the bytes sent came back before the reply (an echo)",
            "this interface echoes what it sends (ICS adapters do): drop --no-echo",
        )
    if isinstance(exc, errors.EchoMismatch) and exc.echo_behind:
        return CliError(
            ExitCode.COMMUNICATION,
            text,
            "a reply came after its allowance and landed in front of the next command's echo: a slow servo "
            "or link (a TCP bridge can hold a reply's tail); raise --timeout",
        )
    if isinstance(exc, errors.EchoMismatch):
        return CliError(
            ExitCode.COMMUNICATION,
            text,
            "the bytes sent came back changed: two servos answering at once (duplicate ID), noise, or loose wiring",
            "if your interface does not loop TX back to RX, pass --no-echo",
        )
    if isinstance(exc, errors.ReplyError) and id0_top_bit_differs(exc, settings.baud):
        return CliError(
            ExitCode.COMMUNICATION,
            f"{text}: only the top bit differs",
            "an ICS 3.5 servo answers a position command to ID 0 with the reply's top bit set at 115200 baud "
            "(ICS 2.0 compatibility) and clear at 625000 and 1250000; this device does the other: give it an ID "
            "other than 0 (ics35 set-id), where the rule does not apply",
        )
    if isinstance(exc, (errors.BadReply, errors.PartialReply)):
        return CliError(
            ExitCode.COMMUNICATION,
            text,
            f"a garbled reply: a wrong baud rate (try: {settings.command_line('scan')}), two servos sharing one ID, "
            "or noise on the line",
        )
    if isinstance(exc, errors.VerifyError):
        return CliError(ExitCode.COMMUNICATION, text, "the servo may not hold what was written; check its power")
    return CliError(ExitCode.COMMUNICATION, text)


def is_network_link(port: str) -> bool:
    """Whether ``port`` is a line on another machine (a TCP bridge or RFC 2217 server)."""
    return url_scheme(port) in ("socket", "rfc2217")


def bridge_hints(settings: Settings) -> tuple[str, ...]:
    """What to check when the connection to a bridge is refused or dropped (none for local ports)."""
    if not is_network_link(settings.port):
        return ()
    return (
        "is the bridge (ser2net, socat, an RFC 2217 server) running and listening there, "
        "and is the serial port on that machine free (one client at a time)?",
    )


def link_hints(settings: Settings) -> tuple[str, ...]:
    """What to check on a link that does not carry the baud rate and parity (none for other ports)."""
    if carries_line_settings(settings.port):
        return ()
    return (
        f"{settings.port} does not carry the baud rate or parity: set the bridge's serial side to "
        f"{settings.baud} baud, 8 data bits, EVEN parity, 1 stop bit (or use rfc2217://)",
    )


def _opener(settings: Settings) -> Callable[[int], Bus]:
    """How the diagnoses below open the line at a rate (``open_at(baud)``, as the policies take it): as the
    command's line, at that rate (each request the diagnoses send names its own retries)."""

    def open_at(baud: int) -> Bus:
        return settings.bus(baud)

    return open_at


def trying_rates(settings: Settings) -> Callable[[int], None]:
    """A search of the other rates' progress (its ``on_rate``), for a person watching: where nothing answers,
    each rate costs a whole --timeout (raised for a slow link, the search must keep it: see policies.scan)."""

    from ..policies import trying_rate

    told: list[int] = []

    def tell(baud: int) -> None:
        if err.is_terminal:
            say(trying_rate(settings.baud, baud, told[-1] if told else None))
        told.append(baud)

    return tell


def _rate_elsewhere(
    settings: Settings,
    search: Callable[[Callable[[int], Bus], list[int], Callable[[int], None]], Awaitable[tuple[int, ...]]],
) -> int | None:
    """The first of the line's other rates ``search(open_at, rates, on_rate)`` (a policy) finds, or None: also
    when the port cannot be opened again (advice only: what was said stands)."""
    from ..policies import other_bauds

    try:
        found = run_loop(lambda: search(_opener(settings), other_bauds([settings.baud]), trying_rates(settings)))
    except (errors.IcsError, OSError):
        return None
    return found[0] if found else None


def no_reply_error(settings: Settings, exc: errors.ReplyTimeout) -> CliError:
    """No answer: why (policies.why_no_reply: the adapter, a long reply lost, another baud rate), else what
    to check."""
    from ..policies import NoReplyCause, why_no_reply

    finding = run_loop(
        lambda: why_no_reply(exc, _opener(settings), settings.baud, echo=settings.echo, on_rate=trying_rates(settings))
    )
    if finding.cause is NoReplyCause.NO_ECHO:
        # Not even our own echo came back: the adapter or its wiring, not the servo.
        return CliError(
            ExitCode.NO_REPLY,
            f"no echo and no reply from {settings.port}: the bytes sent never came back",
            *link_hints(settings),
            "check the adapter is an ICS adapter (TX looped back to RX) and the cable is plugged in",
            "if your interface does not echo what it sends, pass --no-echo",
        )
    if finding.cause is NoReplyCause.LONG_REPLY_LOST:
        return CliError(
            ExitCode.NO_REPLY,
            f"servo {exc.servo_id} answers short reads on {settings.port} at {settings.baud} baud, "
            "but not the EEPROM read",
            "its reply is the longest on the line (66 bytes): an adapter or bridge that drops or holds back long "
            "replies loses it; raise --timeout, and see what ics35 doctor measures on this line",
            "a device that is not an ICS 3.5 servo (another firmware, a board) may not answer the EEPROM read",
        )
    if finding.cause is NoReplyCause.OTHER_RATE:
        return CliError(
            ExitCode.WRONG_BAUD,
            f"servo {exc.servo_id} does not answer at {settings.baud} baud, but does at {finding.rates[0]} baud",
            f"pass --baud {finding.rates[0]}",
        )
    # An ID command names no servo: whatever is on the line may answer it.
    what = f"servo {exc.servo_id} did not answer" if exc.servo_id is not None else "nothing answered the ID command"
    # Where the other rates were asked too (each said as it was tried), the error names them: the line's rate
    # alone read as if they had not been.
    elsewhere = finding.nothing_elsewhere()
    # A rate the search could not ask (the port lost as it was asked there) is said apart: not one it is silent at.
    untried = finding.not_searched_in_words()
    return CliError(
        ExitCode.NO_REPLY,
        f"{what} on {settings.port} at {settings.baud} baud"
        + (f", {elsewhere}" if elsewhere else "")
        + (f" ({untried})" if untried else ""),
        *link_hints(settings),
        *NO_REPLY_HINTS,
    )


def none_of_them_answered(settings: Settings, ids: Sequence[int]) -> CliError:
    """The error for a command that asked servos ``ids`` over and over (a stream) and none ever answered: the
    rate the first of them answers at when it is another (its EEPROM agreeing: see policies.servo_rates), as
    the one-shot commands say it, else what to check."""
    from ..policies import servo_rates

    rate = _rate_elsewhere(
        settings, lambda open_at, others, on_rate: servo_rates(open_at, ids[0], others, on_rate=on_rate)
    )
    if rate is not None:
        return _at_another_rate(settings, ids, rate)
    return CliError(ExitCode.NO_REPLY, f"{no_servo_among(ids)} answered", *NO_REPLY_HINTS)


async def at_another_rate(settings: Settings, bus: Bus, ids: Sequence[int]) -> CliError | None:
    """Where none of ``ids`` answered as a live view asked them: the error naming the rate the first of them
    answers at when it is another (a wrong --baud, said at once rather than after a view of "off" rows), else
    None (they may be powering up: the view starts, and takes them in as they answer).  ``bus`` is reopened at
    the other rates for the search, and left at its own."""
    from ..policies import other_bauds, reopening, servo_rates

    if not carries_line_settings(settings.port):  # (a link blind to the rate: every rate is the far end's one)
        return None
    found: tuple[int, ...] = ()
    try:
        with contextlib.suppress(errors.ReplyError):  # (advice only: a search that fails leaves the view to run)
            others = other_bauds([settings.baud])
            found = await servo_rates(reopening(bus), ids[0], others, on_rate=trying_rates(settings))
    finally:
        if int(bus.baudrate) != settings.baud:
            await bus.reopen(baudrate=settings.baud)
    return _at_another_rate(settings, ids, found[0]) if found else None


def _at_another_rate(settings: Settings, ids: Sequence[int], rate: int) -> CliError:
    none = no_servo_among(ids)  # (32 IDs in one short line: 0-31)
    return CliError(
        ExitCode.WRONG_BAUD,
        f"{none} answered at {settings.baud} baud, but servo {ids[0]} does at {rate} baud",
        f"pass --baud {rate}",
    )


def answered_at_another_id(
    settings: Settings,
    ids: Sequence[int],
    where: str,
    at_id: int | None = None,
    rate: str = "",
    *,
    several: bool = False,
) -> CliError:
    """The error for IDs none of which answered on a line where a device at another ID does (an ID read: ``at_id``,
    its ID where one device gave it; ``several``: devices answered it at once; ``rate``: " at N baud" where several
    rates were asked): the line, its rate and its power are right, the IDs asked are not."""
    asked = f"{no_servo_among(ids)} answered on {where}"
    if at_id is None:
        others = "servos at other IDs answer" if several else "a servo at another ID does"
        return CliError(
            ExitCode.NO_REPLY,
            f"{asked}, but {others}{rate}",
            f"{settings.command_line('scan')} lists the IDs on the line; pass those to --ids",
        )
    return CliError(
        ExitCode.NO_REPLY,
        f"{asked}, but a servo at ID {at_id} does{rate}",
        f"ask for it at its ID: {settings.command_line('scan', '--ids', str(at_id))}",
    )


def nothing_answered(settings: Settings, where: str, *, silent: bool) -> CliError:
    """The error for a line where no servo answered; ``silent``: not a single byte came back."""
    if silent and settings.echo:
        return CliError(
            ExitCode.NO_REPLY,
            f"nothing came back from {where}, not even the echo of the bytes sent",
            *link_hints(settings),
            "check the adapter is an ICS adapter (TX looped back to RX) and the cable is plugged in",
            "if your interface does not echo what it sends, pass --no-echo",
        )
    return CliError(ExitCode.NO_REPLY, f"no servo answered on {where}", *link_hints(settings), *NO_REPLY_HINTS)


class NobodyAnswered(CliError):
    """No servo answered at the line's rate where a command asked every ID (``all``, or a look for servos) or
    several: the command line's runner (``_runner.run``), once the line is closed, looks for the rate a device
    answers at (:func:`nobody_at_this_rate`); until then, and where none is found, :func:`nothing_answered`'s
    words."""

    def __init__(self, settings: Settings, where: str, *, silent: bool) -> None:
        said = nothing_answered(settings, where, silent=silent)
        super().__init__(said.code, said.message, *said.hints)
        self.where = where
        self.silent = silent


def nobody_at_this_rate(settings: Settings, nobody: NobodyAnswered) -> CliError:
    """``nobody``, or the rate a device answers the ID read at when it is another (policies.device_rates, as
    set-id names it): servos set to 1.25 Mbit/s on a line opened at the default 115200 are no power fault."""
    from ..policies import device_rates

    if nobody.silent and settings.echo:
        return nobody  # not even the echo came back: the adapter or its wiring, which no rate mends
    rate = _rate_elsewhere(settings, lambda open_at, others, on_rate: device_rates(open_at, others, on_rate=on_rate))
    if rate is None:
        return nobody
    return CliError(
        ExitCode.WRONG_BAUD,
        f"no servo answered on {nobody.where}, but a device does at {rate} baud",
        f"pass --baud {rate}",
    )


def answered_garbled(settings: Settings, where: str, garbled: list[tuple[int, int]]) -> CliError:
    """The error for a line where no servo answered cleanly but some did garbled (``(baud, ID)`` pairs): two
    servos sharing an ID, most often new ones (all ID 0), not the unpowered line :func:`nothing_answered` is."""
    baud, servo_id = garbled[0]
    which = ", ".join(f"ID {i} at {b}" for b, i in garbled)
    rate = [] if baud == settings.baud else ["--baud", str(baud)]
    return CliError(
        ExitCode.NO_REPLY,
        f"no servo answered cleanly on {where}: {which} answered garbled",
        f"two servos sharing ID {servo_id} answer at once (new servos all have ID 0): connect one at a time and "
        f"give each its own ID with: {settings.command_line('set-id', 'NEW', *rate)}",
        "otherwise: noise or a loose contact on the signal wire",
    )
