"""The pty server's command line: ``python -m ics35_async.sim`` and ``ics35 sim``.

Prints the device path on its first line, then serves until SIGINT or
SIGTERM (see :mod:`.pty_server`); with ``--console`` it also takes commands on stdin
(:mod:`.console`) until ``quit`` or the end of input.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import time
from collections.abc import Callable, Sequence
from types import FrameType
from typing import Any

from ..eeprom import BaudRate
from ..errors import InvalidArgument, error_text
from ..terminal import clear_echoed_ctrl_c, fitted_lines, in_background_of_terminal
from ..units import parse_ids
from .adapter import ADAPTER_KINDS, DEFAULT_LATENCY_TIMER_MS, make_adapter
from .console import PROMPT, ConsoleReader, LineConsole
from .faults import FaultConfig
from .model import DEFAULT_EEPROM_WRITE_DELAY, DEFAULT_TAIL_BYTES, DEFAULT_TAIL_DELAY, DEFAULT_TURNAROUND
from .pty_port import LinkFolderGone
from .pty_server import PtyServer
from .record import ReplayDevice
from .tap import LineTap
from .url import parse_line_ids, parse_seconds
from .virtual_line import DEFAULT_REPLUG_AFTER, VirtualLine


def to_stderr(text: str) -> None:
    """A line of the simulator's own on stderr, wrapped at words on a terminal (see terminal.fitted_lines)."""
    print(fitted_lines(text, sys.stderr), file=sys.stderr, flush=True)


def build_parser(
    prog: str = "python -m ics35_async.sim", parser_class: type[argparse.ArgumentParser] = argparse.ArgumentParser
) -> argparse.ArgumentParser:
    """The options; ``parser_class``: ``ics35 sim`` tells its usage errors as its other commands do."""
    parser = parser_class(
        prog=prog,
        description="Serve a simulated ICS 3.5 servo line on a pseudo-terminal. "
        "Prints the device path on the first line, then serves until SIGINT/SIGTERM. "
        "Runs in real time (wire timing) by default: replies take the modelled wire time "
        "and servos keep moving between commands, as other programs expect of a serial port; "
        "--fast answers at once and moves time only with each command's wire time.",
    )
    parser.set_defaults(realtime=True)
    parser.add_argument("--ids", default="0-31", help="servo IDs, e.g. 0-31 or 1,3,5-7 ('none': no servos)")
    parser.add_argument(
        "--ics36",
        default=None,
        metavar="IDS",
        help="IDs of servos that speak ICS 3.6 (answer its position read), among --ids; default: none",
    )
    parser.add_argument(
        "--noisy",
        default=None,
        metavar="IDS",
        help="IDs of servos whose reported position jumps up to 135 degrees either side of where they are at each "
        "reply, no two of 25 in a row agreeing (a broken potentiometer), among --ids; default: none",
    )
    parser.add_argument("--baud", type=int, default=115200, help="servos' baud rate (115200, 625000, 1250000)")
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument(
        "--fast",
        dest="realtime",
        action="store_false",
        help="fast mode: answer at once; the line's clock advances only by each command's wire time",
    )
    mode.add_argument(
        "--realtime",
        dest="realtime",
        action="store_true",
        help="real time: deliver at the modelled wire times (the default)",
    )
    parser.add_argument("--faults", default=None, help="fault spec, e.g. drop:0.01,late@3:0.1 (see sim.faults)")
    parser.add_argument("--seed", type=int, default=0, help="fault random seed")
    parser.add_argument("--no-echo", action="store_true", help="do not echo the client's bytes")
    parser.add_argument("--turnaround", default=None, help=f"servo turnaround (default {DEFAULT_TURNAROUND * 1e6:g}us)")
    parser.add_argument(
        "--eeprom-delay",
        default=None,
        help=f"extra EEPROM-write delay (default {DEFAULT_EEPROM_WRITE_DELAY * 1e3:g}ms)",
    )
    parser.add_argument(
        "--late-delay", default=None, help="late replies arrive this long after (default: next command)"
    )
    parser.add_argument(
        "--tail-bytes",
        type=int,
        default=None,
        help=f"bytes the 'tail' fault holds back at the end of a reply (default {DEFAULT_TAIL_BYTES})",
    )
    parser.add_argument(
        "--tail-delay",
        default=None,
        help=f"how long the 'tail' fault holds them (default {DEFAULT_TAIL_DELAY * 1e3:g}ms)",
    )
    parser.add_argument("--memory", default=None, help="IDs of generic 128-byte memory devices")
    parser.add_argument("--unplug-after", default=None, help="unplug the port this many seconds after start")
    parser.add_argument(
        "--replug-after", default=None, help=f"plug it back in this long after (default {DEFAULT_REPLUG_AFTER:g}s)"
    )
    parser.add_argument(
        "--adapter",
        choices=ADAPTER_KINDS,
        default=None,
        help="put a USB adapter model between the line and the client: ftdi (62-byte packets, latency timer, "
        "1 ms USB frames), as Kondo's ICS USB adapters are; needs real time",
    )
    parser.add_argument(
        "--latency-timer",
        type=int,
        default=None,
        metavar="MS",
        help=f"the adapter model's latency timer in ms, 1..255 (default {DEFAULT_LATENCY_TIMER_MS})",
    )
    parser.add_argument(
        "--tap",
        default=None,
        metavar="PATH",
        help="also serve the line's bytes, each once, on a second pty at PATH (a listening adapter, for ics35 sniff)",
    )
    parser.add_argument("--record", default=None, help="record the session to this file")
    parser.add_argument("--replay", default=None, help="serve this recording instead of a simulated line")
    parser.add_argument(
        "--link",
        default=None,
        help="path of the symlink to create, with its lock PATH.lock beside it (default: in a temp dir)",
    )
    parser.add_argument(
        "--fixed-baud", action="store_true", help="ignore the client's baud rate; the line runs at --baud"
    )
    parser.add_argument(
        "--console",
        action="store_true",
        help="read commands from stdin while serving, one a line, each answered on stdout: plug ID [BAUD] [ics36] "
        "(a new factory servo), unplug ID, replug [ID], power [ID] (power-cycle), turn ID POSITION (by hand, in "
        "counts), list, help, quit "
        "(stops the simulator, as end of input does); not for a simulator started in the background",
    )
    parser.add_argument(
        "--last",
        type=int,
        default=0,
        metavar="N",
        help="on exit, list the last N reads and writes on the pty with their times (time.monotonic)",
    )
    return parser


