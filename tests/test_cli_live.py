"""monitor and demo: telemetry that follows the stream's offline marking, and --plot checked up front."""

from __future__ import annotations

import asyncio
import io
import json
import os
import re
import subprocess
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from rich.console import Console

from ics35_async import open_bus
from ics35_async.cli import ExitCode
from ics35_async.cli._console import DRAW_SHARE, Redraws, StatusLine, TitleInParts
from ics35_async.cli._live_view import LiveState
from ics35_async.cli._telemetry import Telemetry
from ics35_async.sim import VirtualLine, VirtualServo
from ics35_async.sim.faults import NO_FAULTS, Draw, FaultInjector
from ics35_async.units import temperature_to_celsius
from tests.support.sim_servos import TelemetryGoesSilent, UnplugsWhenAsked, free_command
from tests.support.terminal import screen_of, typed_on_a_terminal
from tests.support.timing import scaled

TELEMETRY_READS = ("read_current", "read_temperature")


def test_monitor_stopped_on_a_line_where_nothing_answers_ends_within_its_search_of_the_other_rates() -> None:
    # `ics35 monitor 1-4 --free --timeout 1` on a line where nothing answers, Ctrl-C: ten seconds to the prompt.  The
    # stop waited for two of the stream's cycles to carry a free to no ID (every ID watched: a servo that answers
    # ICS 3.6's read is never freed), each cycle a whole allowance per offline ID, then the search of the other
    # rates asked each three times.  Left: that search, one allowance a rate.  (Where nothing answers at any rate the
    # view starts all the same: servos powering up join it as they answer.)
    allowance = scaled(0.5)
    typed: list[float] = []

    def now() -> bool:
        typed.append(time.monotonic())
        return True

    args = ["--port", "sim://stop-silent?ids=none", "--timeout", str(allowance), "monitor", "1-4", "--free"]
    code, shown = typed_on_a_terminal(args, [("answering 0/4", b""), (now, b"\x03")])
    took = time.monotonic() - typed[0]
    screen = " ".join(" ".join(screen_of(shown)).split())
    assert code == ExitCode.NO_REPLY and "no servo among 1-4 answered" in screen, screen
    assert "trying 625000 baud" in screen and "trying 1250000 baud" in screen, screen
    assert took < 4 * allowance, took  # (two allowances of search; fourteen and more before)


@pytest.mark.parametrize("command", [["monitor", "1-4", "--free"], ["demo", "--ids", "1-4"]], ids=["monitor", "demo"])
def test_telemetry_does_not_keep_reading_an_id_the_stream_marked_offline(
    cli: Any, sim_line: Any, command: list[str]
) -> None:
    # ID 4 is listed but absent: the stream takes it out of its cycle after a few misses,
    # and telemetry must follow, not spend a reply timeout on it every round.
    sim, url = sim_line([1, 2, 3], log_size=None)
    result = cli("--port", url, "--timeout", "0.005", *command, "--seconds", "1.5", "--telemetry", "4")
    assert result.code == 0, result.err
    reads = Counter(t.servo_id for t in sim.log_since(0) if t.command in TELEMETRY_READS)
    # Nor before: a round after a frame in which ID 4 failed would cost a reply allowance a read (and its
    # retry and guard reads) at each of the offline_after (3) frames it takes the stream to mark it offline,
    # delaying the first cycles.  Telemetry that followed only its own failures would read ID 4 every 0.5 s.
    assert reads[4] == 0, reads
    assert min(reads[1], reads[2], reads[3]) >= 20, reads  # telemetry did run


def test_monitor_starts_an_id_its_probes_found_silent_offline(cli: Any, sim_line: Any) -> None:
    # monitor probes each ID before it streams (nothing that frees a servo it may not), and ID 4 answered none
    # of it; its stream then asked ID 4 again in each of its first three cycles, a whole --timeout each, before
    # taking it out of the cycle: the first frames of a humanoid with its legs unplugged came seconds late.
    sim, url = sim_line([1, 2, 3], log_size=None)
    result = cli("--port", url, "--timeout", "0.05", "monitor", "1-4", "--free", "--seconds", "0.3")
    assert result.code == 0, result.err
    log = list(sim.log_since(0))
    # The stream's cycles go 1, 2, 3, 4 (the probes before it send no free command): its first three cycles are
    # what comes before the fourth free to ID 1.
    frees = [k for k, t in enumerate(log) if t.command == "free" and t.servo_id == 1]
    assert len(frees) >= 4, frees
    first_cycles = log[frees[0] : frees[3]]
    assert [t.command for t in first_cycles if t.servo_id == 4] == [], first_cycles
    assert {t.servo_id for t in first_cycles} == {1, 2, 3}


@pytest.mark.parametrize("command", [["monitor", "1"], ["demo", "--ids", "1"]], ids=["monitor", "demo"])
@pytest.mark.parametrize(
    ("plot", "says"),
    [
        ("/nonexistent/x.png", "does not exist"),
        ("{tmp}/out.txt", "cannot write .txt files"),
        ("{tmp}/noext", "without a suffix"),
        ("{tmp}", "is a directory"),
    ],
)
def test_plot_path_and_format_are_checked_before_the_line(
    cli: Any, sim_line: Any, tmp_path: Path, command: list[str], plot: str, says: str
) -> None:
    pytest.importorskip("matplotlib")
    sim, url = sim_line([1])
    result = cli("--port", url, *command, "--seconds", "1", "--plot", plot.format(tmp=tmp_path))
    assert result.code == ExitCode.USAGE
    assert "--plot" in result.err and says in result.err, result.err
    assert sim.transactions == 0


