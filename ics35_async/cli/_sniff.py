"""sniff: decode a line this adapter only listens to (library: protocol.listening); it never sends a byte."""

from __future__ import annotations

import json
import select
import sys
import time
from pathlib import Path
from typing import IO

import click
from rich.markup import escape

from ..errors import IcsError
from ..protocol.listening import DEFAULT_GAP, HeardTransaction, LineListener
from ..transports.serial_port import open_serial, posix_fd
from ._common import CliError, ExitCode, check_output_path, out, seconds_option, settings_of, translate
from ._console import say, say_labelled
from ._numbers import Number, WholeNumber
from ._settings import Settings

POLL = 0.05  # seconds between looks at the clock while the line is silent


def text_line(h: HeardTransaction) -> str:
    return "  ".join(text_parts(h))


def text_parts(h: HeardTransaction) -> tuple[str, str]:
    """A transaction's text line in two: its time, and what was heard then."""
    who = f"id {h.servo_id:>2}" if h.servo_id is not None else "     "
    if h.error is None:
        value = h.value_json()
        if isinstance(value, dict):  # an EEPROM image: the fields one looks for first
            shown = f"= EEPROM id {value['servo_id']}, {value['baud_rate']} baud, stretch {value['stretch_gain']}"
        else:
            shown = f"= {value}"
    else:
        shown = f"! {h.error}"
    sent = h.sent.hex(" ")
    reply = h.reply.hex(" ") if h.reply else "-"
    return f"{h.t:11.6f}", f"{who}  {h.kind:<24} {shown:<28} {sent} | {reply}"


class HeardOutput:
    """Each transaction, as it is decoded, to the screen and to the file (flushed: Ctrl-C or a lost port loses none)."""

    def __init__(self, as_json: bool, file: IO[str] | None, limit: int | None = None) -> None:
        self.as_json = as_json
        self.file = file
        self.limit = limit  # --count: one read can decode several transactions, and the end's flush one more
        self.count = 0
        self.unknown = 0

    @property
    def full(self) -> bool:
        return self.limit is not None and self.count >= self.limit

    def write(self, heard: list[HeardTransaction]) -> None:
        for h in heard:
            if self.full:
                return
            self.count += 1
            self.unknown += h.kind == "unknown"
            line = json.dumps(h.to_dict()) if self.as_json else text_line(h)
            if self.as_json:
                sys.stdout.write(line + "\n")
                sys.stdout.flush()
            else:
                # On a terminal, wrapped at words with its further lines under the transaction, past its time (the
                # label: the second space after it is said_labelled's own, the line as text_line's into a log).
                at, heard_then = text_parts(h)
                style = "[yellow]" if h.error else ""
                say_labelled(f"{style}{escape(at)}", f"{style} {escape(heard_then)}", to=out)
            if self.file is not None:
                self.file.write(line + "\n")
                self.file.flush()


def listen(settings: Settings, listener: LineListener, output: HeardOutput, duration: float | None) -> str:
    """Read until Ctrl-C, ``duration`` or the output's limit; returns why it stopped."""
    try:
        ser = open_serial(settings.port, settings.baud, low_latency=True)
    except IcsError as exc:
        raise translate(settings, exc) from None
    fd = posix_fd(ser)
    say(f"[dim]listening on {escape(settings.port)} at {settings.baud} baud; Ctrl-C stops[/dim]")
    start = time.monotonic()
    try:
        while True:
            now = time.monotonic() - start
            if duration is not None and now >= duration:
                return "time is up"
            if output.full:
                return "count reached"
            if fd is not None:
                select.select([fd], [], [], POLL)
            try:
                data = ser.read(4096)
            except Exception as exc:  # the adapter went away (pyserial's SerialException, an OSError)
                raise CliError(
                    ExitCode.COMMUNICATION,
                    f"{settings.port} was lost while listening: {exc}",
                    "is the USB adapter still plugged in? (everything decoded so far was written)",
                ) from None
            now = time.monotonic() - start
            if data:
                output.write(listener.feed(data, now))
            else:
                if fd is None:
                    time.sleep(0.001)
                output.write(listener.poll(now))
    except KeyboardInterrupt:
        return "interrupted"
    finally:
        output.write(listener.flush())
        ser.close()


@click.command()
@click.option("--output", "-o", "output_path", default=None, help="Also write every line to this file.")
@seconds_option("--duration", "Stop after this long.", low=0, above_low=True)
@click.option("--count", type=WholeNumber(min=1), default=None, help="Stop after this many transactions.")
@click.option(
    "--gap",
    type=Number(min=0, min_open=True),
    default=DEFAULT_GAP * 1e3,
    show_default=True,
    help="Silence (ms) after which a reply is no longer expected.",
)
@click.option(
    "--json", "as_json", is_flag=True, help="One JSON object a line (t, kind, id, sent, reply, value, error)."
)
@click.pass_context
def sniff(
    ctx: click.Context, output_path: str | None, duration: float | None, count: int | None, gap: float, as_json: bool
) -> int:
    """Decode a line this port only listens to: one line per transaction (time, ID, kind, value, bytes).

    For a line another controller drives (an RCB-4 board, an Arduino, an ESP32): wire a second
    adapter's receive pin to the signal line; it sends nothing.  Set --baud to the line's rate, and
    the adapter's latency timer to 1 ms (gaps between bytes help the decoding).  Ctrl-C stops it.
    """
    settings = settings_of(ctx)
    if settings.port_defaulted or settings.is_sim:
        raise CliError(
            ExitCode.USAGE,
            "sniff listens on a serial port: give the listening adapter's --port (nothing was opened)",
            "to try it: ics35 sim --tap /tmp/ics35-tap, then ics35 sniff --port /tmp/ics35-tap",
        )
    file = None
    if output_path is not None:
        file = check_output_path(output_path, "--output").open("w", encoding="utf-8")
    output = HeardOutput(as_json, file, limit=count)
    try:
        why = listen(settings, LineListener(settings.baud, gap=gap * 1e-3), output, duration)
    finally:
        if file is not None:
            file.close()
    saved = f", written to {Path(output_path)}" if output_path else ""
    heard = f"{output.count} transaction{'' if output.count == 1 else 's'}"
    say(f"[dim]{why}: {heard} heard ({output.unknown} unknown){escape(saved)}[/dim]")
    return 0


COMMANDS = [sniff]
