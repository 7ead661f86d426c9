"""``ics35 sim --console``: servos plugged in, unplugged and power-cycled by typing, while the line serves.

Each test runs the real command as a subprocess on a pty, types into its stdin, reads its answers on
stdout, and checks what happened through the library (or ``ics35``) on the pty, as a person would.
"""

from __future__ import annotations

import os
import queue
import select
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from ics35_async import blocking
from ics35_async.eeprom import BaudRate
from ics35_async.errors import PortLost
from tests.support.cli_runs import run_process
from tests.support.terminal import screen_of, typed_on_a_terminal
from tests.support.timing import GUARD, PATIENT, PATIENT_OPTION

pytestmark = [pytest.mark.pty, pytest.mark.skipif(not sys.platform.startswith("linux"), reason="needs Linux ptys")]


class Console:
    """A running ``ics35 sim ... --console``: ``say(command)`` types one line and returns its answer."""

    def __init__(self, proc: subprocess.Popen[str], path: str, notes: Path) -> None:
        self.proc = proc
        self.path = path
        self.notes = notes
        self.lines: queue.Queue[str] = queue.Queue()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.put(line.rstrip("\n"))

    def read_line(self) -> str:
        try:
            return self.lines.get(timeout=GUARD)
        except queue.Empty:
            pytest.fail(f"no answer within {GUARD} s")

    def say(self, command: str) -> str:
        assert self.proc.stdin is not None
        self.proc.stdin.write(command + "\n")
        self.proc.stdin.flush()
        return self.read_line()

    def listing(self) -> list[str]:
        """``list``'s answer: its first line says how many servo lines follow."""
        head = self.say("list")
        count = 0 if head.startswith("list: no servos") else int(head.split()[1])
        return [head, *(self.read_line() for _ in range(count))]

    def end(self) -> int:
        """Close its stdin (end of input) and wait for it; its exit code."""
        if self.proc.stdin is not None and not self.proc.stdin.closed:
            self.proc.stdin.close()
        try:
            return self.proc.wait(GUARD)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
            raise


def start(*args: str, notes: Path) -> Console:
    with open(notes, "w", encoding="utf-8") as err:
        proc = subprocess.Popen(
            [sys.executable, "-m", "ics35_async.cli", "sim", *args],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=err,
            text=True,
        )
    assert proc.stdout is not None
    ready, _, _ = select.select([proc.stdout], [], [], GUARD)
    path = proc.stdout.readline().strip() if ready else ""
    if not path:
        proc.kill()
        proc.wait()
        pytest.fail(f"the simulator printed no device path: {notes.read_text()}")
    return Console(proc, path, notes)


@pytest.fixture
def sim_console(tmp_path: Path) -> Iterator[Callable[..., Console]]:
    """``sim_console(*args)``: ``ics35 sim --fast --console ARGS``; at the end, end of input must end it
    cleanly (exit 0, no traceback)."""
    started: list[Console] = []

    def run(*args: str) -> Console:
        started.append(start("--fast", "--console", *args, notes=tmp_path / f"sim{len(started)}.log"))
        return started[-1]

    yield run
    for console in started:
        assert console.end() == 0
        notes = console.notes.read_text()
        assert "Traceback" not in notes, notes
        assert "served" in notes  # it ended as it does on SIGINT, with its summary


def scan(path: str, baud: int = 115200, ids: range = range(4)) -> list[int]:
    # Only the IDs that matter: each silent one costs the patient allowance.
    with blocking.open_bus(path, baudrate=baud, **PATIENT) as bus:
        return bus.scan(ids)


def ics35(path: str, *args: str) -> subprocess.CompletedProcess[str]:
    return run_process("--port", path, *PATIENT_OPTION, *args)


def renumber(path: str, old: int, new: int) -> None:
    """Write ID ``new`` into the EEPROM of the servo at ``old`` (an addressed write: no survey of the line)."""
    with blocking.open_bus(path, **PATIENT) as bus:
        servo = bus.servo(old)
        servo.write_eeprom(servo.read_eeprom().replace(servo_id=new), allow_id_change=True)


