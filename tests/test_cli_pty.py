"""``ics35`` as a real process on a real serial boundary: the simulator served on a pty.

Every command here is a subprocess (``python -m ics35_async.cli``) opening the
pty the simulator subprocess prints, exactly as a user's shell would.  The
servers run in real time (the pty server's default); the reply allowance
(``--timeout``) is the timing profile's no-timeouts one, long enough for a
loaded CI machine, and ``--retries`` covers a rare late reply.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import re
import select
import signal
import subprocess
import sys
import termios
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from ics35_async.robot import load_description
from ics35_async.sim import serving
from tests.support.cli_runs import PRESS_AT_A_CALL, run_process
from tests.support.terminal import TerminalOutput, Unread, screen_of, typed_on_a_terminal
from tests.support.timing import PATIENT_OPTION, scaled

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"

pytestmark = [
    pytest.mark.pty,
    pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the pty simulator needs Linux"),
]

SIM_IDS = [2, 5, 17]
SIM_BAUD = 625000
# For commands to servos that are there, every one expected to answer: long enough for a machine stalled
# for half a second (a timeout costs it only where a reply never comes).
ANSWERED = [*PATIENT_OPTION, "--retries", "1"]


def ics35(port: str, *args: str, stdin: str = "", timeout: float = 60) -> subprocess.CompletedProcess[str]:
    return run_process("--port", port, *args, stdin=stdin, timeout=timeout)


def json_of(port: str, *args: str) -> Any:
    """What ``ics35 ... --json`` printed; a failed command fails the test with what it said."""
    proc = ics35(port, *args, "--json")
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)


@pytest.fixture(scope="module")
def port() -> Iterator[str]:
    """Three servos at 625000 baud on a pty."""
    with serving(["--ids", ",".join(map(str, SIM_IDS)), "--baud", str(SIM_BAUD)]) as path:
        yield path


@pytest.mark.slow
def test_scan_finds_exactly_the_simulated_ids_at_their_baud(port: str) -> None:
    # Every present servo must answer (the patient allowance); two IDs nobody has are asked too.
    ids = ",".join(str(i) for i in sorted({0, 31, *SIM_IDS}))
    proc = ics35(port, *ANSWERED, "scan", "--bauds", "115200,625000", "--ids", ids, "--json")
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(proc.stdout)
    assert [(s["id"], s["baud"]) for s in doc["servos"]] == [(i, SIM_BAUD) for i in SIM_IDS]
    assert all(s["eeprom"]["baud_rate"] == SIM_BAUD for s in doc["servos"])
    assert doc["garbled"] == []


def test_python_m_ics35_async_is_the_command_line(port: str) -> None:
    # `python -m ics35_async` said "No module named ics35_async.__main__"; the docs' `-m ics35_async.cli` worked.
    command = ["--port", port, "--baud", str(SIM_BAUD), *ANSWERED, "get", str(SIM_IDS[0]), "speed", "--json"]
    done = subprocess.run([sys.executable, "-m", "ics35_async", *command], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout == ics35(*command[1:]).stdout


def test_json_read_commands_parse(port: str) -> None:
    baud = ["--baud", str(SIM_BAUD), *ANSWERED]
    info = json_of(port, *baud, "info", "5", "--free")
    assert info["eeprom"]["servo_id"] == 5 and info["free"] is True
    got = json_of(port, *baud, "get", "17", "stretch")
    assert got == {"id": 17, "param": "stretch", "value": 30, "memory": "RAM"}  # factory gain 60 = RAM 30
    moved = json_of(port, *baud, "move", "2", "--deg", "10")
    assert moved["target"] == 7796


def test_wrong_baud_exit_code(port: str) -> None:
    # The garbled bytes that tell a wrong rate must come within the allowance: the no-timeouts one.
    proc = ics35(port, *ANSWERED, "get", "5", "speed")
    assert proc.returncode == 6
    assert f"--baud {SIM_BAUD}" in proc.stderr


def test_eeprom_dump_restore_round_trip(port: str, tmp_path: Path) -> None:
    baud = ["--baud", str(SIM_BAUD), *ANSWERED]
    backup = tmp_path / "servo5.json"
    proc = ics35(port, *baud, "eeprom", "dump", "5")
    assert proc.returncode == 0, proc.stderr
    backup.write_text(proc.stdout)
    original = json.loads(proc.stdout)

    proc = ics35(port, *baud, "eeprom", "set", "5", "speed=77", "punch=3", "flags=PWMINH", "--yes")
    assert proc.returncode == 0, proc.stderr
    changed = json.loads(ics35(port, *baud, "eeprom", "dump", "5").stdout)
    assert (changed["fields"]["speed"], changed["fields"]["punch"], changed["fields"]["flags"]) == (77, 3, 8)

    proc = ics35(port, *baud, "eeprom", "restore", "5", str(backup), "--yes")
    assert proc.returncode == 0, proc.stderr
    restored = json.loads(ics35(port, *baud, "eeprom", "dump", "5").stdout)
    assert restored["fields"] == original["fields"]
    assert restored["raw"] == original["raw"]  # calibration bytes included


@pytest.mark.slow
def test_monitor_and_demo_run_and_leave_servos_free(port: str) -> None:
    baud = ["--baud", str(SIM_BAUD), *ANSWERED]
    proc = ics35(port, *baud, "monitor", "--free", "2,5,17", "--seconds", "1", "--json")
    assert proc.returncode == 0, proc.stderr
    final = json.loads(proc.stdout.splitlines()[-1])
    assert final["final"] is True
    # Every servo was read.  Not "all answered the last cycle": on a loaded machine a stream read may
    # give up early on a late reply, and its servo then sits out the rest of its allowance (see
    # engine.probe), which the last frame can show.
    assert all(final["servos"][str(i)]["position"] is not None for i in SIM_IDS), final

    proc = ics35(port, *baud, "demo", "--ids", "2,5,17", "--seconds", "1")
    assert proc.returncode == 0, proc.stderr
    assert "left free" in proc.stdout
    # A free servo draws no current in the simulator; a holding one does.
    for i in SIM_IDS:
        got = json_of(port, *baud, "get", str(i), "current")
        assert got["current"]["magnitude"] == 0


def test_demo_that_loses_its_port_says_the_servos_may_hold_and_how_to_free_them(pty_sim: Any) -> None:
    """demo promises free servos at its end; with the port gone it could not send free: the error says so and
    gives the free command for this very line (its --port and line options), which works once it is back."""
    # Unplugged by the traffic (after a few dozen transactions), not by the clock: a loaded machine can take
    # longer than any fixed delay to start the command.
    server = pty_sim("--ids", "1-3", "--faults", "unplug@1-3:0.02", "--seed", "1", "--replug-after", "1.0")
    # The patient allowance: the free that follows the replug must be answered on a loaded machine too.
    proc = ics35(server.path, *ANSWERED, "demo", "--ids", "1-3", "--seconds", "10")
    assert proc.returncode == 1, proc.stderr
    text = " ".join(proc.stderr.split())
    assert "may still be holding" in text, proc.stderr
    command = f"ics35 --port {server.path} {' '.join(ANSWERED[:2])} free 1-3"
    assert f"once the line is back, free them with: {command}" in text, proc.stderr
    deadline = time.monotonic() + 10
    while not Path(server.path).exists():
        assert time.monotonic() < deadline, "the port never came back"
        time.sleep(0.05)
    time.sleep(0.3)
    freed = subprocess.run([sys.executable, "-m", "ics35_async.cli", *command.split()[1:]], capture_output=True)
    assert freed.returncode == 0, freed.stderr


def demo_interrupted(
    port: str, after: float, *signals: int, gap: float = 0.0, wrapper: tuple[str, ...] = ()
) -> tuple[subprocess.Popen[str], str, str]:
    """``ics35 demo`` on ``port`` (under ``wrapper``, e.g. nohup), sent ``signals`` (Ctrl-C when none)
    ``after`` seconds past its title line, ``gap`` seconds apart."""
    baud = ["--baud", str(SIM_BAUD), *ANSWERED]
    command = [
        sys.executable,
        "-m",
        "ics35_async.cli",
        "--port",
        port,
        *baud,
        "demo",
        "--ids",
        "2,5",
        "--seconds",
        "60",
    ]
    proc = subprocess.Popen([*wrapper, *command], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        first = proc.stdout.readline()  # the title: the demo is running
        assert "demo" in first
        time.sleep(after)
        for k, signum in enumerate(signals or (signal.SIGINT,)):
            if k:
                time.sleep(gap)
            proc.send_signal(signum)
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return proc, out, err


@pytest.mark.parametrize(
    ("command", "above", "unbuffered"),
    [
        (["demo"], ["note: no --port given: this is the built-in simulator", "demo: wave on 32 servo(s)"], ""),
        (["demo"], ["note: no --port given: this is the built-in simulator", "demo: wave on 32 servo(s)"], "1"),
        (["teach", "{robot}", "{taught}", "--yes"], ["the joints are free: pose the robot by hand", "teach: /"], ""),
    ],
    ids=["demo", "demo-unbuffered", "teach"],
)
def test_ctrl_c_while_a_terminal_is_behind_leaves_the_lines_above_a_live_view(
    tmp_path: Path, command: list[str], above: list[str], unbuffered: str
) -> None:
    # At Ctrl-C a terminal discards what the program wrote and it has not read yet, and Python run unbuffered
    # (PYTHONUNBUFFERED, as many container images set it) drops what a write cut short by the signal had left: a
    # terminal behind (a loaded machine, an ssh link) lost the rest of a redraw, the cursor was not where the view
    # thought, and its next redraw, moving up by the view's height from there, wiped the lines above it.
    robot = tmp_path / "arm.toml"
    robot.write_text(CALIBRATED)
    args = [word.format(robot=robot, taught=tmp_path / "wave.json") for word in command]
    shown = "answering" if command == ["demo"] else "captured"
    # (a few seconds unread: ten redraws a second fill the pty's buffer, and the view's writes wait for room)
    keys = [(shown, b""), (Unread(scaled(3)), b"\x03")]
    _, written = typed_on_a_terminal(args, keys, env={"PYTHONUNBUFFERED": unbuffered})
    screen = screen_of(written, width=120)
    said = "\n".join(screen)
    assert "Traceback" not in written, said
    # The lines above the view, then the view's title (its first line) once: not overwritten, nor left behind by a
    # redraw starting elsewhere.
    assert [sum(shown.startswith(line) for shown in screen) for line in above] == [1] * len(above), said


def test_ctrl_c_leaves_a_live_view_right_below_the_line_above_it() -> None:
    # The ^C the terminal echoed was cleared as the view stopped, through the view's own redirection of stderr,
    # which printed that clearing as a line above the view: an empty line came between the note and the table.
    _, written = typed_on_a_terminal(["demo"], [("answering", b""), (scaled(0.5), b"\x03")])
    screen = screen_of(written, width=120)
    said = "\n".join(screen)
    assert "Traceback" not in written, said
    title = next(k for k, line in enumerate(screen) if line.startswith("demo: wave on 32 servo(s)"))
    assert screen[title - 1].startswith("note: no --port given: this is the built-in simulator"), said


def test_a_live_views_ctrl_c_discards_a_half_typed_line_and_the_terminal_gets_its_setting_back() -> None:
    # The terminal keeps its output at Ctrl-C while a live view runs (so that a redraw arrives whole), which keeps
    # what was typed ahead too: a half-typed line was left to the shell's prompt, where the press discarded it.
    master, slave = os.openpty()
    before = termios.tcgetattr(slave)

    def own_terminal() -> None:
        os.setsid()
        fcntl.ioctl(0, termios.TIOCSCTTY, 0)
        signal.signal(signal.SIGINT, signal.SIG_DFL)

    args = ["--port", "sim://?ids=1-3&realtime=1", "monitor", "1-3", "--free", "--seconds", "60"]
    proc = subprocess.Popen(
        [sys.executable, "-m", "ics35_async.cli", *args],
        stdin=slave,
        stdout=slave,
        stderr=slave,
        preexec_fn=own_terminal,
        env={**os.environ, "TERM": "xterm", "COLUMNS": "120"},
    )
    screen = TerminalOutput(master)
    try:
        screen.read_until(screen.shows("cycle"), scaled(30))
        os.write(master, b"half a line")
        screen.read_until(screen.shows("half a line"), scaled(10))  # (echoed: in the terminal's input)
        os.write(master, b"\x03")
        screen.read_until(lambda: proc.poll() is not None, scaled(30))
        assert proc.wait(scaled(30)) == 0, screen.text
        after = termios.tcgetattr(slave)
        raw = list(after)
        raw[3] &= ~termios.ICANON  # (what a shell's line editor does: a half-typed line becomes its input)
        raw[6] = list(raw[6])
        raw[6][termios.VMIN], raw[6][termios.VTIME] = 0, 0
        termios.tcsetattr(slave, termios.TCSANOW, raw)
        left = os.read(slave, 100)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        os.close(master)
        os.close(slave)
    assert left == b"", left
    assert after[3] == before[3], "the terminal's own setting is put back as the command ends"


def assert_demos_servos_free(port: str) -> None:
    for i in (2, 5):
        got = json_of(port, "--baud", str(SIM_BAUD), *ANSWERED, "get", str(i), "current")
        assert got["current"]["magnitude"] == 0


def test_demo_stops_on_ctrl_c_and_frees_the_servos(port: str) -> None:
    proc, out, err = demo_interrupted(port, 0.3)
    assert proc.returncode == 0, err
    assert "demo stopped by Ctrl-C after" in out and "left free" in out
    assert_demos_servos_free(port)


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP], ids=["SIGTERM", "SIGHUP"])
def test_demo_ended_by_a_service_manager_or_a_closed_terminal_frees_the_servos(port: str, signum: int) -> None:
    # SIGTERM (systemd, kill) and SIGHUP (the terminal closed) end it as Ctrl-C does, servos freed;
    # the exit code says which signal it was.
    proc, out, err = demo_interrupted(port, 0.3, signum)
    assert proc.returncode == 128 + signum, err
    assert "Traceback" not in err
    # (output to a pipe still comes after SIGHUP: only a terminal's goes to /dev/null)
    assert f"demo stopped by {signal.Signals(signum).name} after" in out and "left free" in out
    assert_demos_servos_free(port)


def test_a_second_stop_signal_does_not_cut_the_first_ones_cleanup_short(port: str) -> None:
    # Closing a terminal often sends SIGHUP twice (the shell to its jobs, the kernel to the foreground
    # group); the second must not interrupt the freeing the first began.
    proc, out, err = demo_interrupted(port, 0.3, signal.SIGHUP, signal.SIGHUP, gap=0.01)
    assert proc.returncode == 128 + signal.SIGHUP, err
    assert "Traceback" not in err and "left free" in out, err
    assert_demos_servos_free(port)


def test_a_command_started_ignoring_sighup_keeps_running_when_the_terminal_closes(port: str) -> None:
    # `nohup ics35 demo ...`: SIGHUP ignored from the start stays ignored (SIGTERM half a second
    # later ends it: had the SIGHUP stopped it, the exit code would say so).
    proc, out, err = demo_interrupted(port, 0.0, signal.SIGHUP, signal.SIGTERM, gap=0.5, wrapper=("nohup",))
    assert proc.returncode == 128 + signal.SIGTERM, err
    assert "demo stopped by SIGTERM after" in out


def test_demos_summary_counts_the_wave_not_the_scan_and_the_question(port: str) -> None:
    # No IDs: it scans and asks; the answer comes two seconds later.  The summary's time is the wave's.
    baud = ["--baud", str(SIM_BAUD), *ANSWERED]
    proc = subprocess.Popen(
        [sys.executable, "-m", "ics35_async.cli", "--port", port, *baud, "demo", "--seconds", "1"],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        time.sleep(2.0)
        out, err = proc.communicate("y\n", timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, err
    (summary,) = [ln for ln in out.splitlines() if ln.startswith("demo done after")]
    took = float(summary.split("after ")[1].split(" s")[0])
    assert 0.5 <= took < 2.0, summary  # (the last frame's time: a stall near the end may leave it short of 1 s)


def test_demo_stopped_before_its_first_frame_is_no_error(port: str) -> None:
    # Ctrl-C before any cycle ended (at once, or on a slow machine): nothing is known of the
    # servos, so no "no servo answered"; the stop is the one the user asked for.
    proc, out, err = demo_interrupted(port, 0.0)
    assert proc.returncode == 0, err
    assert "demo stopped by Ctrl-C after" in out and "no servo" not in err


def run_set_id(ids: str, new: int, *extra: str) -> tuple[subprocess.CompletedProcess[str], Any]:
    # Every reply counted: the patient allowance, and the scan after asks only the IDs involved.
    with serving(["--ids", ids]) as path:
        proc = ics35(path, *ANSWERED, "set-id", str(new), *extra)
        scan = json.loads(
            ics35(path, *ANSWERED, "scan", "--bauds", "115200", "--ids", f"{ids},{new}", "--quick", "--json").stdout
        )
    return proc, [s["id"] for s in scan["servos"]]


@pytest.mark.slow
def test_set_id_refused_with_two_devices() -> None:
    proc, ids_after = run_set_id("3,4", 9, "--yes")
    assert proc.returncode == 5
    assert "2 servos answer" in proc.stderr
    assert ids_after == [3, 4]


def test_set_id_works_with_one_device() -> None:
    proc, ids_after = run_set_id("3", 9, "--yes", "--json")
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout) == {"old": 3, "new": 9, "changed": True}
    assert ids_after == [9]


@contextlib.contextmanager
def ics35_sim(ids: str, *, wrapper: tuple[str, ...] = ()) -> Iterator[tuple[subprocess.Popen[str], str]]:
    """``ics35 sim --ids IDS`` in a process of its own (started through ``wrapper``, e.g. ``nohup``): the process
    and the path of its pty; terminated after the block."""
    sim = subprocess.Popen(
        [*wrapper, sys.executable, "-m", "ics35_async.cli", "sim", "--ids", ids],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert sim.stdout is not None
        path = sim.stdout.readline().strip()
        assert path, sim.stderr.read() if sim.stderr else ""
        yield sim, path
    finally:
        sim.terminate()
        sim.communicate(timeout=10)


def test_ics35_sim_serves_a_line_other_commands_can_open() -> None:
    with ics35_sim("4,6") as (sim, path):
        proc = ics35(path, *ANSWERED, "scan", "--bauds", "115200", "--ids", "4-6", "--quick", "--json")
        assert [s["id"] for s in json.loads(proc.stdout)["servos"]] == [4, 6]
    assert sim.returncode == 0


def test_ics35_sim_started_ignoring_sighup_keeps_serving_when_the_terminal_closes() -> None:
    # `nohup ics35 sim --link ... &`, as every other command: SIGHUP ignored from the start stays ignored (it
    # took SIGHUP over and ended with the terminal); SIGTERM still ends it.
    with ics35_sim("4", wrapper=("nohup",)) as (sim, path):
        sim.send_signal(signal.SIGHUP)
        time.sleep(0.5)
        assert sim.poll() is None, sim.communicate(timeout=10)
        proc = ics35(path, *ANSWERED, "scan", "--bauds", "115200", "--ids", "4", "--quick", "--json")
        assert [s["id"] for s in json.loads(proc.stdout)["servos"]] == [4]
    assert sim.returncode == 0


CALIBRATED = """\
[lines.main]
port = "sim://ctrl-c-arm?ids=1-2&realtime=1"

