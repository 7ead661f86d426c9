"""doctor: what stands between this machine and the servos, and how fast a cycle can be (library: diagnose)."""

from __future__ import annotations

import contextlib
import os
import sys
from typing import Any

import click
from rich.markup import escape

from .. import policies
from ..bus import Bus
from ..compiled import ENGINE_NAME, engine_compiled
from ..diagnose import Finding
from ..diagnose.line_report import LineReport, measure_round_trips
from ..diagnose.system import SystemReport, check_system
from ..drivers.burst import PATH_NAME, burst_path, line_path
from ..drivers.fine_timer import TIMER_NAME, fine_deadlines
from ..errors import IcsError
from ..transports import carries_line_settings
from ..transports.listing import SerialPortInfo, adapter_name, list_serial_ports
from ..transports.platforms import misnamed_port_hints
from ..transports.wire_device import example_port
from ._common import (
    CliError,
    ExitCode,
    all_ids_option,
    emit_json,
    every_id,
    ids_text,
    json_option,
    out,
    run,
    settings_of,
)
from ._console import say, say_labelled
from ._errors import answered_at_another_id, answered_garbled, nothing_answered, trying_rates
from ._numbers import WholeNumber
from ._settings import Settings

SEVERITY_STYLE = {"error": "bold red", "warning": "yellow", "info": "cyan"}


def machine_ports() -> list[SerialPortInfo]:
    try:
        return list_serial_ports()
    except Exception:  # pyserial's platform backend failed: the other checks still help
        return []


async def why_nobody(settings: Settings, bus: Bus, probed: policies.RateScan, ids: list[int]) -> CliError:
    """Why no servo among ``ids`` answered, as the other commands say it: the adapter when not even the echo came
    back, two servos sharing an ID when replies came garbled, servos at other IDs when only some were asked, the
    rate a device answers at when it is another, else what to check."""
    where = f"{settings.port} at {settings.baud} baud"
    if probed.silent and settings.echo:
        return nothing_answered(settings, where, silent=True)
    if not every_id(ids):
        # (`--ids 9` on a line of servos 1-6: the line and its rate are right, the IDs asked are not)
        probed = await policies.check_other_ids(bus, probed, ids)
        if probed.lost is not None:
            raise probed.lost
        if probed.elsewhere:
            at_id = probed.id_answer
            return answered_at_another_id(settings, ids, where, at_id, several=at_id is None)
    search = policies.RateSearch((settings.baud,))
    if carries_line_settings(settings.port):  # (a link blind to the rate would answer at every one)
        # (advice only: a port that cannot be opened again leaves what was said)
        with contextlib.suppress(IcsError, OSError):
            search = await policies.search_other_rates(
                policies.reopening(bus), [settings.baud], on_rate=trying_rates(settings)
            )
    rates = search.found
    if probed.garbled:
        garbled = answered_garbled(settings, where, [(settings.baud, i) for i in sorted(probed.garbled)])
        if rates:  # (a servo at another rate can garble what it hears at this one)
            garbled.hints.append(f"a device answers at {rates[0]} baud: try --baud {rates[0]}")
        return garbled
    if rates:
        return CliError(
            ExitCode.WRONG_BAUD,
            f"no servo answered on {where}, but a device does at {rates[0]} baud",
            f"pass --baud {rates[0]}",
        )
    # The rates tried, said once (a terminal also saw each as it was tried): the wait is explained, and the advice
    # is not read as if they were still to be tried.
    elsewhere = search.nothing_elsewhere()
    return nothing_answered(settings, where if elsewhere is None else f"{where}, {elsewhere}", silent=False)