def test_plot_in_another_format_is_written(cli: Any, sim_line: Any, tmp_path: Path) -> None:
    pytest.importorskip("matplotlib")
    _, url = sim_line([1])
    target = tmp_path / "trace.svg"
    result = cli("--port", url, "monitor", "--free", "1", "--seconds", "0.3", "--plot", str(target))
    assert result.code == 0, result.err
    assert b"<svg" in target.read_bytes()[:500]


@pytest.mark.parametrize("command", [["monitor", "1", "--free"], ["demo", "--ids", "1"]], ids=["monitor", "demo"])
def test_a_first_cycle_that_ends_after_seconds_is_up_is_reported(cli: Any, command: list[str]) -> None:
    # Behind an adapter that holds every reply 0.25 s (an FTDI chip's latency timer at 250 ms), the first
    # cycle ends after --seconds 0.1 is up.  Before it nothing is known of the servo: the command waits for it
    # and reports what it found, not "no servo answered" (a loaded machine can be as slow).
    url = "sim://?ids=1&realtime=1&adapter=ftdi&latency_timer=250"
    result = cli("--port", url, "--timeout", "1", *command, "--seconds", "0.1")
    assert result.code == 0, result.err
    assert "answering 1/1" in result.out, result.out  # (0/1 until a cycle has ended)


@pytest.mark.parametrize(
    ("command", "position_cells"),
    [(["monitor", "1-3", "--free"], slice(1, 3)), (["demo", "--ids", "1-3"], slice(2, 3))],
    ids=["monitor", "demo"],
)
def test_a_servo_gone_offline_shows_no_position(
    cli: Any, sim_line: Any, command: list[str], position_cells: slice
) -> None:
    # Servo 3 answers, then is unplugged: its row says "off", and shows no position (nor current or
    # temperature), not the last ones read as if it were still there.
    sim, url = sim_line([1, 2, 3], realtime=True)
    ended = threading.Event()

    def unplug_once_it_answered() -> None:  # (by what the command has seen, not by the clock: a loaded machine)
        while not ended.is_set() and sum(t.servo_id == 3 for t in sim.log_since(0)) < 5:
            time.sleep(0.01)
        sim.remove_servo(3)

    unplugging = threading.Thread(target=unplug_once_it_answered)
    unplugging.start()
    try:
        # 4 s: servo 3 goes offline after failing three cycles in a row, and on a loaded machine the command ran
        # under 3 cycles a second (2 s then left servo 3 with failures counted, "6!", not yet offline).
        result = cli("--port", url, "--timeout", "0.02", *command, "--seconds", "4")
    finally:
        ended.set()
        unplugging.join()
    assert result.code == 0, result.err
    rows = {line.split()[0]: line.split() for line in result.out.splitlines() if line.split()[:1] in (["1"], ["3"])}
    assert rows["3"][-1] == "off", result.out
    assert rows["3"][position_cells] == ["-"] * len(rows["3"][position_cells]), result.out
    assert rows["3"][-3:-1] == ["-", "-"], result.out  # current, temperature
    assert "-" not in rows["1"][position_cells], result.out  # (a servo still there shows where it is)


@pytest.mark.parametrize("json_lines", [False, True], ids=["table", "json"])
def test_monitor_that_cannot_keep_its_rate_says_so(cli: Any, sim_line: Any, json_lines: bool) -> None:
    # 32 servos at 115200 baud take over 18 ms a cycle on the wire: --rate 100 ran at about 40 Hz with not a word
    # (the stream's warning, which names the cause, was silenced with the library's other log records).
    _, url = sim_line(list(range(32)), realtime=True)
    json_option = ["--json"] if json_lines else []
    # (the stream judges its rate at its 20th cycle: about half a second here, idle; under load three times that)
    result = cli("--port", url, "monitor", "0-31", "--free", "--rate", "100", "--seconds", "3", *json_option)
    assert result.code == 0, result.err
    assert "warning: stream of 32 IDs cannot keep rate_hz=100" in result.err, result.err
    assert "115200 baud" in result.err and "lower rate" in result.err, result.err


def test_monitor_json_that_loses_its_port_still_ends_with_a_final_line(cli: Any) -> None:
    # A log of the JSON lines is told the run is over by "final": true; a lost port ended it after a line of
    # "final": false (or none at all under a second), as if cut off, with the servos' last readings unsaid.
    url = "sim://?ids=1-2&realtime=1&unplug_after=0.5"
    result = cli("--port", url, "monitor", "1-2", "--free", "--json", "--seconds", "5")
    assert result.code == ExitCode.COMMUNICATION and "lost" in result.err, result.err
    docs = [json.loads(line) for line in result.out.splitlines()]
    assert docs and docs[-1]["final"] is True, result.out
    assert docs[-1]["servos"]["1"]["position"] is not None and docs[-1]["cycle"] > 0, docs[-1]
    # (and the option that keeps the command going through a lost port: the person learns of it where they need it)
    assert "--reconnect" in " ".join(result.err.split()), result.err


def cycle_of(summary: str) -> int:
    """The cycle a live view's status line names."""
    found = re.search(r"\bcycle (\d+)", summary)
    assert found is not None, summary
    return int(found.group(1))


