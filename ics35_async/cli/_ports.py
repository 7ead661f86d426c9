"""ports: the serial ports this machine has, Kondo adapters marked, and how to make a missing one appear."""

from __future__ import annotations

import sys

import click
from rich import box
from rich.markup import escape
from rich.table import Table

from ..diagnose.system import missing_adapter_notes
from ..transports import adapter_advice
from ..transports.listing import SerialPortInfo, adapter_name, kondo_usb_without_port, list_serial_ports
from ..transports.platforms import latency_timer_advice, port_names_hint
from ._common import CliError, ExitCode, emit_json, json_option, out, settings_of
from ._console import say_labelled


def ports_table(found: list[SerialPortInfo]) -> Table:
    table = Table(box=box.SIMPLE_HEAD, pad_edge=False, collapse_padding=True)
    for name in ("port", "description", "USB ID", ""):
        table.add_column(name)
    for p in found:
        table.add_row(
            escape(p.device),
            escape(p.description or "-"),
            p.usb_id or "-",
            f"[bold green]Kondo adapter{escape(f' ({adapter_name(p.usb_id)})' if adapter_name(p.usb_id) else '')}"
            "[/bold green]"
            if p.kondo
            else "",
        )
    return table


def notes(found: list[SerialPortInfo], unbound: list[str], port: str | None = None) -> list[str]:
    """What to do next: a Kondo adapter missing (as doctor says it), or an FTDI latency timer to set; with
    ``port`` (--port or ICS35_PORT) a pseudo-terminal, what it is instead of a missing adapter."""
    said = missing_adapter_notes(found, unbound, linux=sys.platform.startswith("linux"), port=port)
    for p in found:
        if not p.ftdi_based:
            continue
        if sys.platform.startswith("linux"):
            said.extend(adapter_advice(p.device))  # reads the timer itself: only when it is too long
        else:
            said.append(f"{p.device}: set the adapter's latency timer to 1 ms: {latency_timer_advice()}")
    return said


@click.command()
@json_option
@click.pass_context
def ports(ctx: click.Context, as_json: bool) -> int:
    """List serial ports with their USB IDs, marking Kondo adapters (USB vendor 165C).

    Exit code 3 when there is no serial port at all.  On Linux, an ICS USB
    adapter HS that gets no port needs the ftdi_sio driver told its USB ID
    (the command is printed; untested without the hardware).
    """
    try:
        found = list_serial_ports()
    except Exception as exc:  # pyserial's platform backend failed: say so, no traceback
        raise CliError(ExitCode.PORT, f"cannot list serial ports: {exc}") from None
    unbound = kondo_usb_without_port()
    settings = settings_of(ctx)
    said = notes(found, unbound, None if settings.port_defaulted else settings.port)
    if as_json:
        emit_json({"ports": [p.to_dict() for p in found], "kondo_without_port": unbound, "notes": said})
    elif found:
        out.print(ports_table(found))
    if not as_json:
        for note in said:
            say_labelled("[yellow]note:[/yellow]", escape(note))
    if not found:
        raise CliError(ExitCode.PORT, "no serial ports found", f"is the adapter plugged in? ({port_names_hint()})")
    return 0


COMMANDS = [ports]