def measure(
    settings: Settings, ids: list[int], per_servo: int | None, system: SystemReport, system_root: str = "/"
) -> tuple[LineReport, bool, CliError | None]:
    """The line's report, whether its streams take the burst path (as the open bus says), and why no servo
    answered (None when one did).  The port's latency timer is read again meanwhile, with the port open (the
    timer the round trips met: see SystemReport.timer_while_open)."""

    async def body() -> tuple[LineReport, bool, CliError | None]:
        async with settings.bus() as bus:
            probed = await policies.probe_ids(bus, ids, id_read_first=False)
            found = list(probed.answered)
            nobody = None if found else await why_nobody(settings, bus, probed, ids)
            samples, failed = await measure_round_trips(bus, found, per_servo=per_servo)
            system.timer_while_open(system_root)  # (why_nobody may have reopened it: open again by now)
            report = LineReport(
                baudrate=settings.baud,
                samples=samples,
                failed=failed,
                system_latency_timer_ms=system.latency_timer_ms,
                platform=sys.platform,
                simulated=settings.is_sim,
            )
            return report, bool(bus.describe()["burst_path"]), nobody

    return run(settings, body)


def simulator_note() -> str:
    """What doctor says of the simulator it was given (this system's port named as the example)."""
    return (
        "[bold]the simulator[/bold]: the machine's adapters, drivers and port rights are not checked (they mean "
        "nothing for it); its round trips are the simulator's, not hardware's (for hardware: ics35 doctor --port "
        f"{example_port()})"
    )


def print_report(
    system: SystemReport, line: LineReport | None, findings: list[Finding], simulated: bool = False
) -> None:
    if simulated:
        say(simulator_note(), to=out)
    elif system.ports:
        say("[bold]ports[/bold]", to=out)
        for p in system.ports:
            kind = adapter_name(p.usb_id) or ("Kondo adapter" if p.kondo else p.description or "-")
            say(f"  {escape(p.device)}  {p.usb_id or '-'}  {escape(kind)}", to=out)
    else:
        say("[bold]ports[/bold]: none found", to=out)
    if system.latency_timer_ms is not None:
        opened = ", with the port open" if system.timer_read_open else ""
        say(f"latency timer (from the system{opened}): {system.latency_timer_ms} ms", to=out)
    if line is not None and line.median is not None and line.p99 is not None:
        rates = line.cycle_hz()
        say(
            f"[bold]line{' (simulated)' if simulated else ''}[/bold] at {line.baudrate} baud: "
            f"servo(s) {ids_text(line.servo_ids)}; "
            f"round trip median {line.median * 1e3:.2f} ms, p99 {line.p99 * 1e3:.2f} ms "
            f"({len(line.all_samples)} reads)",
            to=out,
        )
        suspected = line.suspected_timer_ms
        say(f"latency timer suspected: {f'{suspected} ms' if suspected is not None else 'none'}", to=out)
        these = "" if rates["servos"] == 32 else f"{rates['now']:.1f} Hz for these {rates['servos']}, "
        say(f"position cycle rate now (estimated from the reads): {these}{rates['now_32']:.1f} Hz for 32", to=out)
        for fix in rates["after_fixes"]:
            say(f"  after '{fix['fix']}': about {fix['cycle_hz_32']:.1f} Hz for 32 (the adapter's own limit)", to=out)
        say(f"  the wire's limit at {line.baudrate} baud: {rates['wire_limit_32']:.1f} Hz for 32", to=out)
    for f in findings:
        style = SEVERITY_STYLE[f.severity]
        say_labelled(f"[{style}]{f.severity}:[/{style}]", escape(f.problem))
        if f.fix:
            say_labelled("  [cyan]fix:[/cyan]", escape(f.fix))