@pytest.mark.parametrize("json_lines", [False, True], ids=["log", "json"])
def test_monitor_with_reconnect_waits_for_a_lost_port_and_carries_on_once_it_is_back(
    cli: Any, sim_line: Any, json_lines: bool
) -> None:
    # A loose cable ended the view (exit 1).  With --reconnect it stays: it says the port is lost and that it
    # waits for it, shows no readings meanwhile (the last ones would pass for live ones), and carries on.
    sim, url = sim_line([1, 2], realtime=True)
    ended = threading.Event()
    away = scaled(2.5)  # (two of the lines said once a second, at least)

    def unplug_then_plug_back() -> None:  # (once the stream runs: by what the command has sent, not by the clock)
        while not ended.is_set() and len(sim.log_since(0)) < 40:
            time.sleep(0.01)
        sim.unplug()  # (it stays out until plugged back)
        ended.wait(away)
        sim.replug()

    plugging = threading.Thread(target=unplug_then_plug_back)
    plugging.start()
    try:
        seconds = f"{away + scaled(3):g}"
        json_option = ["--json"] if json_lines else []
        result = cli("--port", url, "monitor", "1-2", "--free", "--reconnect", "--seconds", seconds, *json_option)
    finally:
        ended.set()
        plugging.join()
    assert result.code == 0, result.err
    assert sim.unplug_count == 1, "the port was never unplugged"
    if json_lines:
        docs = [json.loads(line) for line in result.out.splitlines()]
        lost = [k for k, doc in enumerate(docs) if doc["port_lost"]]
        assert lost, result.out
        for k in lost:
            for servo in docs[k]["servos"].values():
                assert [servo[key] for key in ("position", "current", "temperature")] == [None] * 3, docs[k]
        last = docs[-1]
        assert last["final"] is True and last["port_lost"] is False and last["reconnects"] == 1, last
        assert last["cycle"] > docs[lost[-1]]["cycle"], last
        assert all(last["servos"][sid]["position"] is not None for sid in ("1", "2")), last
        return
    summaries = [line for line in result.out.splitlines() if line.startswith("t=")]
    lost = [k for k, line in enumerate(summaries) if "port lost" in line]
    assert lost, result.out
    for k in lost:
        assert "waiting for it to come back" in summaries[k] and "answering" not in summaries[k], summaries[k]
    after = summaries[lost[-1] + 1 :]
    assert after and "answering 2/2" in after[-1] and "reconnects 1" in after[-1], result.out
    assert cycle_of(after[-1]) > cycle_of(summaries[lost[-1]]), result.out
    rows = [line.split() for line in result.out.splitlines() if line.split()[:1] in (["1"], ["2"])]
    assert len(rows) == 2 and all("-" not in row and "lost" not in row for row in rows), result.out


@pytest.mark.parametrize("ids", ["1-2", "all"], ids=["named", "scanned"])
def test_monitor_with_reconnect_rides_out_a_port_lost_while_it_asks_its_ids(cli: Any, sim_line: Any, ids: str) -> None:
    # A loss before the view began ended the command at once (exit 4), --reconnect or not: the first transaction
    # pulls the port here, and it comes back by itself.
    sim, url = sim_line([1, 2], realtime=True, faults="unplug:1", replug_after=scaled(0.3))
    sim.add_listener(lambda plugged: setattr(sim, "faults", FaultInjector()))  # (once: the port stays back)
    result = cli("--port", url, "--timeout", "0.05", "monitor", ids, "--free", "--reconnect", "--seconds", "1")
    assert result.code == 0, result.err
    assert sim.unplug_count == 1
    said = [line for line in result.err.splitlines() if "port is lost" in line]
    assert len(said) == 1 and "waiting for it to come back" in said[0], result.err
    assert "the port is back" in result.err, result.err
    summary = [line for line in result.out.splitlines() if line.startswith("t=")][-1]
    assert "answering 2/2" in summary and "reconnects 1" in summary, result.out


class UnplugInTheStream(FaultInjector):
    """Pulls the port at the ``k``-th transaction after the stream's first (monitor --free streams the free
    command), once."""

    def __init__(self, sim: VirtualLine, k: int) -> None:
        super().__init__()
        self.sim, self.k, self.pulled = sim, k, False

    def draw(self, servo_id: int | None) -> Draw:
        log = [t.command for t in self.sim.log]  # (called under the line's lock: the transactions before this one)
        if self.pulled or "free" not in log or len(log) - log.index("free") != self.k:
            return NO_FAULTS
        self.pulled = True
        return Draw(echo=False, reply=None, noise=False, unplug=True)


# Each transaction of a cycle (two frees, then telemetry's reads): a loss right after a frame came, before
# telemetry queued its reads, ended the command with the loss's error, --reconnect or not (the request raised).
@pytest.mark.parametrize("k", range(1, 8))
def test_monitor_with_reconnect_rides_out_a_port_lost_at_any_transaction_of_its_first_cycles(
    cli: Any, sim_line: Any, k: int
) -> None:
    sim, url = sim_line([1, 2], realtime=True, replug_after=scaled(0.2))
    sim.faults = UnplugInTheStream(sim, k)
    result = cli("--port", url, "--timeout", "0.05", "monitor", "1-2", "--free", "--reconnect", "--seconds", "0.8")
    assert result.code == 0, result.err
    assert sim.unplug_count == 1
    summary = [line for line in result.out.splitlines() if line.startswith("t=")][-1]
    assert "answering 2/2" in summary and "reconnects 1" in summary, result.out


def test_monitor_without_reconnect_fails_at_a_port_lost_while_it_asks_its_ids_and_names_the_option(
    cli: Any, sim_line: Any
) -> None:
    _, url = sim_line([1, 2], realtime=True, faults="unplug:1", replug_after=scaled(0.3))
    result = cli("--port", url, "--timeout", "0.05", "monitor", "1-2", "--free", "--seconds", "1")
    assert result.code == ExitCode.COMMUNICATION, result.err
    assert "lost: the simulated port was unplugged" in result.err and "--reconnect keeps" in result.err, result.err