def test_servos_plugged_in_renumbered_unplugged_and_plugged_back(sim_console: Callable[..., Console]) -> None:
    sim = sim_console("--ids", "none")
    assert scan(sim.path, ids=range(1)) == []
    assert sim.say("plug 0") == "plugged in a new servo at ID 0 (ICS 3.5, 115200 bit/s); 1 servo on the line"
    assert scan(sim.path, ids=range(2)) == [0]
    renumber(sim.path, 0, 1)
    assert scan(sim.path, ids=range(2)) == [1]
    assert sim.say("plug 0").startswith("plugged in a new servo at ID 0")
    assert scan(sim.path, ids=range(2)) == [0, 1]
    assert sim.say("unplug 1") == "unplugged the servo at ID 1 (replug 1 plugs it back in); 1 servo on the line"
    assert scan(sim.path, ids=range(3)) == [0]
    renumber(sim.path, 0, 2)
    assert sim.say("replug 1") == "plugged the servo at ID 1 back in (115200 bit/s); 2 servos on the line"
    assert scan(sim.path, ids=range(3)) == [1, 2]
    assert sim.listing() == [
        "list: 2 servos",
        "  ID 2: ICS 3.5, 115200 bit/s, at 7500, free",
        "  ID 1: ICS 3.5, 115200 bit/s, at 7500, free",
    ]


def test_the_simulators_first_line_names_the_link_to_open_not_the_pty_a_replug_renames() -> None:
    # It said "real-time on /dev/pts/2 (link ...)": a program given /dev/pts/2 lost the line for good at the console's
    # replug port (the pty is a new one, the link the same).
    keys = [("sim>", b"unplug port\n"), ("replug port", b"replug port\n"), ("back in", b"quit\n")]
    code, written = typed_on_a_terminal(["sim", "--ids", "1", "--console"], keys, columns=200)
    screen = [line for line in screen_of(written, width=200) if line]
    assert code == 0, screen
    link = screen[0]
    said = next(line for line in screen if line.startswith("ics35 sim: 1 servo"))
    assert said.startswith(f"ics35 sim: 1 servo at 115200 bit/s, real-time on {link} (a link to /dev/pts/"), said
    assert said.endswith(", which a replug renames: open the link)"), said


@pytest.mark.slow
def test_the_port_unplugged_and_plugged_back_in_from_the_console(sim_console: Callable[..., Console]) -> None:
    # As pulling the USB adapter out and putting it back: the link goes and a program on the port loses it; it
    # stays out until told (no replug of its own), and the program's reconnect finds it at the same path.
    sim = sim_console("--ids", "1-2")
    with blocking.open_bus(sim.path, reconnect=True, **PATIENT) as bus:
        assert bus.scan(range(3)) == [1, 2]
        assert sim.say("unplug port") == (
            f"unplugged the port: {sim.path} is gone and a program on it loses it (replug port plugs it back in)"
        )
        gone_by = time.monotonic() + GUARD  # (the server, a thread of its own, follows the unplug at once)
        while os.path.lexists(sim.path):
            assert time.monotonic() < gone_by, "the link stayed"
            time.sleep(0.01)
        with pytest.raises(PortLost):
            bus.servo(1).read_temperature()
        assert sim.say("unplug port") == "error: the port is unplugged already (replug port plugs it back in)"
        assert sim.listing()[0] == "list: 2 servos, the port unplugged (replug port plugs it back in)"
        time.sleep(0.5)  # longer than the simulator's own replug after an unplug fault: it stays out
        assert not os.path.lexists(sim.path)
        assert sim.say("replug port") == f"plugged the port back in at {sim.path}; 2 servos on the line"
        assert sim.say("replug port") == "error: the port is plugged in (unplug port pulls it out)"
        deadline = time.monotonic() + GUARD
        while True:  # the program's reconnect brings its line back
            try:
                bus.servo(2).read_temperature()
                break
            except PortLost:
                assert time.monotonic() < deadline, "the line did not come back"
                time.sleep(0.05)
    assert scan(sim.path, ids=range(3)) == [1, 2]
    assert "comes back in" not in sim.notes.read_text()  # (only an unplug that replugs by itself says when)