@click.command()
@all_ids_option("IDs to look for on the line.")
@click.option(
    "--samples",
    type=WholeNumber(1, 1000),
    default=None,
    help="Reads per servo (default: 200 in all, 5 or more each).",
)
@click.option("--system-root", default="/", hidden=True, help="Read system files below this directory (tests).")
@json_option
@click.pass_context
def doctor(ctx: click.Context, ids: list[int], samples: int | None, system_root: str, as_json: bool) -> int:
    """Check the machine and the line: adapters and their driver, rights on the port, who holds it,
    the USB latency timer, a board's UART that cannot carry the line; then each answering servo's round
    trip, the latency timer it points to, and the cycle rate for 32 servos now and after each fix.

    Reads only (temperature reads; ID reads at the other rates when none answers: nothing moves, nothing
    is freed).  Without --port only the machine
    is checked.  Exit codes: 0 checked (findings are advice), 1 the port was lost while measuring, 3 the port
    cannot be opened or another program holds it (the line is not measured), 4 no servo answered, 6 none
    answered at --baud but a device does at another rate (named).
    """
    settings = settings_of(ctx)
    port = None if settings.port_defaulted else settings.port
    # The simulator's line has no adapter, driver or port: the machine's checks would be advice about hardware
    # the user did not ask about ("no Kondo adapter is plugged in"), listed beside the simulator's figures.
    simulated = port is not None and settings.is_sim
    system = SystemReport() if simulated else check_system(machine_ports(), port, root=system_root, own_pid=os.getpid())
    findings = list(system.findings)
    line: LineReport | None = None
    nobody: CliError | None = None
    failure: CliError | None = None
    if port is None:
        findings.append(
            Finding("line", "info", "no --port given: the line was not measured", "ics35 doctor --port PORT")
        )
    elif unreachable := [f for f in system.findings if f.check == "port" and f.severity == "error"]:
        # (the port is not there: said once, as the command's error, with what its name may have meant)
        fixes = [f for f in (unreachable[0].fix, *misnamed_port_hints(port)) if f]
        failure = CliError(ExitCode.PORT, unreachable[0].problem, *fixes)
    elif held := [f for f in system.findings if f.check == "holder" and f.severity == "error"]:
        # (another program has it open: opening it too fails for that one cause, said once with who holds it; or,
        # where the open is let through, its reads would share the replies with that program's)
        failure = CliError(ExitCode.PORT, held[0].problem, *([held[0].fix] if held[0].fix else []))
    else:
        try:
            line, bursts, nobody = measure(settings, ids, samples, system, system_root)
        except CliError as exc:
            failure = exc
        findings = list(system.findings)  # (its latency timer judged again if it was read with the port open)
        if failure is not None:
            findings.append(Finding("line", "error", failure.message, " ; ".join(failure.hints)))
    if line is not None:
        if not line.servo_ids:
            where = f"{settings.port} at {settings.baud} baud"
            failure = nobody or nothing_answered(settings, where, silent=False)
            findings.append(Finding("line", "error", failure.message, " ; ".join(failure.hints)))
        findings += line.judge()
    burst_on, burst_text = burst_path() if line is None else line_path(bursts)  # (the measured line's, if one)
    if as_json:
        report: dict[str, Any] = {
            "port": port,
            "simulated": simulated,
            **system.to_dict(),
            "burst_path": burst_on,
            "io_path": burst_text,
            "compiled_engine": engine_compiled()[0],
            "fine_deadlines": fine_deadlines()[0],
        }
        line_part = line.to_dict() if line is not None else {}
        report.update(
            {
                "baud": settings.baud,
                "servos": line_part.get("servos", []),
                "transactions": line_part.get("transactions", 0),
                "failed": line_part.get("failed", 0),
                "round_trip_ms": line_part.get("round_trip_ms", {"median": None, "p99": None}),
                "latency_timer_suspected_ms": line_part.get("latency_timer_suspected_ms"),
                "cycle_hz": line_part.get("cycle_hz"),
                "findings": [f.to_dict() for f in findings],
            }
        )
        emit_json(report)
    else:
        # The failure itself is printed last, as every command's error is: not twice.
        shown = [f for f in findings if failure is None or f.problem != failure.message]
        say(f"{PATH_NAME}: {escape(burst_text)}", to=out)
        say(f"{ENGINE_NAME}: {escape(engine_compiled()[1])}", to=out)
        say(f"{TIMER_NAME}: {escape(fine_deadlines()[1])}", to=out)
        print_report(system, line, shown, simulated)
    if failure is not None:
        raise failure
    return 0


COMMANDS = [doctor]