def test_monitor_with_reconnect_whose_port_stays_lost_while_it_asks_ends_at_seconds(cli: Any, sim_line: Any) -> None:
    # (no cycle ran: an error, not a table of nothing; and --seconds ends the wait, not only Ctrl-C)
    _, url = sim_line([1, 2], realtime=True, faults="unplug:1", replug_after=scaled(30))
    started = time.monotonic()
    result = cli("--port", url, "--timeout", "0.05", "monitor", "1-2", "--free", "--reconnect", "--seconds", "0.5")
    assert time.monotonic() - started < scaled(10), result.err
    assert result.code == ExitCode.COMMUNICATION, result.err
    assert "was not back when --seconds" in result.err and "--seconds" in result.err, result.err


@pytest.mark.timeout(scaled(60))  # (it waited for the port without end: Ctrl-C alone ended it)
def test_monitor_with_reconnect_whose_port_is_lost_in_its_first_cycle_for_good_ends_at_seconds(
    cli: Any, sim_line: Any
) -> None:
    # The IDs known, the port went in the stream's first cycle and stayed out: --seconds was set at the first frame,
    # which never came.  It bounds the run: counted from when the IDs are known, it ends the wait with the loss's
    # error (no cycle ran: an error, not a table of nothing).
    puller = UnplugsWhenAsked(1, free_command)  # (the stream's first transaction: monitor --free streams the free)
    sim, url = sim_line([puller, VirtualServo(2)], realtime=True)
    puller.line = sim
    started = time.monotonic()
    result = cli("--port", url, "--timeout", "0.05", "monitor", "1-2", "--free", "--reconnect", "--seconds", "0.5")
    assert time.monotonic() - started < scaled(10), result.err
    assert sim.unplug_count == 1
    assert result.code == ExitCode.COMMUNICATION, result.err
    said = " ".join(result.err.split())
    assert "lost" in said and "was not back when --seconds (0.5 s) ran out, before a first cycle" in said, said


# (The unplug comes a second in and 40 transactions of a real-time simulator in.)
@pytest.mark.realtime
def test_monitor_that_ends_while_it_waits_for_its_lost_port_says_it_was_lost_not_that_it_waits(
    cli: Any, sim_line: Any
) -> None:
    # (--seconds up with the port gone for good: the table and the status line a log ends with)
    sim, url = sim_line([1, 2], realtime=True)
    ended = threading.Event()

    def unplug() -> None:
        start = time.monotonic()
        while not ended.is_set() and (len(sim.log_since(0)) < 40 or time.monotonic() - start < scaled(1)):
            time.sleep(0.01)
        sim.unplug()

    unplugging = threading.Thread(target=unplug)
    unplugging.start()
    try:
        result = cli("--port", url, "monitor", "1-2", "--free", "--reconnect", "--seconds", f"{scaled(3):g}")
    finally:
        ended.set()
        unplugging.join()
    assert result.code == 0, result.err
    last = result.out.splitlines()[-1]
    assert "port lost for" in last and "waiting" not in last, result.out
    rows = [line.split() for line in result.out.splitlines() if line.split()[:1] in (["1"], ["2"])]
    assert [row[1:] for row in rows] == [["-", "-", "-", "-", "lost"]] * 2, result.out


def test_a_servo_gone_offline_has_no_readings_in_monitor_json(cli: Any, sim_line: Any) -> None:
    # As in the table: a log of the JSON lines took the last readings of an unplugged servo, repeated each
    # second, for where it was and what it drew.
    sim, url = sim_line([3], realtime=True)
    ended = threading.Event()

    def unplug_once_it_answered() -> None:  # (its position read, and its temperature: readings to go stale)
        while not ended.is_set() and not {"free", "read_temperature"} <= {t.command for t in sim.log_since(0)}:
            time.sleep(0.01)
        sim.remove_servo(3)

    unplugging = threading.Thread(target=unplug_once_it_answered)
    unplugging.start()
    try:
        result = cli("--port", url, "--timeout", "0.02", "monitor", "3", "--free", "--json", "--seconds", "4")
    finally:
        ended.set()
        unplugging.join()
    assert result.code == 0, result.err
    servos = json.loads(result.out.splitlines()[-1])["servos"]
    assert servos["3"]["offline"] is True, servos
    assert [servos["3"][k] for k in ("position", "current", "temperature")] == [None, None, None], servos


def test_a_servo_whose_telemetry_reads_keep_failing_has_no_current_or_temperature_in_monitor_json(
    cli: Any, sim_line: Any
) -> None:
    # Servo 2 answers its position every cycle, but its temperature and current reads went unanswered after the
    # first: each JSON line went on giving the temperature and current read then, as if read that second.
    silent = TelemetryGoesSilent(2, answered=2)
    _, url = sim_line([VirtualServo(1), silent])
    result = cli("--port", url, "--timeout", "0.005", "monitor", "1-2", "--free", "--json", "--seconds", "1.5")
    assert result.code == 0, result.err
    assert silent.answered == 0 and silent.unanswered >= 2, silent.unanswered  # (read once, then failing)
    servos = json.loads(result.out.splitlines()[-1])["servos"]
    assert servos["2"]["offline"] is False and servos["2"]["position"] is not None, servos  # (still answering)
    assert [servos["2"][k] for k in ("current", "temperature")] == [None, None], servos
    assert servos["2"]["errors"] >= 2, servos  # (the failed reads counted)
    assert servos["1"]["temperature"] is not None and servos["1"]["current"] is not None, servos