def test_new_servos_renumbered_one_at_a_time_with_set_id(sim_console: Callable[..., Console]) -> None:
    # The how-to's steps (docs/how-to/simulator.md), with ics35 set-id: it proves the servo alone on the
    # line first (31 IDs that do not answer, each waited for with the patient allowance: seconds).
    sim = sim_console("--ids", "none")
    assert sim.say("plug 0").startswith("plugged in a new servo at ID 0")
    done = ics35(sim.path, "set-id", "1", "--yes")
    assert done.returncode == 0, done.stderr
    assert sim.say("unplug 1").startswith("unplugged the servo at ID 1")
    assert sim.say("plug 0").startswith("plugged in a new servo at ID 0")
    done = ics35(sim.path, "set-id", "2", "--yes")
    assert done.returncode == 0, done.stderr
    assert sim.say("replug 1").startswith("plugged the servo at ID 1 back in")
    assert scan(sim.path, ids=range(3)) == [1, 2]


def test_a_baud_rate_written_to_eeprom_takes_effect_at_power(sim_console: Callable[..., Console]) -> None:
    sim = sim_console("--ids", "1,2")
    with blocking.open_bus(sim.path, **PATIENT) as bus:
        servo = bus.servo(1)
        servo.write_eeprom(servo.read_eeprom().replace(baud_rate=BaudRate.B1250000), allow_baud_change=True)
    assert scan(sim.path, ids=range(1, 3)) == [1, 2]  # it still talks at its old rate, as a real one does
    assert sim.listing()[1] == "  ID 1: ICS 3.5, 115200 bit/s (1250000 in its EEPROM, after power), at 7500, free"
    assert sim.say("power 1") == "power-cycled the servo at ID 1: it listens at 1250000 bit/s"
    assert scan(sim.path, ids=range(1, 3)) == [2]
    assert scan(sim.path, 1250000, range(1, 3)) == [1]
    assert sim.say("power") == "power-cycled 2 servos"


def test_power_cycling_every_servo_applies_what_each_eeprom_holds(sim_console: Callable[..., Console]) -> None:
    sim = sim_console("--ids", "3", "--ics36", "3")
    with blocking.open_bus(sim.path, **PATIENT) as bus:
        servo = bus.servo(3)
        servo.write_eeprom(servo.read_eeprom().replace(baud_rate=BaudRate.B625000), allow_baud_change=True)
    assert scan(sim.path, ids=range(3, 4)) == [3]
    assert sim.say("power") == "power-cycled 1 servo"
    assert scan(sim.path, ids=range(3, 4)) == []
    assert scan(sim.path, 625000, range(3, 4)) == [3]
    assert sim.listing() == ["list: 1 servo", "  ID 3: ICS 3.6, 625000 bit/s, at 7500, free"]


def test_two_servos_at_one_id_are_named_and_the_last_plugged_in_leaves(sim_console: Callable[..., Console]) -> None:
    sim = sim_console("--ids", "0")
    assert sim.say("plug 0 ics36") == (
        "plugged in a new servo at ID 0 (ICS 3.6, 115200 bit/s); 2 servos on the line; "
        "2 servos now answer to ID 0: their replies collide"
    )
    assert sim.say("unplug 0") == (
        "unplugged the servo at ID 0 plugged in last (replug 0 plugs it back in); 1 servo on the line; "
        "1 more still answers to ID 0"
    )
    assert sim.listing() == ["list: 1 servo", "  ID 0: ICS 3.5, 115200 bit/s, at 7500, free"]
    assert scan(sim.path, ids=range(1)) == [0]


def test_a_servo_plugged_in_at_another_rate_answers_only_there(sim_console: Callable[..., Console]) -> None:
    sim = sim_console("--ids", "none", "--baud", "625000")
    assert sim.say("plug 4") == "plugged in a new servo at ID 4 (ICS 3.5, 625000 bit/s); 1 servo on the line"
    assert sim.say("plug 5 1250000").startswith("plugged in a new servo at ID 5 (ICS 3.5, 1250000 bit/s)")
    assert scan(sim.path, 625000, range(4, 6)) == [4]
    assert scan(sim.path, 1250000, range(4, 6)) == [5]