def build_device(args: argparse.Namespace) -> VirtualLine | ReplayDevice:
    if args.replay is not None:  # (an empty one, a script's unset variable, is refused, not taken for none)
        return ReplayDevice(args.replay)
    ids = option_ids(args.ids, "--ids", parse_line_ids)
    replug_after = parse_seconds(args.replug_after, "--replug-after") if args.replug_after else DEFAULT_REPLUG_AFTER
    options: dict[str, Any] = {}
    if args.turnaround is not None:
        options["turnaround"] = parse_seconds(args.turnaround, "--turnaround")
    if args.eeprom_delay is not None:
        options["eeprom_write_delay"] = parse_seconds(args.eeprom_delay, "--eeprom-delay")
    if args.late_delay is not None:
        options["late_delay"] = parse_seconds(args.late_delay, "--late-delay")
    if args.tail_bytes is not None:
        options["tail_bytes"] = args.tail_bytes
    if args.tail_delay is not None:
        options["tail_delay"] = parse_seconds(args.tail_delay, "--tail-delay")
    adapter = make_adapter(args.adapter, args.latency_timer)
    if adapter is not None and not args.realtime:
        raise InvalidArgument("--adapter models the time the client waits: it cannot be used with --fast")
    bus = VirtualLine(
        ids,
        baudrate=BaudRate.parse(args.baud),
        memory={i: b"" for i in option_ids(args.memory, "--memory")} if args.memory else None,
        realtime=args.realtime,
        echo=not args.no_echo,
        faults=FaultConfig.parse(args.faults),
        seed=args.seed,
        follow_host_baud=not args.fixed_baud,
        replug_after=replug_after,
        record=args.record,
        adapter=adapter,
        ics36=option_ids(args.ics36, "--ics36"),
        noisy=option_ids(args.noisy, "--noisy"),
        **options,
    )
    return bus


def option_ids(text: str | None, option: str, parse: Callable[[str], list[int]] = parse_ids) -> list[int]:
    """``parse(text)``, the IDs given to ``option`` (none when it is not given); an error naming the option and
    the value as written (an empty one quoted, or it would not show)."""
    if text is None:
        return []
    try:
        return parse(text)
    except InvalidArgument as exc:
        raise InvalidArgument(f"{option} {text if text.strip() else repr(text)}: {exc}") from None


def say_unplugs(device: VirtualLine, started: float, say: Callable[[str], None]) -> None:
    """``say`` a line each time the port goes (``--unplug-after``, an ``unplug`` fault) and when it comes back: a
    person watching the simulator's terminal tells its doing from their own program's fault."""

    def said(plugged: bool) -> None:
        # (only an unplug that comes back by itself: the console's unplug port says so in its answer)
        if not plugged and device.replug_pending:
            say(
                f"ics35 sim: the port was unplugged ({time.monotonic() - started:.1f} s after the start): it comes "
                f"back in {device.replug_after:g} s, at the same path"
            )

    device.add_listener(said)