[joints.a]
line = "main"
id = 1

[joints.b]
line = "main"
id = 2
"""


@contextlib.contextmanager
def a_line_with_no_servo() -> Iterator[tuple[str, Any]]:
    """A pty as a line with no servo on it: its path, and a check for ``typed_on_a_terminal``'s keys that echoes
    what the command sent (as a line's adapter does) and says whether it has sent anything yet: the command is
    then on its event loop (its port is opened there), wherever the machine's load has it in time."""
    master, slave = os.openpty()
    sent: list[bytes] = []

    def sending() -> bool:
        while select.select([master], [], [], 0)[0]:
            chunk = os.read(master, 4096)
            os.write(master, chunk)
            sent.append(chunk)
        return bool(sent)

    try:
        yield os.ttyname(slave), sending
    finally:
        os.close(master)
        os.close(slave)


@pytest.mark.parametrize(
    ("args", "when", "first"),
    [
        # A one-shot command waiting for a silent servo: the message came right after the echoed ^C.  Pressed as
        # it waits for the answer to its first command (at a fixed time, a loaded machine was still loading it).
        (
            ["--port", "{line}", "--timeout", "3", "--retries", "3", "get", "5", "speed"],
            "{sent}",
            "error: interrupted",
        ),
        # With -v the log's lines as the command stops ("closed ..."): the first came right after the ^C.
        (["--port", "{line}", "--timeout", "3", "-v", "get", "5", "speed"], "{sent}", "error: interrupted"),
        # doctor prints its report after the Ctrl-C, then the error: the report's first line came after the ^C.
        # (32 servos' 1000 reads each take half a minute: the Ctrl-C lands while they run, also on a machine
        # slow to load the command line, 1.5 s under the stress run's burners)
        (["doctor", "--port", "sim://?ids=0-31&realtime=1", "--samples", "1000"], 3.0, "compiled stream path: "),
        # calibrate's live view: its last redraw and the message after it.
        (["calibrate", "{robot}"], "neutral pose   Enter", "error: interrupted: nothing written to"),
    ],
    ids=["get", "get -v", "doctor", "calibrate"],
)
def test_what_is_said_after_ctrl_c_starts_on_a_line_of_its_own(
    tmp_path: Path, args: list[str], when: str | float, first: str
) -> None:
    robot = tmp_path / "arm.toml"
    robot.write_text(CALIBRATED)
    with a_line_with_no_servo() as (line, sending):
        press = sending if when == "{sent}" else scaled(when) if isinstance(when, float) else when
        code, written = typed_on_a_terminal([a.format(robot=robot, line=line) for a in args], [(press, b"\x03")])
    screen = screen_of(written)
    assert code == 130, "\n".join(screen)
    assert "Traceback" not in written, written
    assert not any("^C" in line and line != "^C" for line in screen), "\n".join(screen)  # never beside other text
    assert any(line.startswith(first) for line in screen), "\n".join(screen)
    assert any(line.startswith("error: interrupted") for line in screen), "\n".join(screen)


@pytest.mark.parametrize(
    ("args", "said"),
    [
        (["--port", "sim://?ids=1-3&realtime=1", "demo", "--ids", "1-3", "--seconds", "30"], "stopping:"),
        (
            ["--timeout", "0.5", "play", str(EXAMPLES / "humanoid.toml"), str(EXAMPLES / "wave.json")],
            "stopped by Ctrl-C: slowing",
        ),
    ],
    ids=["demo", "play"],
)
def test_what_is_said_as_ctrl_c_is_handled_starts_a_line_of_its_own_when_the_output_goes_to_a_file(
    tmp_path: Path, args: list[str], said: str
) -> None:
    # Output to a file, notes on the terminal: the note said at the Ctrl-C followed the echoed ^C.  Typed once the
    # command has run a second (its first line a second in the file; a loaded machine starts it late).
    out = tmp_path / "out.txt"

    def running() -> bool:
        return out.exists() and "\nt=" in out.read_text(errors="replace")

    _, written = typed_on_a_terminal(args, [(running, b"\x03")], stdout=out)
    screen = screen_of(written)
    assert "Traceback" not in written, written
    assert not any("^C" in line and line != "^C" for line in screen), "\n".join(screen)
    assert any(line.startswith(said) for line in screen), "\n".join(screen)


def test_the_simulators_last_words_after_ctrl_c_start_a_line_of_their_own() -> None:
    code, written = typed_on_a_terminal(["sim", "--ids", "1"], [("ics35 sim: 1 servo ", b"\x03")])
    screen = screen_of(written)
    assert code == 0, "\n".join(screen)
    assert any(line.startswith("ics35 sim: served 0 transactions") for line in screen), "\n".join(screen)


# A process on a terminal of its own (its controlling one: a new session), in the terminal's foreground
# process group or, forked, in a background one; it clears "the ^C line" on stderr, the terminal.
_ON_A_TERMINAL = """
import os, sys
os.setsid()
tty = os.open(sys.argv[1], os.O_RDWR)  # (the session's first terminal opened: its controlling one)
if sys.argv[2] == "background":
    pid = os.fork()
    if pid:
        os.waitpid(pid, 0)
        os._exit(0)
    os.setpgid(0, 0)  # a process group of its own: not the terminal's foreground one
sys.stderr = os.fdopen(tty, "w")
from ics35_async.terminal import clear_echoed_ctrl_c
clear_echoed_ctrl_c()
sys.stderr.write("said\\n")
sys.stderr.flush()
"""


@pytest.mark.parametrize("group", ["foreground", "background"])
def test_the_ctrl_c_line_is_cleared_only_on_the_terminal_the_process_is_in_the_foreground_of(group: str) -> None:
    # A background process sent SIGINT (kill -INT) echoes no ^C: the line where the cursor is, then, is the
    # shell's prompt with what the person is typing; clearing it wiped that.
    master, slave = os.openpty()
    try:
        path = os.ttyname(slave)
        os.close(slave)
        proc = subprocess.run(
            [sys.executable, "-c", _ON_A_TERMINAL, path, group], stdout=subprocess.PIPE, timeout=30, check=True
        )
        written = b""
        while select.select([master], [], [], 0.5)[0]:
            try:
                chunk = os.read(master, 4096)
            except OSError:  # (the terminal's last process has closed it)
                break
            if not chunk:
                break
            written += chunk
    finally:
        os.close(master)
    assert proc.returncode == 0 and b"said" in written, written
    assert (b"\x1b[2K" in written) == (group == "foreground"), written


_STOPPING_ON_A_TERMINAL = """
import os, signal, sys, time
os.setsid()
tty = os.open(sys.argv[1], os.O_RDWR)  # (the session's first terminal opened: its controlling one)
sys.stderr = os.fdopen(os.dup(tty), "w")  # (tty itself open until the process is gone)
from ics35_async.terminal import ctrl_c_typed
presses = []
def on_sigint(signum, frame):
    presses.append(signum)
    ctrl_c_typed()  # (as the command line's handler does at each press)
signal.signal(signal.SIGINT, on_sigint)
os.write(tty, b"ready\\n")
while not presses:
    time.sleep(0.001)
os.write(tty, b"stopping\\n")
for i in range(int(sys.argv[2])):  # its last words, line by line, as more presses come
    os.write(tty, b"line %d\\n" % i)
    time.sleep(0.0002)
signal.signal(signal.SIGINT, signal.SIG_IGN)  # (as the command line's own end does: see running._ignore_at_exit)
os.write(tty, b"end\\n")
"""


def test_a_stopping_commands_last_words_survive_more_ctrl_c_presses() -> None:
    # A terminal discards what a program wrote and it has not shown yet at each Ctrl-C (unless NOFLSH): a double
    # Ctrl-C's second press, landing as calibrate said what it left, took the hint "the joints it opened are left
    # free" off the screen.  Once a Ctrl-C has stopped the command, a later one must not take its last words.
    lost, no_flush_after = _last_words_lost_on_a_terminal(_STOPPING_ON_A_TERMINAL, 1500, pressing=True)
    assert lost == [], f"{len(lost)} line(s) of its last words lost"
    assert not no_flush_after, "the terminal's own setting is put back as the command ends"


def _last_words_lost_on_a_terminal(script: str, lines: int, *, pressing: bool) -> tuple[list[int], bool]:
    """Run ``script`` (its terminal's path and ``lines`` its arguments) on a pty, read as a terminal does, and
    return the lines of its last words (``line N``) that never reached the terminal, and whether the terminal
    kept its output at Ctrl-C (NOFLSH) once the script had ended.  ``pressing``: type Ctrl-C once the script
    says ``ready``, then at each pass once it says ``stopping`` and until it says ``end``; else read 4 KiB each
    5 ms (a terminal reading a little behind: a loaded machine, an ssh link)."""
    master, slave = os.openpty()
    try:
        proc = subprocess.Popen([sys.executable, "-c", script, os.ttyname(slave), str(lines)])
        written = b""
        deadline = time.monotonic() + scaled(30)
        pressed = False
        while proc.poll() is None or select.select([master], [], [], 0.2)[0]:
            assert time.monotonic() < deadline, written[-300:]
            if pressing and b"ready" in written and not pressed:
                os.write(master, b"\x03")
                pressed = True
            elif pressing and b"stopping" in written and b"end" not in written:
                os.write(master, b"\x03")  # (a press every millisecond or so as it says its last words)
            if select.select([master], [], [], 0.001 if pressing else 0.005)[0]:
                written += os.read(master, 65536 if pressing else 4096)
                if not pressing:
                    time.sleep(0.005)
        no_flush_after = bool(termios.tcgetattr(master)[3] & termios.NOFLSH)  # (the pty's settings, from its master)
    finally:
        os.close(master)
        os.close(slave)
    assert proc.wait(scaled(30)) == 0
    # (A press's echoed ^C lands between two of the terminal's output blocks, which on a full pty buffer can be in
    # the middle of a line's number: "line 6^C0".)
    said = {int(number) for number in re.findall(rb"line (\d+)", written.replace(b"^C", b""))}
    return sorted(set(range(lines)) - said), no_flush_after


# Its last words written at once as it ends, and a press just after (TIOCSTI: typed from inside, at that moment),
# on a terminal that reads them a little behind (a loaded machine, an ssh link).
_ENDING_ON_A_TERMINAL = """
import atexit, fcntl, os, signal, sys, termios
os.setsid()
tty = os.open(sys.argv[1], os.O_RDWR)  # (the session's first terminal opened: its controlling one)
sys.stderr = os.fdopen(os.dup(tty), "w")  # (tty itself open until the process is gone)
from ics35_async.terminal import ctrl_c_typed

def press_as_it_ends():
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # (as the command line's own end does)
    fcntl.ioctl(tty, termios.TIOCSTI, b"\\x03")

atexit.register(press_as_it_ends)  # (registered first: run last, once the terminal has its own setting back)
signal.signal(signal.SIGINT, lambda signum, frame: ctrl_c_typed())
fcntl.ioctl(tty, termios.TIOCSTI, b"\\x03")  # the first press (its handler runs before the next line)
os.write(tty, b"".join(b"line %d\\n" % i for i in range(int(sys.argv[2]))))
"""


def test_last_words_written_as_the_command_ends_survive_a_press_as_it_ends() -> None:
    # The setting put back at once as the process ended: a press landing just after discarded what the terminal
    # had not read yet (calibrate's error and hint, under a loaded test run).
    lost, no_flush_after = _last_words_lost_on_a_terminal(_ENDING_ON_A_TERMINAL, 1000, pressing=False)
    assert lost == [], f"{len(lost)} line(s) of its last words lost"
    assert not no_flush_after, "the terminal's own setting is put back as the command ends"


# Two presses (TIOCSTI: typed from inside), the first noted as the command line's handler notes it, then its
# last words.
_TWO_PRESSES_ON_A_TERMINAL = """
import fcntl, os, signal, sys, termios
os.setsid()
tty = os.open(sys.argv[1], os.O_RDWR)  # (the session's first terminal opened: its controlling one)
sys.stderr = os.fdopen(os.dup(tty), "w")
from ics35_async.terminal import clear_echoed_ctrl_c, ctrl_c_typed

signal.signal(signal.SIGINT, lambda signum, frame: ctrl_c_typed())
fcntl.ioctl(tty, termios.TIOCSTI, b"\\x03")  # the first press (its handler runs before the next line)
clear_echoed_ctrl_c()
signal.signal(signal.SIGINT, signal.SIG_IGN)  # (the second is taken for the same stop)
fcntl.ioctl(tty, termios.TIOCSTI, b"\\x03")  # the second, as the command says what it left
os.write(tty, b"wrote 1 pose(s)\\n")
"""


def test_a_second_press_once_a_ctrl_c_has_stopped_the_command_echoes_no_c_before_its_last_words() -> None:
    # The terminal echoed the second press's ^C where the last words were about to start: "^Cwrote 1 pose(s) ...",
    # whenever it came between the first press's clearing and the words (teach, eeprom set, a few runs in a
    # hundred).  Once a Ctrl-C has stopped the command the terminal echoes no more ^C, until it ends.
    master, slave = os.openpty()
    try:
        echoctl_before = bool(termios.tcgetattr(master)[3] & termios.ECHOCTL)
        proc = subprocess.Popen([sys.executable, "-c", _TWO_PRESSES_ON_A_TERMINAL, os.ttyname(slave)])
        written = b""
        deadline = time.monotonic() + scaled(30)
        while proc.poll() is None or select.select([master], [], [], 0.2)[0]:
            assert time.monotonic() < deadline, written[-300:]
            if select.select([master], [], [], 0.01)[0]:
                written += os.read(master, 65536)
        echoctl_after = bool(termios.tcgetattr(master)[3] & termios.ECHOCTL)
    finally:
        os.close(master)
        os.close(slave)
    assert proc.wait(scaled(30)) == 0
    assert echoctl_before, "a pty echoes control characters as ^C by default"
    assert written.count(b"^C") == 1, written  # the first press's, cleared; none for the second
    assert written.rstrip().endswith(b"wrote 1 pose(s)") and b"^Cwrote" not in written, written
    assert echoctl_after, "the terminal's own setting is put back as the command ends"


def test_no_terminal_control_goes_into_a_file_whatever_the_colour_settings_say(tmp_path: Path) -> None:
    # FORCE_COLOR makes the console library treat a file as a terminal: the clearing went into the log.
    log = tmp_path / "err.log"
    with log.open("w") as stderr:
        code = subprocess.run(
            [sys.executable, "-c", "from ics35_async.terminal import clear_echoed_ctrl_c; clear_echoed_ctrl_c()"],
            stdout=subprocess.PIPE,
            stderr=stderr,
            env={**os.environ, "FORCE_COLOR": "1", "TTY_COMPATIBLE": "1"},
            timeout=30,
        ).returncode
    assert code == 0 and log.read_bytes() == b""


ARM_WITH_AN_UNPLUGGED_HAND = """\
[lines.main]
port = "sim://{name}?ids=1-2&realtime=1&turnaround={turnaround}&record={record}"

[joints.a]
line = "main"
id = 1

[joints.b]
line = "main"
id = 2

[joints.hand]
line = "main"
id = 5
"""


def torque_commands_sent(record: Path) -> dict[int, list[int]]:
    """Every position or free command in a simulator's recording, by ID (0: free), decoded from the wire bytes."""
    from ics35_async.sim import load_recording

    sent: dict[int, list[int]] = {}
    for entry in load_recording(record):
        if entry.tx[0] & 0xE0 == 0x80 and len(entry.tx) == 3:
            sent.setdefault(entry.tx[0] & 0x1F, []).append((entry.tx[1] << 7) | entry.tx[2])
    return sent


def arm_interrupted_as_it_opens(tmp_path: Path, name: str, command: list[str], when: str) -> tuple[int, str, Path]:
    """``command`` (with the robot file's path first) on the arm whose hand is unplugged, the reply allowance long
    (its silent hand keeps the open waiting), Ctrl-C typed half a second after ``when`` is on the screen.  Its
    servos answer slowly (0.6 s after each command): the open's first cycle, once its warnings are said, takes
    over a second (the hand, found silent by the open, is not in it)."""
    record = tmp_path / "wire.txt"
    robot = tmp_path / "arm.toml"
    robot.write_text(ARM_WITH_AN_UNPLUGGED_HAND.format(name=name, record=record, turnaround=scaled(0.6)))
    args = ["-v", "--timeout", str(scaled(3.0)), command[0], str(robot), *command[1:]]
    code, written = typed_on_a_terminal(args, [(when, b""), (scaled(0.5), b"\x03")])
    return code, written, record


def test_ctrl_c_as_a_robot_command_reads_its_servos_says_nothing_was_sent_that_moves_or_frees_them(
    tmp_path: Path,
) -> None:
    # Typed as the open waits for the unplugged hand's EEPROM: it said only "interrupted", and the person could
    # not tell whether any servo had gone free.
    code, written, record = arm_interrupted_as_it_opens(
        tmp_path, "ctrl-c-open-reads", ["teach", str(tmp_path / "wave.json")], "opened sim://"
    )
    screen = screen_of(written)
    said = "\n".join(screen)
    assert code == 130, said
    assert "Traceback" not in written, said
    assert torque_commands_sent(record) == {}, said  # only reads went out
    assert any(line.startswith("error: interrupted while opening the robot:") for line in screen), said
    assert "no joint was sent anything that moves or frees it" in " ".join(said.split()), said


@pytest.mark.slow  # (its open waits whole allowances: the unplugged hand, joint a read once more)
def test_ctrl_c_as_a_robot_command_waits_for_its_first_pose_names_the_joints_it_freed_and_those_it_holds(
    tmp_path: Path,
) -> None:
    motion = tmp_path / "reach.json"
    motion.write_text(
        json.dumps(
            {
                "format": "ics35-motion",
                "version": 1,
                "keyframes": [{"time": 1.0, "pose": {"a": 10, "b": 10, "hand": 10}}],
            }
        )
    )
    # Typed once the open has started the stream (its warnings said), as it waits for the first cycle.
    code, written, record = arm_interrupted_as_it_opens(
        tmp_path, "ctrl-c-open-stream", ["play", str(motion), "--start-pose", "b=10"], "did not answer"
    )
    screen = screen_of(written)
    said = "\n".join(screen)
    assert code == 130, said
    assert "Traceback" not in written, said
    sent = torque_commands_sent(record)
    assert set(sent[1]) == {0}, sent  # a: freed, to read where it stands
    assert set(sent.get(5, [])) <= {0}, sent  # the hand, found silent: nothing, or its probe (a free)
    assert 0 not in sent[2], sent  # b: its stated angle only
    flat = " ".join(said.split())  # (the error wrapped at words, its further lines indented)
    assert any(line.startswith("error: interrupted while opening the robot:") for line in screen), said
    assert "joint a was freed" in flat and "joint b holds its stated angle" in flat, said
    # The hand's servo is not on the line: sent the free, it heard nothing of it.
    assert "joint hand never answered" in flat and "hand were freed" not in flat, said


@pytest.mark.parametrize("gap", [0.005, 0.01, 0.02, 0.03])
def test_a_double_ctrl_c_in_calibrate_still_says_what_it_left(tmp_path: Path, gap: float) -> None:
    # The second press landed as the first one's message was being made: "aborted" was all it said (nothing
    # of the file left untouched, nor of the joints left free), or it killed the process as Python ended.
    robot = tmp_path / "arm.toml"
    robot.write_text(CALIBRATED)
    keys = [("neutral pose   Enter", b"\r"), ("Enter: done", b"\x03"), (gap, b"\x03")]
    code, written = typed_on_a_terminal(["calibrate", str(robot)], keys)
    screen = screen_of(written)
    assert code == 130, "\n".join(screen)
    assert "Traceback" not in written and "aborted" not in written, "\n".join(screen)
    # (Anywhere on its line: the second press's ^C is echoed by the terminal whenever it lands, and one landing
    # between the first's clearing and the message stays in front of it.)
    assert any(f"error: interrupted: nothing written to {robot}" in line for line in screen), "\n".join(screen)
    assert any("the joints it opened are left free" in line for line in screen), "\n".join(screen)


@pytest.mark.parametrize("gap", [0.0, 0.005, 0.01, 0.02, 0.05])
def test_teachs_last_words_after_a_double_ctrl_c_start_a_line_of_their_own(tmp_path: Path, gap: float) -> None:
    # The second press, landing as teach ended (taken for the same stop), had its ^C echoed on the line its
    # last words then followed: "^Cwrote 1 pose(s) ...".  And landing as the robot closed (its joints free all
    # along, the poses written after), it ended teach as "error: interrupted", exit code 130: nothing was left
    # for it to cut short.
    robot = tmp_path / "arm.toml"
    robot.write_text(CALIBRATED)
    keys = [("0 pose(s) captured", b"\r"), ("1 pose(s) captured", b"\x03"), (gap, b"\x03")]
    code, written = typed_on_a_terminal(["teach", str(robot), str(tmp_path / "wave.json"), "--yes"], keys)
    screen = screen_of(written)
    assert code == 0, "\n".join(screen)
    assert any(line.startswith("wrote 1 pose(s) over ") for line in screen), "\n".join(screen)
    assert "interrupted" not in written and "forced out" not in written, "\n".join(screen)
    assert not any("^C" in line and line.strip("^C") for line in screen), "\n".join(screen)
    assert json.loads((tmp_path / "wave.json").read_text())["keyframes"], "\n".join(screen)


@pytest.mark.parametrize(
    "gaps", [[0.002], [0.005], [0.01], [0.02], [0.03], [0.05], [0.03, 0.005]], ids=lambda gaps: "+".join(map(str, gaps))
)
def test_a_double_ctrl_c_in_demo_says_what_the_servos_were_left_in(gaps: list[float]) -> None:
    # The second press forced the stop out as the servos were being freed: asyncio's runner, closing, then
    # printed the command's own account (the servos may still hold, and how to free them) as a traceback
    # and dropped it; landing as the runner closed, it left tracebacks of the loop and exit code 1.  Landing
    # once they had been freed (or a third press after it), the error said only "interrupted".
    args = ["--port", "sim://?ids=1-3&realtime=1", "demo", "--ids", "1-3", "--seconds", "30"]
    # (pressed once the wave is under way: on a loaded machine 1.5 s can pass before its first cycle, and a stop
    # forced out before the servos were sent anything has nothing to say of them)
    keys = [("cycle", b""), (scaled(0.5), b"\x03"), *((gap, b"\x03") for gap in gaps)]
    code, written = typed_on_a_terminal(args, keys)
    screen = screen_of(written)
    assert "Traceback" not in written and "Exception" not in written, "\n".join(screen)
    assert code in (0, 130), "\n".join(screen)
    said = "\n".join(screen)
    assert "servos left free" in said or "may still be holding" in said, said
    assert code == 0 or "error: interrupted" in said, said


def test_the_screen_shows_no_control_character_a_terminal_does_not_print() -> None:
    # Once a Ctrl-C has stopped the command the terminal echoes a later press raw (ECHOCTL off: see
    # ics35_async.terminal.keep_last_words), which a terminal does not print; the screen model printed it, in front of
    # the last words ("\x03error: interrupted"), and failed a test on what no one sees.
    assert screen_of("\x03error: interrupted\x07\r\n\x03\x03ok") == ["error: interrupted", "ok"]


@pytest.mark.parametrize(
    ("args", "when", "said"),
    [
        (
            ["--port", "sim://?ids=1-3&realtime=1", "demo", "--ids", "1-3", "--seconds", "30"],
            [("cycle", b""), (scaled(0.5), b"")],
            "error: interrupted",
        ),
        (
            ["--timeout", "0.5", "play", str(EXAMPLES / "humanoid.toml"), str(EXAMPLES / "wave.json")],
            [("cycles legs", b""), (scaled(1.0), b"")],  # (a second into the motion: the open's time varies)
            "error: interrupted",  # (": Ctrl-C again cut the slow-down short" once the slow-down had begun)
        ),
    ],
    ids=["demo", "play"],
)
def test_three_quick_ctrl_c_force_the_command_out_without_a_traceback(
    args: list[str], when: list[tuple[str | float, bytes]], said: str
) -> None:
    # The third press forces out at once; landing as the runner closed the loop, it left asyncio's and the
    # loop's tracebacks and exit code 1.
    code, written = typed_on_a_terminal(args, [*when, (0.0, b"\x03"), (0.005, b"\x03"), (0.005, b"\x03")])
    screen = screen_of(written)
    assert "Traceback" not in written and "Exception" not in written, "\n".join(screen)
    # (Nor what the stop had started and the loop left unrun: "coroutine ... was never awaited", at exit.)
    assert "Warning" not in written and "Task was destroyed" not in written, "\n".join(screen)
    if code == 0:  # the first press's stop was over before the others came: they were the same stop
        # (On failure, also the bytes written last: what drew over the screen shows only there.)
        assert any("stopped by Ctrl-C" in line for line in screen), "\n".join(screen) + f"\n{written[-1500:]!r}"
        return
    assert code == 130, "\n".join(screen)
    # On a line of its own, below the live table: a table whose stop the press cut short kept stdout and stderr
    # redirected through itself, and redrew its last line around the message ("cycle 509error: interrupted"), or
    # over it.  (A press's ^C may be echoed in front of it, after the clearing: the terminal's, not ours.)
    assert any(line.replace("^C", "").startswith(said) for line in screen), "\n".join(screen)


# A command's stop that starts more work (play's slow-down: a task per moving joint, in a task group), forced out
# as it does: the second press ends the run, the runner's close cancels the command again, and the third lands in
# the loop as the stop has just started its work, before that work's first step.  (run_robot runs a command inside
# warnings.catch_warnings, as here.)
_FORCED_OUT_AS_IT_STARTS_WORK = """
import asyncio, gc, inspect, os, signal, warnings
import anyio
from ics35_async.cli._loop import run_loop

def press():
    os.kill(os.getpid(), signal.SIGINT)  # (Ctrl-C's handler runs before the next line)

async def slow_down():
    await asyncio.sleep(1)

async def stop():
    async with anyio.create_task_group() as tasks:
        asyncio.get_running_loop().call_soon(press)  # the third
        tasks.start_soon(slow_down)
        tasks.start_soon(slow_down)

async def main():
    press()
    try:
        await asyncio.sleep(30)  # the first press cancels it
    finally:
        press()  # the second forces the command out
        try:
            await asyncio.sleep(30)  # the runner, closing, cancels it again
        finally:
            asyncio.ensure_future(stop())
            asyncio.ensure_future(slow_down())
            await asyncio.sleep(1)

with warnings.catch_warnings():
    try:
        run_loop(main)
    except KeyboardInterrupt:
        print("interrupted")
gc.collect()  # (what the process's end does, at once)
# What the process's end collects in whatever order it finds them: each coroutine never started says so then.
unstarted = [c for c in gc.get_objects() if inspect.iscoroutine(c) and inspect.getcoroutinestate(c) == "CORO_CREATED"]
assert not unstarted, unstarted
"""


def script_on_loop(loop: str, script: str, *args: str, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    """``python -c script args`` with ``ICS35_LOOP=loop``: what it printed and how it ended."""
    env = {**os.environ, "ICS35_LOOP": loop}
    return subprocess.run(
        [sys.executable, "-c", script, *args], capture_output=True, text=True, timeout=timeout, env=env
    )


# A third press landing in a weakref callback as the runner's close ran the command's cleanup again: Python prints
# an exception raised there ("Exception ignored in: <function WeakSet.__init__.<locals>._remove ...>" and its
# traceback, under demo's table) and drops it.  (signal.raise_signal runs the handler before it returns: inside the
# callback, at once.)
_FORCED_OUT_IN_A_CALLBACK = """
import asyncio, signal, weakref
from ics35_async.cli._loop import run_loop

class Thing:
    pass

async def main():
    signal.raise_signal(signal.SIGINT)
    try:
        await asyncio.sleep(30)  # the first press cancels it
    finally:
        signal.raise_signal(signal.SIGINT)  # the second forces the command out
        try:
            await asyncio.sleep(30)  # the runner, closing, cancels it again
        finally:
            thing = Thing()
            ref = weakref.ref(thing, lambda _: signal.raise_signal(signal.SIGINT))  # the third
            del thing
            await asyncio.sleep(30)  # forced out, it must not wait for this (dropped, the press did)

try:
    run_loop(main)
except KeyboardInterrupt:
    print("interrupted")
"""


# A stop whose own task fails as the third press lands (play's ``retrieved(robot.stop())``, its first step taken as
# the runner's close ran, the robot closed by then): the press stops the loop before the task's done callback, which
# retrieves its error, has run; the process's end then printed "Task exception was never retrieved" and the error's
# traceback under the command's message.
_FORCED_OUT_AS_A_STOP_FAILS = """
import asyncio, gc, os, signal
from ics35_async.cli._loop import run_loop
from ics35_async.tasks import retrieved

def press():
    os.kill(os.getpid(), signal.SIGINT)  # (Ctrl-C's handler runs before the next line)

async def stop():
    raise RuntimeError("the robot is closed")

async def main():
    press()
    try:
        await asyncio.sleep(30)  # the first press cancels it
    finally:
        press()  # the second forces the command out
        try:
            await asyncio.sleep(30)  # the runner, closing, cancels it again
        finally:
            retrieved(stop())  # its step fails next, and its done callback is queued behind the third press
            asyncio.get_running_loop().call_soon(press)  # the third
            await asyncio.sleep(30)

try:
    run_loop(main)
except KeyboardInterrupt:
    print("interrupted")
gc.collect()  # (what the process's end does, at once)
"""


# A task the second press cut off from the task group it ran in (play's robot cycles: anyio's cancel scope left
# mid-exit), cancelled by the runner's close, fails as it ends: the runner reported it ("unhandled exception during
# asyncio.run() shutdown", "Attempted to exit a cancel scope that isn't the current tasks's current cancel scope")
# and its traceback under the command's message.
_FORCED_OUT_WITH_A_TASK_CUT_OFF = """
import asyncio, os, signal
from ics35_async.cli._loop import run_loop

def press():
    os.kill(os.getpid(), signal.SIGINT)

async def cut_off():
    try:
        await asyncio.sleep(30)
    except asyncio.CancelledError:  # (as anyio's task does, its cancel scope no longer the current one)
        raise RuntimeError("Attempted to exit a cancel scope that isn't the current tasks's current cancel scope")

async def main():
    asyncio.create_task(cut_off())
    await asyncio.sleep(0)  # (it has started)
    press()
    try:
        await asyncio.sleep(30)  # the first press cancels it
    finally:
        press()  # the second forces the command out
        await asyncio.sleep(30)

try:
    run_loop(main)
except KeyboardInterrupt:
    print("interrupted")
"""


@pytest.mark.parametrize("loop", ["asyncio", "uvloop"])
@pytest.mark.parametrize(
    "script",
    [_FORCED_OUT_IN_A_CALLBACK, _FORCED_OUT_AS_A_STOP_FAILS, _FORCED_OUT_WITH_A_TASK_CUT_OFF],
    ids=["press-in-a-callback", "stop-failing", "a-task-cut-off"],
)
def test_what_a_press_forcing_the_command_out_cuts_short_is_not_printed_and_it_still_forces_out(
    loop: str, script: str
) -> None:
    done = script_on_loop(loop, script, timeout=scaled(15))  # (less than its 30 s wait)
    assert done.stdout == "interrupted\n", done.stderr
    assert done.stderr == "", done.stderr


# Ctrl-C as the command's loop is being made, or as the task that runs the command is (uvloop's loop, here a
# stand-in whose loop-making or task-making is where the press lands): the command's coroutine, made before, never
# ran, and Python said so as the process ended ("sys:1: RuntimeWarning: coroutine 'get.<locals>.body' was never
# awaited", under "error: interrupted"); closed while its task waited to start, the task failed ("Task exception
# was never retrieved ... cannot reuse already awaited coroutine").
_CTRL_C_AS_THE_LOOP_IS_MADE = """
import asyncio, gc, signal, sys, types

def press():
    signal.raise_signal(signal.SIGINT)  # (the handler runs before it returns)

def new_event_loop():
    if sys.argv[1] == "loop":
        press()
    loop = asyncio.new_event_loop()

    def task_factory(loop, coro, **options):
        task = asyncio.Task(coro, loop=loop, **options)
        press()
        return task

    loop.set_task_factory(task_factory)
    return loop

sys.modules["uvloop"] = types.SimpleNamespace(new_event_loop=new_event_loop)
from ics35_async.cli._loop import run_loop

async def body():
    pass

try:
    run_loop(body)
except KeyboardInterrupt:
    print("interrupted")
gc.collect()  # (what the process's end does, at once)
"""


@pytest.mark.parametrize("where", ["loop", "task"])
def test_a_command_interrupted_before_its_loop_ran_it_ends_without_a_warning(where: str) -> None:
    done = script_on_loop("uvloop", _CTRL_C_AS_THE_LOOP_IS_MADE, where)
    assert done.stdout == "interrupted\n", done.stderr
    assert done.stderr == "", done.stderr


# Ctrl-C as the runner closes the loop, the command's work over: uvloop runs Python's socket bookkeeping inside its
# own loop step (a profile hook presses there, as a press lands in the main thread between any two steps), and a
# KeyboardInterrupt raised there left the loop running and unclosable ("RuntimeError: Cannot close a running event
# loop", a traceback, exit code 1).
_PRESS_AS_THE_LOOP_CLOSES = (
    PRESS_AT_A_CALL
    + """
from ics35_async.cli import main

sys.setprofile(press)
main(["--port", "sim://", "get", "1", "stretch"])
"""
)


@pytest.mark.parametrize(
    ("loop", "where"),
    [
        ("uvloop", ("_decref_socketios", 1)),
        ("uvloop", ("_decref_socketios", 2)),
        ("asyncio", ("shutdown_asyncgens", 1)),
    ],
)
def test_ctrl_c_as_the_loop_closes_ends_in_one_line(loop: str, where: tuple[str, int]) -> None:
    done = script_on_loop(loop, _PRESS_AS_THE_LOOP_CLOSES, where[0], str(where[1]))
    assert (done.returncode, done.stderr) == (130, "error: interrupted\n"), done.stderr


# A later press landing in uvloop's own step as it starts or ends a run of the loop (the runner's close running the
# forced-out command's task to its end): uvloop marks itself running, then makes its self-pipe with Python's socket
# code (and closes it as the run ends, before unmarking itself), and a KeyboardInterrupt raised in between left the
# loop running and unclosable: "RuntimeError: Cannot close a running event loop", tracebacks under demo's table
# (three presses 30 ms and 5 ms apart), exit code 1.  A profile hook presses at the chosen socket call.
_LATER_PRESS_IN_THE_LOOPS_OWN_STEP = (
    PRESS_AT_A_CALL
    + """
import asyncio
from ics35_async.cli._loop import run_loop

async def main():
    signal.raise_signal(signal.SIGINT)
    try:
        await asyncio.sleep(30)  # the first press cancels it
    finally:
        sys.setprofile(press)
        signal.raise_signal(signal.SIGINT)  # the second forces the command out
        await asyncio.sleep(30)  # the runner, closing, cancels it again

try:
    run_loop(main)
except KeyboardInterrupt:
    print("interrupted")
"""
)


@pytest.mark.parametrize(
    "where", [("socketpair", 1), ("_real_close", 1), ("_real_close", 2)], ids=lambda where: f"{where[0]}-{where[1]}"
)
def test_a_later_press_in_uvloops_own_step_still_ends_in_one_line(where: tuple[str, int]) -> None:
    done = script_on_loop("uvloop", _LATER_PRESS_IN_THE_LOOPS_OWN_STEP, where[0], str(where[1]), timeout=scaled(15))
    assert (done.stdout, done.stderr) == ("interrupted\n", ""), done.stderr


@pytest.mark.parametrize("loop", ["asyncio", "uvloop"])
def test_work_a_forced_out_command_started_and_never_ran_is_not_reported_on_screen(loop: str) -> None:
    # Three quick Ctrl-C in play printed "coroutine 'Robot._come_to_rest.<locals>.slow_down' was never awaited"
    # (or "Task was destroyed but it is pending!") as the process ended: the slow-down's tasks, started as the
    # third press landed, were left unrun by the closed loop.
    done = script_on_loop(loop, _FORCED_OUT_AS_IT_STARTS_WORK)
    assert done.stdout == "interrupted\n", done.stderr
    assert done.stderr == "", done.stderr


# Ctrl-C typed while `ics35 web` loads what it serves with (the web extra's modules, a good part of a second),
# before it takes Ctrl-C as its stop: a hook holds it there.
_WEB_LOADING = """
import sys, time
import ics35_async.web
from ics35_async.cli import main

load_token = ics35_async.web.load_token

def loading(*args, **kwargs):
    sys.stdout.write("loading\\n")  # (one write: print's two, unbuffered, let the press land between them)
    sys.stdout.flush()
    time.sleep(30)  # Ctrl-C typed here
    return load_token(*args, **kwargs)

ics35_async.web.load_token = loading
main(sys.argv[1:])
"""


def test_ctrl_c_as_web_loads_leaves_no_echoed_ctrl_c_above_its_last_words() -> None:
    # click, taking the KeyboardInterrupt, writes a newline to stderr before the command line says it was interrupted:
    # the ^C the terminal echoed was left on a line of its own above it, which the clearing of the line that
    # every other stop does (the line below, empty) did not reach.
    code, written = typed_on_a_terminal(["web", "--no-browser"], [("loading", b"\x03")], script=_WEB_LOADING)
    screen = [line for line in screen_of(written) if line]
    said = "\n".join(screen)
    assert code == 130 and "Traceback" not in written, said
    assert screen[-2:] == ["loading", "error: interrupted"], said
    assert "^C" in written  # (the terminal echoed it: the scene)


NARROW = 60  # columns: fewer than a live view's status line with its hint


def test_q_typed_on_a_narrow_terminal_leaves_teachs_view_whole_and_its_last_words_on_their_own_line(
    tmp_path: Path,
) -> None:
    # On a terminal narrower than teach's status line, the line was cut at the last column ("q then Enter (or
    # Ctrl") and the cursor rested there: the q typed wrapped to a line of its own, and the view's next redraw
    # began a line low, leaving its title twice on the screen above the last words.
    robot = tmp_path / "arm.toml"
    robot.write_text(CALIBRATED)
    args = ["teach", str(robot), str(tmp_path / "wave.json"), "--yes"]
    code, written = typed_on_a_terminal(args, [("0 pose(s) captured", b"q\r")], columns=NARROW)
    screen = [line for line in screen_of(written, width=NARROW) if line]
    said = "\n".join(screen)
    assert code == 5, said  # (refused: no pose captured)
    # (the title: the file as typed, cut at its start where the terminal is too narrow for it)
    assert sum(line.endswith("/wave.json") for line in screen) == 1, said
    end = next(k for k, line in enumerate(screen) if line.startswith("error: no pose captured"))
    assert screen[end - 1].startswith("t=") and screen[end - 1].endswith("0 pose(s) captured"), said
    assert "q" not in [line.strip() for line in screen], said


def test_teachs_clock_reads_the_motions_time_the_poses_it_records_get(tmp_path: Path) -> None:
    # The status line's clock counted from when teaching began, the poses' times from the first capture (at
    # --lead): "pose 2 at 0.6 s" said under a clock past 2 s.
    robot = tmp_path / "arm.toml"
    robot.write_text(CALIBRATED)
    motion = tmp_path / "wave.json"
    args = ["teach", str(robot), str(motion), "--yes", "--lead", "0.1"]
    keys = [
        ("0 pose(s) captured", b""),
        (scaled(2.0), b"\r"),  # (posing before the first capture: not motion time)
        ("1 pose(s) captured", b""),
        (scaled(0.5), b"\r"),
        ("2 pose(s) captured", b"q\r"),
    ]
    code, written = typed_on_a_terminal(args, keys)
    screen = [line for line in screen_of(written) if line]
    said = "\n".join(screen)
    assert code == 0 and "Traceback" not in written, said
    taught = [frame["time"] for frame in json.loads(motion.read_text())["keyframes"]]
    # The time said is the one recorded, to its last digit ("pose 2 at 2.94 s" of a pose saved at 2.936 s).
    shown = [float(m[1]) for line in screen if (m := re.search(r"pose 2 at ([\d.]+) s", line))]
    assert shown == [taught[1]], (shown, taught, said)
    # The view's last status line, drawn after the second capture: the clock read just past that pose's time.
    clock = [float(m[1]) for line in screen if (m := re.match(r"t= *([\d.]+) s", line))]
    assert clock, said
    assert taught[1] - 0.05 <= clock[-1] <= taught[1] + scaled(1.0), (taught, clock, said)


def test_teachs_title_names_the_motion_file_as_typed_its_folder_too(tmp_path: Path) -> None:
    # `ics35 teach arm.toml motions/wave.json` titled its view "teach: wave.json": which wave.json, of the folders
    # a person keeps motions in, was left to guess.
    robot = tmp_path / "arm.toml"
    robot.write_text(CALIBRATED)
    (tmp_path / "motions").mkdir()
    args = ["teach", "arm.toml", "motions/wave.json", "--yes"]
    code, written = typed_on_a_terminal(args, [("0 pose(s) captured", b"q\r")], cwd=tmp_path)
    screen = [line for line in screen_of(written) if line]
    assert code == 5 and "teach: motions/wave.json" in screen, "\n".join(screen)  # (5: no pose captured)


MOTION_NAME = "the_walking_gait_of_the_hexapod_on_both_of_its_lines"
ROBOT_NAME = "hexapod_on_its_two_lines_left_and_right"


@pytest.mark.parametrize(
    ("command", "motion", "expected"),
    [
        # (each part fits the terminal, the whole does not: a line each, neighbours sharing one where they fit)
        # (teach's file as typed, here a whole path: cut at its start, {file} below)
        ("teach", f"{MOTION_NAME}.json", ["teach:", "{file}"]),
        ("play", MOTION_NAME, [f"play {MOTION_NAME}", f"on {ROBOT_NAME}: 2 joint(s)"]),
        # (a part wider than the terminal by itself: a name cut at its end, a file's cut at its start, since its
        # end names it; each with an ellipsis)
        (
            "teach",
            f"a_long_motion_for_{MOTION_NAME}.json",
            ["teach:", "{file}"],
        ),
        ("play", f"a_long_motion_for_{MOTION_NAME}", [f"play a_long_motion_for_{MOTION_NAME}"[:59] + "…"]),
        # (a motion without a name: its file's path, after "play")
        ("play", None, ["play", "…" + f"/{MOTION_NAME}_v2.json"[-59:], f"on {ROBOT_NAME}: 2 joint(s)"]),
    ],
    ids=["teach", "play", "teach-too-wide", "play-too-wide", "play-unnamed-file-too-wide"],
)
def test_a_robot_views_title_wider_than_the_terminal_goes_on_lines_of_its_own(
    tmp_path: Path, command: str, motion: str | None, expected: list[str]
) -> None:
    # As monitor's and demo's: a title wider than the terminal was cut with an ellipsis, what came last lost (the
    # robot, the joints played); its parts go on lines of their own, each cut only where it alone is too wide.
    robot = tmp_path / "arm.toml"
    robot.write_text(f'name = "{ROBOT_NAME}"\n{CALIBRATED}')
    if command == "teach":
        args, keys = ["teach", str(robot), str(tmp_path / motion), "--yes"], [("0 pose(s) captured", b"q\r")]
        expected = [part.format(file="…" + str(tmp_path / motion)[-(NARROW - 1) :]) for part in expected]
    else:
        played = tmp_path / ("motion.json" if motion is not None else f"{MOTION_NAME}_v2.json")
        keyframes = [{"time": 0.5, "pose": {"a": 5, "b": 5}}]
        named = {"name": motion} if motion is not None else {}
        played.write_text(json.dumps({"format": "ics35-motion", "version": 1, **named, "keyframes": keyframes}))
        args, keys = ["play", str(robot), str(played), "--start-pose", "a=0,b=0"], []
    code, written = typed_on_a_terminal(args, keys, columns=NARROW)
    screen = [line for line in screen_of(written, width=NARROW) if line]
    said = "\n".join(screen)
    assert code == (5 if command == "teach" else 0), said  # (teach refused: no pose captured)
    top = next(k for k, line in enumerate(screen) if line.startswith(expected[0]))
    assert screen[top : top + len(expected)] == expected, said
    assert screen.count(expected[-1]) == 1, said  # (drawn once: no redraw left it twice)


def test_calibrates_title_wider_than_the_terminal_goes_on_lines_of_its_own_keeping_the_files_name(
    tmp_path: Path,
) -> None:
    # As play's and teach's: calibrate's title was one line cut at the terminal's width, what it says of the
    # columns on the right lost.  The file's path, wider than the terminal by itself, is cut at its start: its
    # end names the file.
    robot = tmp_path / "arm.toml"
    robot.write_text(CALIBRATED)
    assert len(str(robot)) > NARROW  # (the scene: a path too wide by itself)
    code, written = typed_on_a_terminal(["calibrate", str(robot)], [("step 1/2", b"\x03")], columns=NARROW)
    screen = [line for line in screen_of(written, width=NARROW) if line]
    said = "\n".join(screen)
    assert code == 130, said
    expected = ["calibrate:", "…" + str(robot)[-(NARROW - 1) :], "(on the right: offset, min and max", "as the file"]
    top = next(k for k, line in enumerate(screen) if line.startswith(expected[0]))
    assert screen[top : top + 3] == expected[:3] and screen[top + 3].startswith(expected[3]), said
    assert "…" not in screen[top + 3], said
    assert sum(line.startswith(expected[0]) for line in screen) == 1, said  # (drawn once: no redraw left it twice)


def joint_rows(screen: list[str]) -> list[str]:
    """The lines of the last joint table on ``screen``: those below its header's rule, up to the line naming the
    columns left out (or, for a table drawn with its edges, one column in, up to the first line that is not)."""
    rule = max(k for k, line in enumerate(screen) if line.strip().startswith("───"))
    edge = screen[rule].startswith(" ")
    below = range(rule + 1, len(screen))
    end = next(k for k in below if screen[k].startswith("columns left out: ") or (edge and screen[k][:1] != " "))
    return [line[edge:] for line in screen[rule + 1 : end]]


LONG_NAMES = ["right_shoulder_pitch", "left_ankle_roll", "neck"]


def calibrating_on_a_narrow_terminal(tmp_path: Path, names: list[str], columns: int) -> tuple[list[str], str]:
    """``calibrate`` on a robot of joints ``names`` at ``columns`` columns, stopped at step 2 (its right columns
    filled): the lines on the screen, and the bytes written."""
    robot = tmp_path / "arm.toml"
    joints = "".join(f'[joints.{name}]\nline = "main"\nid = {k}\n' for k, name in enumerate(names, 1))
    robot.write_text(f'[lines.main]\nport = "sim://narrow-arm?ids=1-{len(names)}&realtime=1"\n{joints}')
    keys = [("step 1/2", b"\r"), ("step 2/2", b"\x03")]
    code, written = typed_on_a_terminal(["calibrate", str(robot)], keys, columns=columns)
    screen = [line for line in screen_of(written, width=columns) if line]
    assert code == 130 and "Traceback" not in written, "\n".join(screen)
    return screen, written


@pytest.mark.parametrize(
    ("command", "names"),
    [
        ("play", []),
        ("calibrate", LONG_NAMES),
        ("calibrate", [name.replace("_", "-") for name in LONG_NAMES]),
    ],
    ids=["play", "calibrate", "calibrate-hyphens"],
)
def test_a_robots_joint_table_on_a_narrow_terminal_keeps_every_value_whole(
    tmp_path: Path, command: str, names: list[str]
) -> None:
    # At 50 columns the joint table was cut to fit, every column's values with it: "right…" for any of five
    # joints, "+2…" for a position of +23.5.  Columns are left out instead (named under the table), then long
    # joint names wrap after an underscore or a hyphen (calibrate's, with its three columns more): a name with
    # hyphens was not wrapped, so a column that fits was cut ("offse…") and the name with it.
    columns = 50
    if command == "play":  # (the humanoid example, as its file says to run it)
        args = ["play", str(EXAMPLES / "humanoid.toml"), str(EXAMPLES / "wave.json")]
        code, written = typed_on_a_terminal(args, [], columns=columns)
        screen = [line for line in screen_of(written, width=columns) if line]
        assert code == 0 and "Traceback" not in written, "\n".join(screen)
        names = list(json.loads((EXAMPLES / "wave.json").read_text())["keyframes"][0]["pose"])
    else:  # (a robot of few joints: the whole view within the terminal's rows; at step 2, the right columns filled)
        screen, written = calibrating_on_a_narrow_terminal(tmp_path, names, columns)
    said = "\n".join(screen)
    rows = joint_rows(screen)
    assert not any("…" in line for line in rows), said
    assert all(len(line) <= columns for line in rows), said
    # Each row begins with its joint's name, or a part of it on a line of its own (a state's words wrapped go on
    # lines that begin blank): read in order, they spell the joints' names.
    assert "".join(line.split()[0] for line in rows if not line.startswith(" ")) == "".join(names), said
    if command == "calibrate":
        assert names[0] not in said, said  # (the scene: a name wrapped)
        assert screen[screen.index(rows[0]) - 2].split()[-4:] == ["state", "offset°", "min°", "max°"], said


def test_a_joint_name_too_long_to_wrap_is_cut_with_an_ellipsis_before_any_value_is(tmp_path: Path) -> None:
    # A name with no underscore or hyphen to wrap after, wider than the terminal leaves it: rich cut it and the
    # values beside it ("offse…", a column left out that fits), each then reading as another.  The name alone is
    # cut, with an ellipsis, and every value and column that fits stays whole.
    columns = 50
    names = ["rightshoulderpitchjoint", "neck"]
    screen, _ = calibrating_on_a_narrow_terminal(tmp_path, names, columns)
    said = "\n".join(screen)
    rows = joint_rows(screen)
    assert screen[screen.index(rows[0]) - 2].split()[-4:] == ["state", "offset°", "min°", "max°"], said
    first, second = (row.split() for row in rows)
    assert first[0].endswith("…") and names[0].startswith(first[0][:-1]) and len(first[0]) >= 8, said
    assert second[0] == "neck", said
    assert not any("…" in cell for row in (first[1:], second[1:]) for cell in row), said


def test_keys_typed_on_a_narrow_terminal_leave_monitors_view_whole_and_its_status_line_complete() -> None:
    # monitor's status line was cut at a narrow terminal's last column (its "Ctrl-C to stop" hint gone), and a key
    # typed there (q, as other programs quit) or the ^C the terminal echoed wrapped to a line of their own: each
    # left the view's title on the screen once more.
    args = ["--port", "sim://?ids=1-3&realtime=1", "monitor", "1-3", "--free", "--seconds", "60"]
    keys = [("cycle", b""), (scaled(0.5), b"q"), (scaled(0.5), b"\x03")]
    _, written = typed_on_a_terminal(args, keys, columns=NARROW)
    screen = [line for line in screen_of(written, width=NARROW) if line]
    said = "\n".join(screen)
    assert "Traceback" not in written, said
    assert sum(line.startswith("monitor sim://") for line in screen) == 1, said
    assert "q" not in [line.strip() for line in screen], said
    # The last status line whole, its words wrapped at the terminal's width, not cut there.
    status = " ".join(screen[next(k for k, line in enumerate(screen) if line.startswith("t=")) :]).split()
    # (its last words "errors N": the count is the machine's load, a realtime simulator's replies late under it)
    assert status[-2] == "errors" and status[-1].isdigit() and "answering" in status, said
    assert "Ctrl-C to stop" in " ".join(written.split()), said  # (the hint, as the view ran: wrapped, not cut)


def view_drawn_last(written: str, columns: int, title: str) -> list[str]:
    """The lines of the last live view drawn whole before the first Ctrl-C was typed (its ``^C`` echoed, maybe in
    the middle of a redraw), from its title's first line (starting with ``title``) on, up to its last line."""
    before = written[: written.index("^C")]
    redraw = before.rindex("\r\x1b[2K\x1b[1A")  # (the redraw under way: it goes back up over the view)
    screen = screen_of(before[:redraw], width=columns)
    top = max(k for k, line in enumerate(screen) if line.startswith(title))
    end = max(k for k, line in enumerate(screen) if line)
    return screen[top : end + 1]


@pytest.mark.parametrize("command", ["calibrate", "monitor", "demo"])
def test_a_live_view_taller_than_the_terminal_cuts_its_table_and_keeps_its_status_line(
    tmp_path: Path, command: str
) -> None:
    # A humanoid's 17 joints (20 servos for monitor and demo) on a terminal of 16 rows: rich cut the view's bottom
    # lines ("..." in their place), the status line that says what is happening and how to stop among them; or,
    # where it let the view run past the terminal's top (monitor, demo), each redraw left its title once more
    # above.  The table loses its last rows for a line saying how many more there are; the status line stays.
    columns, rows = 80, 16
    if command == "calibrate":
        robot = tmp_path / "humanoid.toml"
        robot.write_text((EXAMPLES / "humanoid.toml").read_text())
        names = list(load_description(robot).joints)
        args, title, status, noun = ["calibrate", str(robot)], "calibrate:", "step 1/2", "joints"
    else:
        names = [str(sid) for sid in range(1, 21)]
        args = ["--port", "sim://?ids=1-20&realtime=1", command, *(["1-20", "--free"] if command == "monitor" else [])]
        title, status, noun = command, "Ctrl-C to stop", "servos"
    keys = [(title, b""), (scaled(1.5), b"\x03")]
    code, written = typed_on_a_terminal(args, keys, columns=columns, rows=rows)
    assert code == (130 if command == "calibrate" else 0), "\n".join(screen_of(written, width=columns))
    assert "Traceback" not in written, "\n".join(screen_of(written, width=columns))
    view = view_drawn_last(written, columns, title)
    said = "\n".join(view)
    assert len(view) < rows, said  # (and the cursor resting on the line below)
    assert status in " ".join(" ".join(view[-3:]).split()), said
    more = [(k, int(m[1])) for k, line in enumerate(view) if (m := re.match(rf"… (\d+) more {noun}\b", line))]
    assert len(more) == 1, said
    cut, hidden = more[0]
    # The rows shown, each starting with its name (monitor's and demo's: an ID, in each half of a row of two).
    firsts = [half.split()[0] for line in view[:cut] for half in line.split("│") if half.strip()]
    shown = [first for first in firsts if first in names]
    assert shown and len(shown) + hidden == len(names), said
    # (its last drawing, once it stops, is the whole table: the terminal scrolls and keeps it)
    assert all(name in written[written.index("^C") :] for name in names[-2:]), said


@pytest.mark.parametrize("command", ["monitor", "demo"])
def test_a_live_table_of_many_servos_on_a_narrow_terminal_keeps_every_value_whole(command: str) -> None:
    # Past 16 servos the table shows two a row, 65 columns and more: at 50 rich cut every value to fit ("7…" for a
    # position of 7500, "+…" for an angle).  As the robot commands' table: columns are left out in turn (in both
    # halves, named under the table), the values left whole.
    columns = 50
    args = ["--port", "sim://?ids=1-20&realtime=1", command, *(["1-20", "--free"] if command == "monitor" else [])]
    code, written = typed_on_a_terminal(args, [("Ctrl-C", b""), (scaled(0.5), b"\x03")], columns=columns)
    screen = [line for line in screen_of(written, width=columns) if line]
    said = "\n".join(screen)
    assert code == 0 and "Traceback" not in written, said
    rows = joint_rows(screen)
    assert len(rows) == 10 and not any("…" in line for line in rows), said
    assert all(len(line) <= columns for line in rows), said
    header = screen[screen.index(rows[0]) - 2].split()
    assert header[0] == "ID" and "pos°" in header and header.count("ID") == 2, said  # (the angle read: kept)
    left_out = " ".join(screen[screen.index(rows[-1]) + 1 :])
    assert left_out.startswith("columns left out: "), said
    # (demo's target° goes last, where its values are wide: a wave's first angles, or "free" as it stops, fit)
    targets = ("target°" in header) + ("target°" in left_out.split("t=")[0])
    assert targets == (command == "demo"), said
    assert [line.split("│")[1].split()[0] for line in rows] == [str(sid) for sid in range(11, 21)], said


@pytest.mark.parametrize("columns", [120, 50, 40, 30])
def test_monitors_title_spans_the_terminal_and_on_a_narrower_one_keeps_the_port_and_its_rate(columns: int) -> None:
    # The title is wider than the table below it: it is drawn at the terminal's width, not the table's.  On a
    # terminal narrower than the title it was cut at the last column ("... at 115200" read as the whole title),
    # then with an ellipsis, which at 40 columns took what the servos are left in and, with a longer port's name,
    # the line's rate: each part goes on a line of its own, the port's name cut at its start if it must be (its
    # end, and the rate after it, are what tell one port from another), and the command's name kept before it (a
    # cut at the start of "monitor PORT" left "…or /tmp/...", as demo's title does not).
    args = ["--port", "sim://?ids=1-3&realtime=1", "monitor", "1-3", "--free", "--seconds", "60"]
    assert_live_title(args, columns, ("monitor", "(ICS 3.5 servos free)"), 50)


def assert_live_title(args: list[str], columns: int, ends: tuple[str, str], two_lines: int) -> None:
    """A live command's title (``ends``: its part before the port and the one after it) drawn once, at ``columns``:
    whole at 120, on two lines at the width ``two_lines`` names (the lead and the port sharing one), a line a part
    at 40, the port's name cut at its start at 30."""
    _, written = typed_on_a_terminal(args, [("cycle", b"\x03")], columns=columns)
    screen = [line for line in screen_of(written, width=columns) if line]
    said = "\n".join(screen)
    assert "Traceback" not in written, said
    (lead, after), port = ends, "sim://?ids=1-3&realtime=1 at 115200 baud"
    expected = {
        120: [f"{lead} {port} {after}"],
        two_lines: [f"{lead} {port}", after],
        40: [lead, port, after],
        30: [lead, "…" + port[-29:], after],
    }[columns]
    top = next(k for k, line in enumerate(screen) if line.startswith(lead) and "scanning" not in line)
    assert screen[top : top + len(expected)] == expected, said
    assert sum(line.startswith(lead) for line in screen) == 1, said  # (drawn once: no redraw left it twice)


def monitor_through_a_lost_port(pty_sim: Any, replug_after: float, keys: list[Any], columns: int) -> tuple[int, str]:
    """``monitor 1-2 --free --reconnect`` on a terminal, on a pty simulator whose port is pulled out by the traffic
    (not by the clock: a loaded machine can take longer than any fixed delay to start the command) and comes back
    ``replug_after`` seconds later; ``keys`` as :func:`typed_on_a_terminal`'s.  The exit code and the bytes."""
    # (seed 5: the first unplug comes dozens of cycles into the stream, well after the start's probes)
    server = pty_sim("--ids", "1-2", "--faults", "unplug@1:0.01", "--seed", "5", "--replug-after", f"{replug_after:g}")
    args = ["--port", server.path, *ANSWERED, "monitor", "1-2", "--free", "--reconnect"]
    return typed_on_a_terminal(args, keys, columns=columns)


def test_monitor_with_reconnect_says_the_port_is_lost_and_carries_on_once_it_is_back(pty_sim: Any) -> None:
    # A loose cable ended the view.  With --reconnect it stays: the rows show no readings (the last ones would
    # pass for live ones), the status line says the port is lost and that it waits, and the view carries on.
    waiting = "waiting for it to come back"
    # Ctrl-C once a status line after the port came back counts both servos answering: the first frames' transactions
    # may still fail, as after any reopen, and the line's faults can pull the port out again before any frame drawn
    # reads both (then it comes back again: reconnects 2).
    back_and_read = re.compile(r"answering 2/2  errors \d+  reconnects \d+")
    keys = [(waiting, b""), (back_and_read, b"\x03")]
    code, written = monitor_through_a_lost_port(pty_sim, scaled(1.0), keys, 120)
    assert code == 0 and "Traceback" not in written, "\n".join(screen_of(written))
    while_lost = [line for line in screen_of(written[: written.index(waiting) + len(waiting)]) if line]
    said = "\n".join(while_lost)
    rows = {line.split()[0]: line.split() for line in while_lost if line.split()[0] in ("1", "2")}
    assert [rows[sid][1:] for sid in ("1", "2")] == [["-", "-", "-", "-", "lost"]] * 2, said
    status = while_lost[-1]
    assert status.startswith("t=") and "port lost" in status and "answering" not in status, said
    # Back: the rows are read again, every servo answering.
    back = written[written.index(waiting) :]
    assert back_and_read.search(back), "\n".join(screen_of(written))


def test_ctrl_c_while_monitor_waits_for_its_lost_port_ends_it_as_ever(pty_sim: Any) -> None:
    # (the port gone for good; a terminal narrower than the status line)
    keys = [("port lost", b""), (scaled(0.3), b"\x03")]
    code, written = monitor_through_a_lost_port(pty_sim, 1e6, keys, NARROW)
    screen = [line for line in screen_of(written, width=NARROW) if line]
    said = "\n".join(screen)
    assert code == 0 and "Traceback" not in written and "error:" not in said, said
    rows = {line.split()[0]: line.split() for line in screen if line.split()[0] in ("1", "2")}
    assert [rows[sid][-1] for sid in ("1", "2")] == ["lost", "lost"], said
    status = " ".join(screen[next(k for k, line in enumerate(screen) if line.startswith("t=")) :])
    assert "port lost" in status and "waiting" not in status, said  # (it waits no more: it has ended)


# IDs 4-20 answer nothing on this line: each costs the whole --timeout of the request asking it.
ASKING_SILENT_IDS = ["--port", "sim://?ids=1-3", "--timeout", "5", "monitor", "1-20", "--free"]


@pytest.mark.parametrize(
    ("args", "shown", "asked"),
    [
        (ASKING_SILENT_IDS, "asking IDs 1-20", "asking IDs 1-20"),
        # (a line where nothing answers: each probe of the scan waits the whole --timeout)
        (["--port", "sim://?ids=none", "--timeout", "5", "monitor", "--free"], "no IDs given: scanning", "scanning"),
        (["--port", "sim://?ids=none", "--timeout", "5", "demo"], "no IDs given: scanning", "scanning"),
        # ("all": the servos that answer, found by the same scan, which said nothing: seconds of a blank screen)
        (["--port", "sim://?ids=none", "--timeout", "5", "monitor", "all", "--free"], "scanning sim://", "scanning"),
        (["--port", "sim://?ids=none", "--timeout", "5", "demo", "--ids", "all"], "scanning sim://", "scanning"),
        # (demo asked nothing first: its stream's first cycles asked IDs 4-20 at the whole --timeout each, three
        # cycles before leaving them out, the terminal blank, and a press waited for each cycle that carried the
        # free: minutes)
        (["--port", "sim://?ids=1-3", "--timeout", "5", "demo", "--ids", "1-20"], "asking IDs 1-20", "asking IDs 1-20"),
    ],
    ids=["monitor-ids", "monitor-scan", "demo-scan", "monitor-all", "demo-all", "demo-ids"],
)
def test_ctrl_c_while_a_live_command_asks_its_ids_says_at_once_what_it_waits_for_and_what_was_done(
    args: list[str], shown: str, asked: str
) -> None:
    # Ctrl-C while monitor or demo asked IDs that do not answer waited out the request on the wire (the line's
    # rule: its late reply must not reach the port's next command) with nothing on the screen, then said only
    # "interrupted".
    keys = [(shown, b""), (scaled(0.3), b"\x03")]
    code, written = typed_on_a_terminal(args, keys)
    screen = [line for line in screen_of(written) if line]
    said = "\n".join(screen)
    assert code == 130 and "Traceback" not in written, said
    stopping = next(k for k, line in enumerate(screen) if line.startswith("stopping:"))
    error = next(k for k in range(stopping, len(screen)) if screen[k].startswith("error:"))
    told = " ".join(screen[stopping:error])  # (wrapped at words at the terminal's width)
    assert "up to 5 s" in told and "Ctrl-C again leaves at once" in told, said
    assert screen[error:] == [f"error: interrupted while {asked}: nothing was sent that moves or frees a servo"], said
    if asked == "scanning":  # (and how far, in the words and the bar of `ics35 scan`, gone once it ends)
        assert re.search(r"scanning +115200 baud\S*\s.*\b0/32\b", written), written
        assert not any("/32" in line for line in screen), said


@pytest.mark.parametrize(
    ("command", "stopped"),
    [
        (["scan", "--bauds", "115200"], "error: interrupted"),
        (["monitor", "all", "--free"], "error: interrupted while scanning: nothing was sent that moves or frees a"),
        (["demo", "--ids", "all"], "error: interrupted while scanning: nothing was sent that moves or frees a"),
    ],
    ids=["scan", "monitor-all", "demo-all"],
)
def test_ctrl_c_during_a_scan_on_a_narrow_terminal_takes_its_progress_bar_off_the_screen(
    command: list[str], stopped: str
) -> None:
    # On a terminal narrower than the bar's line it fills the width, the cursor past its last column: the ^C
    # the terminal echoed wrapped to a line of its own, and the bar, cleared from one line too low, stayed on the
    # screen above an empty line.
    args = ["--port", "sim://?ids=none", "--timeout", "5", *command]
    code, written = typed_on_a_terminal(args, [("/32", b""), (scaled(0.3), b"\x03")], columns=NARROW)
    screen = [line for line in screen_of(written, width=NARROW)]
    said = "\n".join(screen)
    assert code == 130 and "Traceback" not in written, said
    assert not any("/32" in line for line in screen), said
    assert stopped in " ".join(said.split()), said  # (the error wrapped at words, its further lines indented)
    assert "" not in screen[: next(k for k, line in enumerate(screen) if line.startswith("error:"))], said


@pytest.mark.parametrize("json_output", [False, True], ids=["text", "json"])
def test_ctrl_c_during_a_scan_names_the_servos_it_had_found(tmp_path: Path, json_output: bool) -> None:
    # Servos 1 and 3 answer at 115200 baud; the scan goes on to 625000, where nothing answers its ID read for a
    # whole allowance.  Ctrl-C there said only "error: interrupted": the two servos found were lost with it.
    # (-v: the log says when the line opens at 625000 baud, a JSON scan drawing no progress bar)
    args = ["-v", "--port", "sim://?ids=1,3", "--timeout", "1", "scan", "--bauds", "115200,625000"]
    out = tmp_path / "out.json"
    code, written = typed_on_a_terminal(
        [*args, *(["--json"] if json_output else [])],
        [("at 625000 baud (", b""), (scaled(0.2), b"\x03")],
        stdout=out if json_output else None,
    )
    screen = [line for line in screen_of(written) if line]
    said = "\n".join(screen)
    assert code == 130 and "Traceback" not in written, said
    flat = " ".join(said.split())  # (wrapped at words)
    error = flat[flat.index("error: interrupted") :]
    assert "servo(s) 1, 3" in error, said
    assert error.endswith("scan --ids 1,3 --bauds 115200"), said  # (where they answered: their settings at once)
    if json_output:
        report = json.loads(out.read_text())
        assert report["interrupted"] is True, report
        assert report["found"] == [{"id": 1, "baud": 115200}, {"id": 3, "baud": 115200}], report
    else:
        assert "servo(s) 1, 3 answered at 115200 baud" in flat[: flat.index("error: interrupted")], said


def test_a_second_ctrl_c_while_monitor_asks_its_ids_leaves_at_once() -> None:
    keys = [("asking IDs 1-20", b""), (scaled(0.3), b"\x03"), ("Ctrl-C again", b"\x03")]
    began = time.monotonic()
    code, written = typed_on_a_terminal(ASKING_SILENT_IDS, keys)
    took = time.monotonic() - began
    screen = [line for line in screen_of(written) if line]
    said = "\n".join(screen)
    assert code == 130 and "Traceback" not in written, said
    assert screen[-1] == "error: interrupted while asking IDs 1-20: nothing was sent that moves or frees a servo"
    # (the whole run, start-up and the wait before the first press included, within the 5 s the first would wait)
    assert took < 5, (took, said)


@pytest.mark.parametrize("columns", [120, 70, 40, 30])
def test_demos_title_on_a_narrower_terminal_keeps_the_port_its_rate_and_what_the_servos_are_left_in(
    columns: int,
) -> None:
    # demo's title was cut with an ellipsis at the terminal's width: at 40 columns "demo: wave on 3 servo(s), the
    # built-in …", the port and its rate gone.  As monitor's, its parts go on lines of their own where the whole
    # does not fit (neighbours sharing one where they fit), the port's name cut at its start if it must be.
    args = ["--port", "sim://?ids=1-3&realtime=1", "demo", "--ids", "1-3", "--seconds", "60"]
    assert_live_title(args, columns, ("demo: wave on 3 servo(s),", "(left free at the end)"), 70)


def test_monitor_json_stopped_with_ctrl_c_on_a_terminal_ends_with_a_line_that_parses() -> None:
    # The terminal echoed ^C where the cursor was, and the final JSON line followed it: "^C{"t": ...}", a line no
    # JSON reader of the screen (a copy, a terminal log) takes.
    code, written = typed_on_a_terminal(
        ["--port", "sim://?ids=1-2&realtime=1", "monitor", "1-2", "--free", "--json"], [('"final": false', b"\x03")]
    )
    screen = [line for line in screen_of(written) if line.strip()]
    assert code == 0, screen
    last = json.loads(screen[-1])
    assert last["final"] is True, screen[-1]


@pytest.mark.parametrize(
    ("json_output", "presses"), [(False, 1), (True, 1), (False, 2)], ids=["text", "json", "double-press"]
)
def test_ctrl_c_during_free_all_names_the_servos_it_freed_and_those_that_may_still_hold(
    tmp_path: Path, json_output: bool, presses: int
) -> None:
    # A robot of 8 servos: "free all" asks the 24 empty IDs after them too, each a short wait.  Ctrl-C typed as it
    # asks the empty ones said only "error: interrupted": servos 0-7 had gone limp, and nothing said so, nor which
    # might still hold.
    record = tmp_path / "wire.txt"
    url = f"sim://ctrl-c-free?ids=0-7&realtime=1&turnaround={scaled(0.05)}&record={record}"
    json_option = ["--json"] if json_output else []
    out = tmp_path / "out.json"
    code, written = typed_on_a_terminal(
        ["-v", "--port", url, "--timeout", str(scaled(0.5)), "free", "all", *json_option],
        # (a second press, forcing the command out as its line closes, must not lose the account either)
        [("free to ID 10:", b"\x03"), *[(0.002, b"\x03")] * (presses - 1)],
        stdout=out if json_output else None,
    )
    screen = screen_of(written)
    said = "\n".join(screen)
    assert code == 130, said
    assert "Traceback" not in written, said
    freed_on_the_wire = set(torque_commands_sent(record))
    assert set(range(11)) <= freed_on_the_wire, freed_on_the_wire  # (then Ctrl-C: ID 11's, perhaps, and no more)
    if json_output:
        report = json.loads(out.read_text())
        said_free = {int(i) for i in report["freed"]}
        assert report["interrupted"] is True and report["not_freed"] == list(range(8, 32)), report
    else:
        said_free = {int(m.group(1)) for line in screen if (m := re.match(r"servo (\d+): free at \d+ ", line))}
    assert said_free == set(range(8)), said
    flat = " ".join(said.split())  # (the error wrapped at words, its further lines indented)
    error = flat[flat.index("error: interrupted") :]
    assert "servo(s) 0-7 went free" in error and "ID(s) 8-31" in error and "may still hold" in error, said
    assert error.endswith(" free all"), said  # (named, the empty IDs 8-31 would each be waited for, and fail)


# Ctrl-C as Python ends, the command over and its words said (typed just as `free` printed its last servo): Python
# puts its own handler back to the default as it ends, and a press in those last milliseconds killed the process by
# SIGINT (the shell saw 130, with not a word) instead of ending with the command's exit code.  Nothing is left to
# interrupt by then: the last of Python's exit steps (this script's first atexit hook runs last) must find Ctrl-C
# ignored, whatever the command's end.
_HANDLER_AS_PYTHON_ENDS = """
import atexit, signal, sys
atexit.register(lambda: print("Ctrl-C as Python ends:", signal.getsignal(signal.SIGINT), file=sys.stderr))
from ics35_async.cli import main
main(sys.argv[1:])
"""


@pytest.mark.parametrize(
    "args", [["free", "1"], ["get", "9", "speed"], ["free", "--bogus"]], ids=["done", "failed", "usage"]
)
def test_ctrl_c_as_python_ends_cannot_kill_a_command_that_has_ended(args: list[str]) -> None:
    done = subprocess.run(
        [sys.executable, "-c", _HANDLER_AS_PYTHON_ENDS, "--port", "sim://", *args],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.stderr.splitlines()[-1] == f"Ctrl-C as Python ends: {signal.SIG_IGN}", done.stderr