def test_bad_input_gets_a_clear_answer_and_changes_nothing(sim_console: Callable[..., Console]) -> None:
    sim = sim_console("--ids", "1")
    before = sim.listing()
    answers = {
        command: sim.say(command)
        for command in (
            "plug",
            "plug 32",
            "plug x",
            "plug 1 9600",
            "plug 1 ics37",
            "unplug",
            "unplug 5",
            "unplug 1 2",
            "replug",
            "replug 1",
            "power 9",
            "power -1",
            "frobnicate",
            # Digits that are not ASCII's: str.isdigit takes them, int() fails on some and reads others.
            "plug \u00b2",  # superscript two
            "plug 0 \u00b2",
            "unplug \u00b2",
            "power \u00b2",
            "plug \u0661",  # Arabic-Indic one: not ID 1
            "plug 0 \uff11\uff11\uff15\uff12\uff10\uff10",  # fullwidth 115200
            "plug " + "9" * 5000,  # past int()'s 4300 digits
            "plug 0 " + "1" * 5000,
        )
    }
    assert all(answer.startswith("error: ") for answer in answers.values()), answers
    assert answers["plug 32"] == "error: an ID is 0..31, got '32'"
    assert answers["unplug 5"] == "error: no servo at ID 5 on the line (list shows them)"
    assert answers["replug"] == "error: no unplugged servo to plug back in"
    assert answers["frobnicate"] == "error: unknown command 'frobnicate' (help lists the commands)"
    assert answers["plug \u00b2"] == "error: an ID is 0..31, got '\u00b2'"
    assert answers["plug 0 \u00b2"] == "error: plug ID takes a baud rate and ics36 after it, not '\u00b2'"
    assert sim.say("") == sim.say("help")  # an empty line gets the help too
    assert sim.say("help").startswith("commands: plug ID [BAUD] [ics36]")
    assert sim.listing() == before
    assert scan(sim.path, ids=range(1, 2)) == [1]


def test_turn_moves_a_free_servo_by_hand_and_it_stays_there(sim_console: Callable[..., Console]) -> None:
    # What ics35 calibrate and teach ask of a person, on the simulator: the free joint turned by hand.
    sim = sim_console("--ids", "1,2")
    assert (
        sim.say("turn 1 9000") == "turned the servo at ID 1 by hand to 9000 (+50.6 degrees); it is free: it stays there"
    )
    assert (
        sim.say("turn 2 3500")
        == "turned the servo at ID 2 by hand to 3500 (-135.0 degrees); it is free: it stays there"
    )
    with blocking.open_bus(sim.path, **PATIENT) as bus:
        assert bus.servo(1).free() == 9000
        assert bus.servo(2).free() == 3500
    assert sim.listing()[1:] == [
        "  ID 1: ICS 3.5, 115200 bit/s, at 9000, free",
        "  ID 2: ICS 3.5, 115200 bit/s, at 3500, free",
    ]
    assert sim.say("plug 1").startswith("plugged in a new servo at ID 1")
    assert sim.say("turn 1 11500") == (
        "turned the 2 servos at ID 1 by hand to 11500 (+135.0 degrees); they are free: they stay there"
    )
    assert [line for line in sim.listing() if "ID 1:" in line] == ["  ID 1: ICS 3.5, 115200 bit/s, at 11500, free"] * 2


def test_turn_pushes_a_holding_servo_which_turns_back_to_its_target(sim_console: Callable[..., Console]) -> None:
    # move_by_hand on a holding servo: it is where the hand put it, and turns back at its speed (--fast:
    # the line's clock moves only with its transactions, so the way back takes a few hundred of them).
    sim = sim_console("--ids", "1")
    with blocking.open_bus(sim.path, **PATIENT) as bus:
        servo = bus.servo(1)
        assert servo.set_position(7500) == 7500
        assert sim.say("turn 1 9000") == (
            "turned the servo at ID 1 by hand to 9000 (+50.6 degrees); it is holding 7500: it turns back there"
        )
        reported = [servo.set_position(7500)]
        assert 8900 < reported[0] <= 9000, reported  # pushed: a transaction's time takes it back a few counts
        while reported[-1] != 7500 and len(reported) < 2000:
            reported.append(servo.set_position(7500))
        assert reported[-1] == 7500, reported[-5:]
        assert reported == sorted(reported, reverse=True)  # on its way back, never past it
    assert sim.listing()[1] == "  ID 1: ICS 3.5, 115200 bit/s, at 7500, holding"