def test_a_servo_whose_telemetry_reads_keep_failing_has_no_current_or_temperature_in_demos_table(
    cli: Any, sim_line: Any
) -> None:
    silent = TelemetryGoesSilent(2, answered=2)
    _, url = sim_line([VirtualServo(1), silent])
    result = cli("--port", url, "--timeout", "0.005", "demo", "--ids", "1-2", "--seconds", "1.5")
    assert result.code == 0, result.err
    assert silent.answered == 0 and silent.unanswered >= 2, silent.unanswered
    rows = {line.split()[0]: line.split() for line in result.out.splitlines() if line.split()[:1] in (["1"], ["2"])}
    # (ID, target, angle, current, temperature, errors)
    assert rows["2"][3:5] == ["-", "-"] and rows["2"][2] != "-", result.out
    assert "-" not in rows["1"][3:5], result.out


@pytest.mark.parametrize("command", [["monitor", "all", "--free"], ["demo", "--ids", "all"]], ids=["monitor", "demo"])
def test_all_means_the_servos_that_answer_and_the_empty_ids_are_one_line(
    cli: Any, sim_line: Any, command: list[str]
) -> None:
    # On a 3-servo line, "all" is those 3: not a table of 29 empty rows counting errors, each a reply timeout.
    _, url = sim_line([1, 2, 3])
    result = cli("--port", url, "--timeout", "0.005", *command, "--seconds", "0.3")
    assert result.code == 0, result.err
    rows = [line.split()[0] for line in result.out.splitlines() if line.split()[:1] and line.split()[0].isdigit()]
    assert rows == ["1", "2", "3"], result.out
    said = [line for line in result.err.splitlines() if "no answer" in line]
    assert len(said) == 1 and "0, 4-31" in said[0], result.err
    assert "answering 3/3" in result.out, result.out


def test_monitor_all_where_nothing_answers_is_an_error(cli: Any, sim_line: Any) -> None:
    _, url = sim_line([])
    result = cli("--port", url, "--timeout", "0.005", "monitor", "all", "--free", "--seconds", "0.3")
    assert result.code == ExitCode.NO_REPLY, result.err
    assert "no servo answered" in result.err


@pytest.mark.parametrize(
    "command",
    [["monitor", "all", "--free"], ["monitor", "--free"], ["demo", "--ids", "all"]],
    ids=["monitor-all", "monitor", "demo-all"],
)
def test_every_servo_asked_where_none_answers_at_this_rate_names_the_rate_they_answer_at(
    cli: Any, sim_line: Any, command: list[str]
) -> None:
    # Servos set to 625000 (an HS adapter's user) and a line opened at the default 115200: not "check the power".
    _, url = sim_line([VirtualServo(1, baud_rate=625000), VirtualServo(2, baud_rate=625000)])
    result = cli("--port", url, "--timeout", "0.005", *command, "--seconds", "0.3")
    assert result.code == ExitCode.WRONG_BAUD, result.err
    assert "625000" in result.err and "--baud 625000" in result.err, result.err
    assert "power" not in result.err, result.err


@pytest.mark.parametrize("json_lines", [False, True], ids=["table", "json"])
def test_a_reader_that_leaves_the_pipe_ends_monitor_quietly(json_lines: bool) -> None:
    # `ics35 monitor 1-3 | head -2`: the reader leaves while monitor still writes.  Nothing said, the servos let
    # go as on any other end (the line closed, not left to the process's exit), and exit code 1 as click, rich
    # and Python's own advice for SIGPIPE have it (a shell's `set -o pipefail` sees it, as it sees a tool the
    # signal ended).
    args = ["--port", "sim://?ids=1-3", "-v", "monitor", "1-3", "--free", "--seconds", "30"]
    proc = subprocess.Popen(
        [sys.executable, "-m", "ics35_async.cli", *args, *(["--json"] if json_lines else [])],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env={**os.environ, "COLUMNS": "100"},
    )
    assert proc.stdout is not None and proc.stderr is not None
    assert proc.stdout.readline()  # the reader takes a line, then leaves
    proc.stdout.close()
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=30) == 1, err
    assert "Traceback" not in err and "rror" not in err, err
    assert "closed sim://" in err, err


@pytest.mark.parametrize("command", [["monitor", "1-20", "--free"], ["demo", "--ids", "1-20"]], ids=["monitor", "demo"])
def test_a_live_commands_table_into_a_log_is_printed_whole_whatever_columns_says(command: list[str]) -> None:
    # `COLUMNS=50 ics35 monitor 1-20 | tee log`: the table at the end was laid out at 50 columns, every value cut
    # ("7…", "+…").  A log is read later, in a wider window or a file: the whole table goes in it.
    proc = subprocess.run(
        [sys.executable, "-m", "ics35_async.cli", "--port", "sim://?ids=1-20", *command, "--seconds", "1"],
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, "COLUMNS": "50"},
    )
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    header = next(line for line in lines if line.split()[:1] == ["ID"])
    half = ["ID", "target°" if command[0] == "demo" else "pos", "pos°", "cur", "temp", "err"]
    assert header.split() == [*half, "│", *half], proc.stdout
    rows = [line for line in lines if re.match(r" *\d+ ", line)]
    assert len(rows) == 10 and not any("…" in line for line in rows), proc.stdout
    assert all(len(line.split()) == 13 for line in rows), proc.stdout