def main(
    argv: Sequence[str] | None = None,
    *,
    prog: str = "python -m ics35_async.sim",
    parser_class: type[argparse.ArgumentParser] = argparse.ArgumentParser,
) -> int:
    """Entry point of ``python -m ics35_async.sim`` (and ``ics35 sim``); returns the exit status.  Every usage
    error goes through ``parser_class``'s ``error`` (argparse's: the usage, the message, exit 2)."""
    parser = build_parser(prog, parser_class)
    args = parser.parse_args(argv)
    if args.console and in_background_of_terminal(0):
        parser.error(
            "--console reads the terminal, but this simulator runs in its background (as with &): the first line "
            "typed would stop it, and the pty with it; run it in the foreground, or without --console"
        )
    started = time.monotonic()  # (what --unplug-after counts from)
    try:
        device = build_device(args)
        unplug_after = None if args.unplug_after is None else parse_seconds(args.unplug_after, "--unplug-after")
    except InvalidArgument as exc:
        parser.error(str(exc))
    except OSError as exc:  # (only the --replay or --record file is opened here: named with its option)
        option = "--replay" if args.replay is not None else "--record"
        path = args.replay if args.replay is not None else args.record
        parser.error(f"{option} {path}: {exc.strerror or error_text(exc)}")
    console: ConsoleReader | None = None

    def note(text: str) -> None:
        """A line of the simulator's own on stderr, from any thread: with the console's prompt kept last."""
        if console is None:
            to_stderr(text)
        else:
            console.aside(lambda: to_stderr(text))

    if isinstance(device, VirtualLine):
        say_unplugs(device, started, note)
        if unplug_after is not None:  # (scheduled once it will be said, however soon it comes)
            device.schedule_unplug(unplug_after, device.replug_after)
    if args.tap is not None and not isinstance(device, VirtualLine):
        parser.error("--tap needs a simulated line, not --replay")
    if args.console and not isinstance(device, VirtualLine):
        parser.error("--console needs a simulated line, not --replay")
    # The tap first: a bad --tap then leaves no server's private directory behind.
    try:
        # (`is not None`: an empty --tap, a script's unset variable, is refused, not taken for no tap)
        tap = LineTap(device, args.tap) if args.tap is not None and isinstance(device, VirtualLine) else None
    except (InvalidArgument, OSError) as exc:
        parser.error(f"--tap: {error_text(exc)}")
    try:
        server = PtyServer(device, link=args.link, follow_host_baud=not args.fixed_baud, keep_last=max(0, args.last))
    except (InvalidArgument, OSError) as exc:
        if tap is not None:
            tap.close()
        parser.error(f"--link: {error_text(exc)}")

    stopped_by: list[int] = []

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stopped_by.append(signum)
        server.stop()

    # (a server: stopped by any of them, it ends as asked, exit 0; one it was started ignoring stays ignored,
    # as with every ics35 command: `nohup ics35 sim ... &` outlives its terminal)
    stops = [
        sig
        for sig in (getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))
        if signal.getsignal(sig) is not signal.SIG_IGN
    ]
    previous = {sig: signal.signal(sig, on_signal) for sig in stops}
    code = 0
    try:
        path = server.open()
        print(path, flush=True)
        if isinstance(device, ReplayDevice):
            what = f"replaying {len(device.entries)} transactions"
        else:
            count = len(device.servos)
            what = f"{count} servo{'s' if count != 1 else ''} at {device.baudrate} bit/s, "
            what += "real-time" if device.realtime else "fast"
        if isinstance(device, VirtualLine) and device.adapter is not None:
            what += f", behind a USB adapter model ({device.adapter.latency_timer_ms} ms latency timer)"
        # (the link first: a program given the pty itself loses the line for good at a replug, which makes a new one)
        to_stderr(f"ics35 sim: {what} on {path} (a link to {server.pts_name}, which a replug renames: open the link)")
        if tap is not None:
            to_stderr(f"ics35 sim: the line's bytes, each once, on {tap.path} (ics35 sniff --port {tap.path})")
        if args.console and isinstance(device, VirtualLine):
            commands = LineConsole(device, args.baud, str(path))

            def on_end() -> None:
                if not commands.quit:  # (quit said so on stdout already)
                    to_stderr("ics35 sim: console: end of input: the simulator stops")
                server.stop()

            # A prompt only for a person typing on the terminal the answers go to, as Python's input() has it:
            # never in the answers a program reads (stdout a pipe or a file: through `| cat` they would also come
            # after the prompt that should follow them).
            prompting = os.isatty(0) and sys.stdout.isatty()
            console = ConsoleReader(
                commands, on_end, out=sys.stdout, prompt=PROMPT, prompt_out=sys.stdout if prompting else None
            )
            to_stderr("ics35 sim: console: type help for its commands, quit to stop")
            console.start()
        server.serve()
    except LinkFolderGone as exc:
        note(f"ics35 sim: {exc}; the simulator stops")
        code = 1
    finally:
        if console is not None:
            console.close()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        server.close()
        if tap is not None:
            tap.close()
        if signal.SIGINT in stopped_by:
            clear_echoed_ctrl_c()  # (the last words start a line of their own, as the ics35 commands' do)
        if isinstance(device, VirtualLine):
            device.close()
            dropped, served = server.dropped_bytes, device.transactions
            lost = f"; {dropped} byte{'s' if dropped != 1 else ''} no client took" if dropped else ""
            counted = f"{served} transaction{'s' if served != 1 else ''}"
            to_stderr(f"ics35 sim: served {counted}{lost}")
        for when, what, data in server.last:
            to_stderr(f"ics35 sim: at {when:.6f} {what:5} {data.hex(' ')}")
    return code