def test_turn_refuses_bad_input_and_changes_nothing(sim_console: Callable[..., Console]) -> None:
    sim = sim_console("--ids", "1")
    before = sim.listing()
    answers = {
        command: sim.say(command)
        for command in (
            "turn",
            "turn 1",
            "turn 1 9000 2",
            "turn 5 9000",
            "turn 32 9000",
            "turn x 9000",
            "turn 1 3499",
            "turn 1 11501",
            "turn 1 0",
            "turn 1 -100",
            "turn 1 +10",
            "turn 1 9000.5",
            "turn 1 \u00b2",
            "turn 1 " + "9" * 5000,
        )
    }
    assert all(answer.startswith("error: ") for answer in answers.values()), answers
    assert answers["turn"] == "error: turn takes an ID and a position, e.g. turn 1 9000"
    assert answers["turn 5 9000"] == "error: no servo at ID 5 on the line (list shows them)"
    assert answers["turn 32 9000"] == "error: an ID is 0..31, got '32'"
    assert answers["turn 1 3499"] == (
        "error: a position is 3500..11500 (-135..+135 degrees, the servo's travel), got '3499'"
    )
    assert answers["turn 1 +10"] == answers["turn 1 3499"].replace("'3499'", "'+10'")
    assert "turn ID POSITION" in sim.say("help")
    assert sim.listing() == before
    with blocking.open_bus(sim.path, **PATIENT) as bus:
        assert bus.servo(1).free() == 7500


def test_quit_ends_the_simulator_as_ctrl_c_does(tmp_path: Path) -> None:
    sim = start("--console", "--ids", "1", notes=tmp_path / "notes.log")
    assert sim.say("quit") == "quit: the simulator stops"
    assert sim.proc.wait(GUARD) == 0
    notes = sim.notes.read_text()
    assert "Traceback" not in notes and "served 0 transactions" in notes, notes
    assert "end of input" not in notes
    assert not os.path.exists(sim.path)


def test_end_of_input_says_why_the_simulator_stops() -> None:
    # As `ics35 sim --console </dev/null` (or under nohup): it stops at once, and says so.
    done = subprocess.run(
        [sys.executable, "-m", "ics35_async.cli", "sim", "--console", "--ids", "1"],
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
        timeout=GUARD,
    )
    assert done.returncode == 0, done.stderr
    assert "Traceback" not in done.stderr, done.stderr
    assert "ics35 sim: console: end of input: the simulator stops" in done.stderr, done.stderr


# Runs ARGS as a shell runs a command in the foreground (fg) or with `&` (bg): in a session of its own
# whose controlling terminal is a new pty, in the terminal's foreground process group or in a group of its
# own; then types quit (fg) or list (bg) on the terminal.  Exits with the command's exit code, or 99 (and
# says its state: T is stopped) if it has not ended within the guard.
ON_A_TERMINAL = """
import fcntl, os, subprocess, sys, termios
guard, where, *args = float(sys.argv[1]), sys.argv[2], *sys.argv[3:]
master, slave = os.openpty()
fcntl.ioctl(slave, termios.TIOCSCTTY, 0)
child = subprocess.Popen(args, stdin=slave, process_group=0 if where == "bg" else None)
os.write(master, b"quit\\n" if where == "fg" else b"list\\n")  # input the terminal's foreground takes
try:
    sys.exit(child.wait(guard))
except subprocess.TimeoutExpired:
    with open(f"/proc/{child.pid}/stat") as stat:
        state = stat.read().rsplit(")", 1)[1].split()[0]
    child.kill()
    child.wait()
    print(f"still running after {guard} s, state {state}", file=sys.stderr)
    sys.exit(99)
"""