@pytest.mark.parametrize("command", [["monitor", "1-4", "--free"], ["demo", "--ids", "1-4"]], ids=["monitor", "demo"])
def test_a_live_command_into_a_pipe_reads_in_the_order_things_happened(command: list[str]) -> None:
    # `ics35 monitor 1-4 2>&1 | cat`: its "t=" lines came first, its title only with the table at the end, and the
    # line saying which IDs it asks not at all, where a terminal shows the title, the asking line, then the table.
    # Into a pipe each line goes out as it is said, stdout's and stderr's in turn, the title first of stdout's.
    proc = subprocess.run(
        [sys.executable, "-m", "ics35_async.cli", "--port", "sim://?ids=1-4", *command, "--seconds", "1.5"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        timeout=60,
        env={**os.environ, "COLUMNS": "100"},
    )
    assert proc.returncode == 0, proc.stdout
    lines = proc.stdout.splitlines()
    title = next((i for i, line in enumerate(lines) if "one line per second, table at the end" in line), None)
    first = next((i for i, line in enumerate(lines) if line.startswith("t=")), None)
    assert title is not None and first is not None and title < first, proc.stdout
    if command[0] == "monitor":
        asking = next((i for i, line in enumerate(lines) if line.startswith("asking IDs 1-4 on sim://")), None)
        assert asking is not None and asking < title, proc.stdout


def test_the_search_of_the_other_rates_says_which_it_tries_on_a_terminal() -> None:
    # `monitor 1 --free --timeout 1` where servo 1 does not answer at the line's rate: the command then asked the
    # other rates, a whole allowance each at least, with nothing said until its error.
    port = "sim://search-said?ids=1&baud=1250000"  # (servo 1 at 1250000, the line at the default 115200)
    code, shown = typed_on_a_terminal(
        ["--port", port, "--timeout", "0.05", "monitor", "1", "--free", "--seconds", "0.3"], []
    )
    screen = " ".join(" ".join(screen_of(shown)).split())
    assert code == ExitCode.WRONG_BAUD, screen
    tried = "no answer at 115200 baud: trying 625000 baud ... trying 1250000 baud too ..."
    assert tried in screen and "--baud 1250000" in screen, screen


def test_monitor_of_listed_ids_on_a_line_where_nothing_answers_says_what_it_asks_and_asks_each_id_once() -> None:
    # `ics35 monitor 1-4 --timeout 1` on a line where nothing answers: ten seconds of a blank terminal before the first
    # cycle.  The wait is said as it starts, and each silent ID costs one allowance, not two: the line is asked once
    # whether anybody is there (the ID read), instead of each ID again.
    allowance = scaled(0.5)
    started: list[float] = []

    def now() -> bool:
        started.append(time.monotonic())
        return True

    args = ["--port", "sim://listed-silent?ids=none", "--timeout", str(allowance), "monitor", "1-6", "--seconds", "0.1"]
    code, shown = typed_on_a_terminal(
        args, [("asking IDs 1-6 on sim://listed-silent?ids=none at 115200 baud", b""), (now, b"")]
    )
    took = time.monotonic() - started[0]
    screen = " ".join(" ".join(screen_of(shown)).split())
    assert code == ExitCode.NO_REPLY and "no servo among 1-6 answered" in screen, screen
    # Six probes, the last one's second look behind its guard read, the ID read, then the other two rates: eleven
    # allowances and the rest of the run, where each ID's position-read probe more made it seventeen.
    assert took < 14 * allowance, took


@pytest.mark.parametrize("command", [["monitor", "1-4", "--free"], ["demo", "--ids", "1-4"]], ids=["monitor", "demo"])
def test_a_live_view_of_listed_ids_none_of_which_answers_ends_at_once_with_the_rate_they_answer_at(
    command: list[str],
) -> None:
    # `ics35 --baud 1250000 monitor 1-3 --free` on a line at 115200: a live table of "off" rows, "answering 0/3",
    # until Ctrl-C or --seconds, and only then "pass --baud 115200".  Not one asked answering at the line's rate but
    # at another, it says so at once, as a command of one servo does (here the servos at 625000, the line at 115200).
    port = "sim://listed-elsewhere?ids=1-4&baud=625000"  # (the servos at 625000, the line at the default 115200)
    code, shown = typed_on_a_terminal(["--port", port, "--timeout", "0.05", *command], [], timeout=30)
    screen = " ".join(" ".join(screen_of(shown)).split())
    assert code == ExitCode.WRONG_BAUD, screen
    assert "no servo among 1-4 answered at 115200 baud, but servo 1 does at 625000 baud" in screen, screen
    assert "answering 0/4" not in screen and "Traceback" not in screen, screen


@pytest.mark.parametrize("port", ["sim://", "SIM://", "sim:///"])
def test_the_simulator_with_nothing_asked_of_it_runs_in_real_time_however_its_url_is_written(
    cli: Any, port: str
) -> None:
    # The bare simulator becomes a real-time one for a live command, so the rate shown is a line's; written with the
    # slash an unnamed URL may have (sim:///, the same line as sim://), it ran in fast mode at thousands of cycles a
    # second, more than the wire carries.
    import json

    from ics35_async.protocol import wire_time

    result = cli("--port", port, "monitor", "1", "--free", "--seconds", "0.2", "--json")
    assert result.code == 0, result.err
    final = json.loads(result.out.splitlines()[-1])
    assert final["final"] and final["servos"]["1"]["position"] is not None, final
    wire_limit_hz = 1 / wire_time(3 + 3, 115200)  # (the free command and its reply, at the default rate)
    assert 0 < final["rate_avg_hz"] < wire_limit_hz, final


@pytest.mark.parametrize("rate", [["--rate", "50"], []], ids=["paced", "unpaced"])
def test_monitor_shows_the_rate_asked_beside_the_rate_reached(rate: list[str]) -> None:
    # `ics35 monitor --rate 100` showed "rate  35.8 Hz": whether that is the rate asked, or far below it, the
    # reader had to remember.  The table's status line and each JSON line say the rate asked too.
    port = "sim://rate-asked?ids=1-2&realtime=1"
    args = ["--port", port, "monitor", "1-2", "--free", *rate, "--seconds", "1.5"]
    code, shown = typed_on_a_terminal(args, [])
    screen = " ".join(" ".join(screen_of(shown)).split())
    assert code == 0, screen
    status = re.findall(r"rate +[\d.]+ (?:of \d+ )?Hz", screen)
    assert status, screen
    assert all(s.endswith(" of 50 Hz") if rate else " of " not in s for s in status), status
    result = subprocess.run(
        [sys.executable, "-m", "ics35_async.cli", *args, "--json"], capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 0, result.stderr
    docs = [json.loads(line) for line in result.stdout.splitlines()]
    assert docs and all(d["rate_asked_hz"] == (50 if rate else None) for d in docs), docs
    assert all(d["rate_hz"] > 0 for d in docs), docs


def test_monitor_on_the_built_in_simulator_names_it_as_its_other_lines_do(cli: Any) -> None:
    # `ics35 monitor` without --port said "scanning sim://?realtime=1&baud=115200 ...", a URL nobody typed (the
    # live view's own), where its other lines say "the built-in simulator"; and its refusal of the 32 ICS 3.5
    # servos listed their IDs one by one, 0, 1, 2, ... 31, where every other list of IDs gives ranges.
    result = cli("monitor", "--seconds", "0.2")
    assert result.code == ExitCode.REFUSED, result.err
    said = " ".join(result.err.split())
    assert "scanning the built-in simulator at 115200 baud" in said, said
    assert "realtime" not in said, said
    assert "no servo among 0-31 can report its position" in said, said


def test_a_servo_back_from_offline_shows_no_reading_from_before_until_read_again(sim_line: Any) -> None:
    # monitor's and demo's table: a servo unplugged went "off" with no readings shown, but once it answered again
    # its row showed the temperature and current read before it went, as if its own now, until telemetry read it
    # anew (it may have come back restarted, hotter or cooler).
    sim, url = sim_line([3])
    shown_back: list[tuple[int | None, int | None, int | None]] = []

    async def main() -> None:
        async with asyncio.timeout(scaled(20)), open_bus(url, adapter_latency=0.01) as bus:
            stream = bus.stream([3], on_close="hold")
            telemetry = Telemetry(bus, [3], 1, probe_interval=stream.probe_interval)
            state = LiveState([3], TitleInParts(("monitor",), frozenset()), None)
            async with stream:
                stage = "reading"
                while stage != "read again":
                    frame = await stream.next_frame()
                    state.update(frame, 0.0, stream)
                    if stage == "reading" and 3 in telemetry.temperature:
                        servo, stage = sim.remove_servo(3), "unplugged"
                    elif stage == "unplugged" and 3 in frame.offline:
                        servo.temperature_celsius = 70.0
                        sim.add_device(servo)
                        stage = "away"
                    elif stage == "away" and 3 not in frame.offline:
                        stage = "back"
                    if stage == "back":
                        shown_back.append(state.readings(3, telemetry))
                        if 3 in telemetry.temperature and temperature_to_celsius(telemetry.temperature[3]) > 65:
                            stage = "read again"
                    telemetry.after_frame(frame)

    asyncio.run(main())
    temperatures = [None if temp is None else temperature_to_celsius(temp) for _, _, temp in shown_back]
    assert temperatures and all(t is None or t > 65 for t in temperatures), temperatures  # (never the 42 C before)


def test_demo_with_reconnect_waits_for_a_lost_port_and_brings_the_servos_back_in_from_where_they_stand(
    cli: Any, sim_line: Any
) -> None:
    # A loose cable ended the wave (exit 1).  With --reconnect it waits for the port, says so, and carries on once
    # it is back: each servo read again first (it may have restarted, free, elsewhere), then blended into the wave.
    sim, url = sim_line([1, 2], realtime=True)
    ended = threading.Event()
    away = scaled(1.5)
    back_at: list[int] = []

    def unplug_then_plug_back() -> None:  # (once the stream runs: by what the command has sent, not by the clock)
        while not ended.is_set() and len(sim.log_since(0)) < 40:
            time.sleep(0.01)
        sim.unplug()
        ended.wait(away)
        back_at.append(len(sim.log))
        sim.replug()

    plugging = threading.Thread(target=unplug_then_plug_back)
    plugging.start()
    try:
        seconds = f"{away + scaled(3):g}"
        result = cli("--port", url, "demo", "--ids", "1-2", "--reconnect", "--seconds", seconds)
    finally:
        ended.set()
        plugging.join()
    assert result.code == 0, result.err
    assert sim.unplug_count == 1, "the port was never unplugged"
    summaries = [line for line in result.out.splitlines() if line.startswith("t=")]
    lost = [k for k, line in enumerate(summaries) if "port lost" in line]
    assert lost and "waiting for it to come back" in summaries[lost[0]], result.out
    after = summaries[lost[-1] + 1 :]
    assert after and "answering 2/2" in after[-1] and "reconnects 1" in after[-1], result.out
    # Back, each servo's first command is the free command that reads where it stands (not a wave target).
    firsts = {}
    for t in sim.log_since(back_at[0]):
        if t.command in ("position", "free") and t.servo_id not in firsts:
            firsts[t.servo_id] = t.command
    assert firsts == {1: "free", 2: "free"}, firsts
    assert "all servos left free" in result.out, result.out


def test_demo_with_reconnect_rides_out_a_port_lost_while_it_asks_its_ids(cli: Any, sim_line: Any) -> None:
    sim, url = sim_line([1, 2], realtime=True, faults="unplug:1", replug_after=scaled(0.3))
    sim.add_listener(lambda plugged: setattr(sim, "faults", FaultInjector()))  # (once: the port stays back)
    result = cli("--port", url, "--timeout", "0.05", "demo", "--ids", "1-2", "--reconnect", "--seconds", "1")
    assert result.code == 0, result.err
    said = [line for line in result.err.splitlines() if "port is lost" in line]
    assert len(said) == 1 and "waiting for it to come back" in said[0], result.err
    summary = [line for line in result.out.splitlines() if line.startswith("t=")][-1]
    assert "answering 2/2" in summary and "reconnects 1" in summary, result.out


def test_demo_without_reconnect_fails_at_a_lost_port_and_names_the_option(cli: Any) -> None:
    result = cli("--port", "sim://?ids=1-2&realtime=1&unplug_after=0.5", "demo", "--ids", "1-2", "--seconds", "5")
    assert result.code == ExitCode.COMMUNICATION and "lost" in result.err, result.err
    assert "--reconnect" in " ".join(result.err.split()), result.err


def test_a_live_view_draws_less_often_where_a_drawing_takes_long() -> None:
    # Drawn ten times a second whatever a drawing cost, monitor's table of 32 servos at 60 columns (30-70 ms a
    # drawing) took most of the loop that streams: 19-23 cycles/s over a pty, 35 into a file.
    clock = [0.0]

    def drawing(took: float) -> Callable[[], None]:
        return lambda: clock.__setitem__(0, clock[0] + took)

    redraws = Redraws(0.1, clock=lambda: clock[0])
    assert redraws.due(5.0)  # (the first at once)
    redraws.draw(5.0, drawing(0.005))
    assert not redraws.due(5.099) and redraws.due(5.1)
    redraws.draw(5.1, drawing(0.08))  # at most DRAW_SHARE of the time: the next one 0.4 s on
    assert not redraws.due(5.1 + 0.08 / DRAW_SHARE - 0.001) and redraws.due(5.1 + 0.08 / DRAW_SHARE)
    later = Redraws(1.0, first=7.0)  # (a log's first line after a second, with a rate measured)
    assert not later.due(6.9) and later.due(7.0)


def test_a_logged_monitor_keeps_its_end_tables_title_whole(cli: Any) -> None:
    # Into a file, the table at the end had its title cut at the table's width: "monitor sim://?ids=1-4&realtime="
    # (a port's path cut short reads as another's; a log's lines stay whole however long).
    result = cli("--port", "sim://?ids=1-4&realtime=1", "monitor", "1-4", "--free", "--seconds", "1.2")
    assert result.code == 0, result.err
    title = "monitor sim://?ids=1-4&realtime=1 at 115200 baud (ICS 3.5 servos free)"
    lines = result.out.splitlines()
    table = next(k for k, line in enumerate(lines) if line.split()[:2] == ["ID", "pos"])
    assert title in [line.strip() for line in lines[table - 3 : table]], result.out


def status_drawn(text: str, columns: int) -> list[str]:
    """The lines a live view's status line ``text`` is drawn as on a terminal ``columns`` wide."""
    console = Console(width=columns, file=io.StringIO(), color_system=None)
    console.print(StatusLine(text))
    return [line.rstrip() for line in console.file.getvalue().splitlines()]  # type: ignore[attr-defined]


@pytest.mark.parametrize("columns", [40, *range(50, 111, 3)])
def test_a_status_line_breaks_between_its_fields_not_inside_one(columns: int) -> None:
    # At 82 columns monitor's status with its port lost read "... waiting for it to come back  errors" / "0   Ctrl-C
    # to stop": a count on a line of its own, its label at the end of the one above; at 70, "... to come" / "back".
    state = LiveState([1, 2], TitleInParts(("monitor",), frozenset()), 10.0, cycle=412, elapsed=3.0, lost_at=0.5)
    telemetry = Telemetry(None, [1, 2], 1)  # type: ignore[arg-type]  (no bus: nothing read, no error counted)
    fields = ["t=  3.0/10 s", "cycle 412", "port lost for 2.5 s: waiting for it to come back", "errors 0"]
    text = state.summary(telemetry) + "   Ctrl-C to stop"
    assert text == "  ".join(fields) + "   Ctrl-C to stop", text
    lines = status_drawn(text, columns)
    assert " ".join(" ".join(lines).split()) == " ".join(text.split()), lines  # (the same words, none cut)
    assert all(len(line) <= columns for line in lines), lines
    for field in [*fields, "Ctrl-C to stop"]:
        if len(field) <= columns:
            assert any(field in line for line in lines), (field, lines)
    if columns < len(fields[2]):  # (a field wider than the terminal: on lines of its own, broken between its words)
        assert lines[1].startswith("port lost") and any(line.startswith("errors 0") for line in lines), lines


@pytest.mark.parametrize(
    "fields",
    [
        ["t=    - s (the first pose is at 1 s)", "12 pose(s) captured"],  # teach's: a field may start with a count
        ["t=  2.5/10 s", "motion  2.5/4.0 s", "pass 2", "cycle 40"],  # play's: numbers padded after a label
        ["t=  3.0 s", "cycle 9", "rate  35.8 of 100 Hz (avg  35.7)", "answering 2/2", "errors 0"],
    ],
    ids=["teach", "play", "monitor"],
)
def test_a_status_line_tells_its_fields_from_a_number_padded_to_its_width(fields: list[str]) -> None:
    # teach's "... (the first pose is at 1 s)  12" / "pose(s) captured" at 40 columns: a count cut from its words.
    text = "  ".join(fields)
    for columns in range(20, len(text) + 2):
        lines = status_drawn(text, columns)
        for field in fields:
            if len(field) <= columns:
                assert any(field in line for line in lines), (columns, field, lines)