def on_a_terminal(where: str, *args: str) -> subprocess.CompletedProcess[str]:
    command = [sys.executable, "-m", "ics35_async.cli", "sim", *args]
    return subprocess.run(
        [sys.executable, "-c", ON_A_TERMINAL, str(GUARD), where, *command],
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
        timeout=3 * GUARD,
        start_new_session=True,
    )


def test_console_refuses_to_start_in_the_background_of_a_terminal() -> None:
    # As `ics35 sim --console &`: reading the terminal would stop it (SIGTTIN), and the pty server with it.
    done = on_a_terminal("bg", "--console", "--ids", "1")
    assert done.returncode == 2, done.stderr
    assert "--console reads the terminal" in done.stderr, done.stderr
    assert "Traceback" not in done.stderr, done.stderr
    assert done.stdout == ""  # no device path: it never served


def test_console_in_the_foreground_of_a_terminal_reads_it() -> None:
    done = on_a_terminal("fg", "--console", "--ids", "1")
    assert done.returncode == 0, done.stderr
    assert "quit: the simulator stops" in done.stdout
    assert "Traceback" not in done.stderr, done.stderr


def test_without_console_the_simulator_does_not_read_its_input(tmp_path: Path) -> None:
    sim = start("--ids", "1", notes=tmp_path / "notes.log")
    try:
        assert sim.proc.stdin is not None
        sim.proc.stdin.write("quit\n")
        sim.proc.stdin.close()
        time.sleep(0.3)
        assert sim.proc.poll() is None
        assert scan(sim.path, ids=range(2)) == [1]
    finally:
        sim.proc.terminate()
        assert sim.proc.wait(GUARD) == 0


def test_console_refuses_a_replay(tmp_path: Path) -> None:
    recording = tmp_path / "r.txt"
    recording.write_text("")
    done = run_process("sim", "--console", "--replay", str(recording), timeout=GUARD)
    assert done.returncode == 2
    assert "--console needs a simulated line, not --replay" in done.stderr


# A user's trial: on a terminal nothing said that the console waits for a command.  It prompts there, after each
# answer too; piped, its stdout holds the answers alone (programs read them), and Ctrl-D or Ctrl-C at the prompt
# ends it with its last words on lines of their own.
PROMPT = "sim> "


@pytest.mark.parametrize(
    ("key", "last_words"), [(b"\x04", "end of input"), (b"\x03", "served")], ids=["ctrl-d", "ctrl-c"]
)
def test_on_a_terminal_the_console_prompts_for_each_command(key: bytes, last_words: str) -> None:
    code, written = typed_on_a_terminal(
        ["sim", "--console", "--ids", "1"], [(PROMPT, b"list\n"), ("ID 1: ICS 3.5", b""), (0.3, key)]
    )
    screen = screen_of(written)
    assert code == 0 and "Traceback" not in written, "\n".join(screen)
    assert f"{PROMPT}list" in screen, "\n".join(screen)  # (the command typed after its prompt)
    after = screen[screen.index(f"{PROMPT}list") :]
    assert written.count(PROMPT) == 2, written  # prompted again once answered (Ctrl-C's stop then clears it)
    ends = [line for line in after if last_words in line]
    assert ends and all(line.startswith("ics35 sim: ") for line in ends), "\n".join(screen)


def test_a_prompt_never_reaches_the_answers_a_program_reads(tmp_path: Path) -> None:
    # Commands from a pipe: no prompt anywhere.  Typed on a terminal with stdout to a file (as `... | tee log`,
    # whose answers would reach the terminal after the prompt meant to follow them): the file holds the answers
    # alone, and no prompt waits on the terminal.
    piped = subprocess.run(
        [sys.executable, "-m", "ics35_async.cli", "sim", "--fast", "--console", "--ids", "1"],
        input="list\n",
        capture_output=True,
        text=True,
        timeout=GUARD,
    )
    assert piped.returncode == 0, piped.stderr
    assert piped.stdout.splitlines()[1:] == ["list: 1 servo", "  ID 1: ICS 3.5, 115200 bit/s, at 7500, free"]
    assert PROMPT.strip() not in piped.stdout + piped.stderr, piped.stderr
    answers = tmp_path / "answers.txt"
    code, written = typed_on_a_terminal(
        ["sim", "--console", "--ids", "1"],
        [("type help", b"list\n"), (lambda: "ID 1:" in answers.read_text(), b"quit\n")],
        stdout=answers,
    )
    assert code == 0 and PROMPT.strip() not in written, written
    assert answers.read_text().splitlines()[1:] == [
        "list: 1 servo",
        "  ID 1: ICS 3.5, 115200 bit/s, at 7500, free",
        "quit: the simulator stops",
    ]


def test_the_simulators_own_line_keeps_the_prompt_below_it() -> None:
    # `--unplug-after` says the port went while the prompt waits: "sim> ics35 sim: the port was unplugged ...".
    # The prompt comes back below it, and the console still answers.
    code, written = typed_on_a_terminal(
        ["sim", "--console", "--ids", "1", "--unplug-after", "0.5"],
        [(PROMPT, b""), ("the port was unplugged", b"list\n"), ("list: 1 servo", b"\x03")],
    )
    screen = screen_of(written)
    assert code == 0 and "Traceback" not in written, "\n".join(screen)
    said = [line for line in screen if "the port was unplugged" in line]
    assert said and said[0].startswith("ics35 sim: "), "\n".join(screen)
    assert written.rindex(PROMPT) > written.index("the port was unplugged"), written  # (prompted again below)


@pytest.mark.parametrize("buffered", [True, False], ids=["buffered", "unbuffered"])
def test_ctrl_c_ends_it_while_nobody_reads_its_answers(tmp_path: Path, buffered: bool) -> None:
    # Its stdout a pipe nobody empties: the answers fill it and the console blocks writing one; SIGINT
    # must still end the simulator (the console is not waited for without end).  With Python's stdout buffered
    # (its default; PYTHONUNBUFFERED, set in many containers, hid it) the console's thread, blocked in a write,
    # held the buffer's lock as Python ended, which then aborted: "Fatal Python error: _enter_buffered_busy".
    env = {key: value for key, value in os.environ.items() if key != "PYTHONUNBUFFERED"}
    if not buffered:
        env["PYTHONUNBUFFERED"] = "1"
    out_r, out_w = os.pipe()
    with open(tmp_path / "notes.log", "w", encoding="utf-8") as err:
        proc = subprocess.Popen(
            [sys.executable, "-m", "ics35_async.cli", "sim", "--fast", "--console", "--ids", "1"],
            stdin=subprocess.PIPE,
            stdout=out_w,
            stderr=err,
            env=env,
        )
    os.close(out_w)
    try:
        with os.fdopen(out_r, "rb") as out:
            assert select.select([out], [], [], GUARD)[0], "no device path"
            out.readline()
            assert proc.stdin is not None
            proc.stdin.write(b"help\n" * 2000)  # some 200 kB of answers: more than a pipe holds
            proc.stdin.flush()
            time.sleep(0.5)
            proc.send_signal(signal.SIGINT)
            assert proc.wait(GUARD) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    notes = (tmp_path / "notes.log").read_text()
    assert "Traceback" not in notes and "served 0 transactions" in notes, notes


@pytest.mark.parametrize("gap", [0.05, 0.1])
def test_a_double_ctrl_c_ends_it_once_and_puts_the_terminal_back(gap: float) -> None:
    # The second press landed as the process ended, in the wait that lets the last words reach the terminal before
    # its own setting is put back: "Exception ignored in atexit callback" and a KeyboardInterrupt's traceback, and
    # the terminal left keeping its output at Ctrl-C and not echoing ^C for every command after.
    code, written = typed_on_a_terminal(["sim", "--console", "--ids", "1"], [("type help", b"\x03"), (gap, b"\x03")])
    assert "Traceback" not in written and "Exception ignored" not in written, written
    assert code == 0, written
