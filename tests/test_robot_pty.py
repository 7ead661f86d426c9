"""teach -> play round trip as real processes over the pty simulator (a real serial boundary, real time)."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from ics35_async import units
from ics35_async.sim import serving
from tests.support.pty_line import PtyLine
from tests.support.robot_rig import ics36_humanoid
from tests.support.terminal import TerminalOutput, screen_of, typed_on_a_terminal
from tests.support.timing import NO_TIMEOUTS_OPTION, scaled

pytestmark = [
    pytest.mark.pty,
    pytest.mark.slow,
    pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the pty simulator needs Linux"),
]

ROBOT = """\
[lines.main]
port = "{port}"

[joints.a]
line = "main"
id = 1
offset = 5

[joints.b]
line = "main"
id = 2
reverse = true
min = -90
max = 90

[joints.c]
line = "main"
id = 3
"""
EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


def ics35(*args: str, stdin: str = "") -> subprocess.CompletedProcess[str]:
    proc = subprocess.run(
        [sys.executable, "-m", "ics35_async.cli", *args],
        input=stdin,
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, "COLUMNS": "100"},
    )
    assert "Traceback" not in proc.stderr, proc.stderr
    return proc


@pytest.fixture
def port() -> Iterator[str]:
    with serving(["--ids", "1-3"]) as path:
        yield path


def servo_degrees(port: str) -> dict[int, float]:
    proc = ics35("--port", port, *NO_TIMEOUTS_OPTION, "free", "1", "2", "3", "--json")
    assert proc.returncode == 0, proc.stderr
    return {int(i): units.position_to_degrees(p) for i, p in json.loads(proc.stdout)["freed"].items()}


def test_teach_then_play_round_trip(port: str, tmp_path: Path) -> None:
    robot = tmp_path / "robot.toml"
    robot.write_text(ROBOT.format(port=port))
    for sid, deg in ((1, "25"), (2, "-40"), (3, "60")):
        assert ics35("--port", port, *NO_TIMEOUTS_OPTION, "move", str(sid), deg, "--deg").returncode == 0
    taught = tmp_path / "taught.json"
    proc = ics35(*NO_TIMEOUTS_OPTION, "teach", str(robot), str(taught), "--yes", stdin="\nq\n")
    assert proc.returncode == 0, proc.stderr
    keyframes = json.loads(taught.read_text())["keyframes"]
    assert len(keyframes) == 1
    # Joint degrees of where the servos were put: a = servo - 5, b = -servo, c = servo.
    assert keyframes[0]["pose"] == pytest.approx({"a": 20.0, "b": 40.0, "c": 60.0}, abs=0.1)
    for sid in (1, 2, 3):
        assert ics35("--port", port, *NO_TIMEOUTS_OPTION, "move", str(sid), "0", "--deg").returncode == 0
    proc = ics35(*NO_TIMEOUTS_OPTION, "play", str(robot), str(taught), "--yes")
    assert proc.returncode == 0, proc.stderr
    assert servo_degrees(port) == pytest.approx({1: 25.0, 2: -40.0, 3: 60.0}, abs=0.1)


@pytest.mark.parametrize("command", ["teach", "calibrate"])
def test_without_joints_on_hardware_asks_before_freeing_every_joint(port: str, tmp_path: Path, command: str) -> None:
    # Teaching an arm's wave (or calibrating a knee) on a standing humanoid without --joints freed every joint at
    # once: the robot fell.  On a serial line (not the simulator) teach and calibrate ask first, naming how many
    # joints go free; --joints or --yes does not ask.  A "no" frees nothing: the servos keep holding.
    robot = tmp_path / "robot.toml"
    robot.write_text(ROBOT.format(port=port))
    assert ics35("--port", port, *NO_TIMEOUTS_OPTION, "move", "1", "25", "--deg").returncode == 0
    taught = tmp_path / "taught.json"
    files = [str(robot), str(taught)] if command == "teach" else [str(robot)]
    proc = ics35(*NO_TIMEOUTS_OPTION, command, *files, stdin="n\n")
    assert proc.returncode == 5, proc.stderr
    assert "Free all 3 joints" in proc.stderr and "falls" in proc.stderr and "--joints" in proc.stderr, proc.stderr
    assert "nothing was freed" in proc.stderr and "the joints are free" not in proc.stderr, proc.stderr
    assert not taught.exists() and not robot.with_suffix(".toml.bak").exists()
    proc = ics35(*NO_TIMEOUTS_OPTION, command, *files, "--joints", "a", stdin="\nq\n" if command == "teach" else "")
    assert "Free all" not in proc.stderr and "the joints are free" in proc.stderr, proc.stderr
    proc = ics35(*NO_TIMEOUTS_OPTION, command, *files, "--yes", stdin="\nq\n" if command == "teach" else "")
    assert "Free all" not in proc.stderr and "the joints are free" in proc.stderr, proc.stderr


def test_play_on_a_serial_line_asks_before_freeing_the_ics35_joints_it_reads(tmp_path: Path) -> None:
    # play freed every ICS 3.5 joint the motion moves to read where it stands, and said so only afterwards: a
    # standing humanoid's hips and ankles went limp under the docs' own wave, whose --start-pose stated its knees.
    # On a serial line it asks first, naming them (not an ICS 3.6 joint, read without freeing, nor one stated):
    # a "no" or no answer frees nothing, the servos keep holding.
    line = PtyLine((1, 2, 3), ics36=(3,))
    try:
        for servo in line.sim.servos:
            servo.command_position(8000)  # (a robot standing: every servo holds)
        robot = tmp_path / "robot.toml"
        robot.write_text(ROBOT.format(port=line.path))
        motion = tmp_path / "motion.json"
        pose = {"a": 0, "b": 0, "c": 0}
        motion.write_text(
            json.dumps({"format": "ics35-motion", "version": 1, "keyframes": [{"time": 0.5, "pose": pose}]})
        )
        played = [*NO_TIMEOUTS_OPTION, "play", str(robot), str(motion)]
        for answer in ("n\n", ""):
            proc = ics35(*played, stdin=answer)
            assert proc.returncode == 5, proc.stderr
            assert "Free joints a, b of" in proc.stderr and "ICS 3.5" in proc.stderr, proc.stderr
            assert "falls" in proc.stderr and "--start-pose" in proc.stderr, proc.stderr
            assert "nothing was freed" in proc.stderr and "--yes" in proc.stderr, proc.stderr
            assert not any(servo.free for servo in line.sim.servos)
        proc = ics35(*played, "--start-pose", "a=20", stdin="n\n")
        assert proc.returncode == 5 and "Free joint b of" in proc.stderr, proc.stderr
        assert not any(servo.free for servo in line.sim.servos)
        proc = ics35(*played, "--start-pose", "a=20,b=0")  # (nothing to free: not asked)
        assert proc.returncode == 0 and "[y/N]" not in proc.stderr, proc.stderr
        proc = ics35(*played, stdin="y\n")
        assert proc.returncode == 0 and "started free" in proc.stderr, proc.stderr
        proc = ics35(*played, "--yes")
        assert proc.returncode == 0 and "[y/N]" not in proc.stderr, proc.stderr
    finally:
        line.close()


@pytest.mark.parametrize(
    ("signum", "code", "name"),
    [(signal.SIGINT, 0, "Ctrl-C"), (signal.SIGTERM, 128 + signal.SIGTERM, "SIGTERM")],
    ids=["Ctrl-C", "SIGTERM"],
)
def test_ctrl_c_stops_play_smoothly_and_frees_as_asked(signum: int, code: int, name: str, tmp_path: Path) -> None:
    returncode, out, err = play_stopped_a_second_in(tmp_path, signum, "--loop", "--on-stop", "free")
    assert returncode == code, err
    assert f"stopped by {name}: slowing to rest, then the joints free" in err
    assert "joints left free" in out
    assert "Traceback" not in err


def test_play_stopped_by_ctrl_c_counts_the_same_time_played_in_its_table_and_its_summary(tmp_path: Path) -> None:
    # The table's last line counted the slow-down after the stop as motion played ("motion 2.0/3.6 s", with
    # --ramp 1), where the summary said "1.0 s of 3.6 s played".
    returncode, out, err = play_stopped_a_second_in(tmp_path, signal.SIGINT, "--ramp", "1")
    assert returncode == 0, err
    *_, table_line, summary = out.strip().splitlines()
    played = summary.split(": ")[1].split(" s of ")[0]
    assert f"motion {played:>4}/3.6 s" in table_line, out


def play_stopped_a_second_in(folder: Path, signum: int, *options: str) -> tuple[int, str, str]:
    """``ics35 play`` of the humanoid's wave with ``options``, sent ``signum`` a second into the motion: its exit
    code, stdout and stderr.  Its servos speak ICS 3.6 (written into ``folder``): what its tests are about is
    the stop, and the open does not read each ICS 3.5 joint once more at the whole allowance first."""
    played = (str(ics36_humanoid(folder)), str(EXAMPLES / "wave.json"))
    proc = subprocess.Popen(
        [sys.executable, "-m", "ics35_async.cli", *NO_TIMEOUTS_OPTION, "play", *played, *options],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        assert "play wave" in proc.stdout.readline()  # the title: playing
        assert "t=" in proc.stdout.readline()  # a second into the motion
        proc.send_signal(signum)
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return proc.returncode, out, err


@pytest.mark.parametrize("servos", ["ICS 3.5", "ICS 3.6", "both"])
def test_play_stopped_as_it_begins_says_what_played_and_what_the_joints_were_left_in(
    servos: str, tmp_path: Path
) -> None:
    # Ctrl-C as the motion starts: the summary said "0.0 s of 3.6 s played; joints left holding", while the
    # joints (ICS 3.5 servos, freed to be read at the start) had not been given a target and were left free;
    # ICS 3.6 servos, read without freeing and not commanded yet, are as they were found (free, on a robot just
    # powered up), not "holding" either.
    robot = (EXAMPLES / "humanoid.toml").read_text()
    if servos != "ICS 3.5":
        robot = robot.replace("ids=1-7&", "ids=1-7&ics36=1-7&")
    if servos == "ICS 3.6":
        robot = robot.replace("ids=1-10&", "ids=1-10&ics36=1-10&")
    robot_file = tmp_path / "humanoid.toml"
    robot_file.write_text(robot)
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "ics35_async.cli",
            *NO_TIMEOUTS_OPTION,
            "play",
            str(robot_file),
            str(EXAMPLES / "wave.json"),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        assert "play wave" in proc.stdout.readline()  # the title: the motion starts now
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, err
    summary = out.strip().splitlines()[-1]
    assert summary.startswith("play stopped by Ctrl-C after "), out
    assert "0.0 s of" not in summary, summary
    # What the summary says of the joints is what the table printed at the end shows them in.  (The stop
    # lands before the motion's first targets unless this machine took over 50 ms to deliver the signal.)
    rows = [line for line in out.splitlines() if "upper:" in line or "legs:" in line]
    # (A row saying "no reply": the simulator, another process, did not answer within the allowance, seen with
    # the machine loaded well past its two cores; what it says of that joint's torque is not read.)
    states = {line.split()[-1] for line in rows if not line.rstrip().endswith("no reply")}
    if states == {"held"}:
        assert "joints left holding" in summary and "found" not in summary, out
        return
    # (Seconds played count on the motion's clock from its start: on a loaded machine 0.1 s passed before the
    # stop with no target sent yet.)
    assert "holding" not in summary and "none had a target yet" in summary, summary
    if servos == "ICS 3.5":
        assert states == {"free"} and "joints left free" in summary, out
    elif servos == "ICS 3.6":
        assert states == {"found"} and "joints left as found" in summary, out
    else:
        assert states == {"free", "found"}, out
        assert "as found" in summary and "free" in summary, summary


def run_on_a_terminal(args: list[str], typed: list[tuple[str, str]]) -> tuple[int, list[str]]:
    """``ics35 ARGS`` with its stdout and stderr on one terminal (a pty) and a pipe as its stdin: for each
    ``(phrase, text)`` it waits until ``phrase`` is on the terminal, then types ``text``.  Returns the exit
    code and the lines on the screen at the end."""
    master, slave = os.openpty()
    proc = subprocess.Popen(
        [sys.executable, "-m", "ics35_async.cli", *args],
        stdin=subprocess.PIPE,
        stdout=slave,
        stderr=slave,
        env={**os.environ, "COLUMNS": "120", "TERM": "xterm"},
        text=True,
    )
    os.close(slave)
    screen = TerminalOutput(master)
    try:
        assert proc.stdin is not None
        for phrase, text in typed:
            screen.read_until(screen.shows(phrase), 60)
            proc.stdin.write(text)
            proc.stdin.flush()
        proc.stdin.close()
        screen.read_until(lambda: proc.poll() is not None, 60)
        proc.wait(30)
        screen.read_until(lambda: False, 60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        os.close(master)
    shown = screen.text
    assert "Traceback" not in shown, shown
    return proc.returncode, screen_of(shown)


def test_teach_on_a_terminal_shows_its_warning_about_a_pose_beyond_the_limits(port: str, tmp_path: Path) -> None:
    # Joint b (servo 2, reversed, -90..90) posed by hand at -100: the pose is recorded at its limit, and the
    # warning saying so was printed beside the live view, whose next redraw wrote over it.
    robot = tmp_path / "robot.toml"
    robot.write_text(ROBOT.format(port=port))
    # Sent until the servo reports it is there (the real-time servo takes its time; teach frees it where it is).
    deadline = time.monotonic() + scaled(20.0)
    while True:
        moved = ics35("--port", port, *NO_TIMEOUTS_OPTION, "move", "2", "100", "--deg", "--json")
        assert moved.returncode == 0, moved.stderr
        if json.loads(moved.stdout)["reported_degrees"] >= 99.5:
            break
        assert time.monotonic() < deadline, moved.stdout
        time.sleep(0.05)
    taught = tmp_path / "taught.json"
    # (A second pose after it: the first's warning, one line of the live view, was gone at the next capture's.)
    code, screen = run_on_a_terminal(
        [*NO_TIMEOUTS_OPTION, "teach", str(robot), str(taught), "--joints", "b"],
        [("Enter: capture", "\n"), ("pose 1 at", "\n"), ("pose 2 at", "q\n")],
    )
    assert code == 0, "\n".join(screen)
    assert [k["pose"] for k in json.loads(taught.read_text())["keyframes"]] == [{"b": -90.0}, {"b": -90.0}]
    text = " ".join(" ".join(screen).split())
    # (Where it stands to the count: the count nearest 100 degrees.)
    assert re.search(r"warning: joint b is at -100\.0\d*, beyond its limits -90\.\.90: recorded at the limit", text), (
        "\n".join(screen)
    )
    # (kept on the screen whatever comes after: which poses, and how far past the limit the joint stood)
    assert "warning: joint b recorded at its limit -90 in poses 1, 2 (it stood up to 10.0 past)" in text, "\n".join(
        screen
    )
    assert sum(f"teach: {taught}" in line for line in screen) == 1, "\n".join(screen)  # the view drawn once


@pytest.mark.parametrize("command", ["teach", "calibrate"])
def test_an_enter_typed_while_the_robot_opens_is_no_answer(port: str, tmp_path: Path, command: str) -> None:
    # An unplugged servo makes the open last a few --timeouts; an Enter pressed meanwhile (nothing on the screen
    # yet) was the first answer: teach captured a pose the hands had not set, calibrate took it as the neutral.
    robot = tmp_path / "robot.toml"
    robot.write_text(ROBOT.format(port=port) + '\n[joints.d]\nline = "main"\nid = 9\n')  # (ID 9: not on the line)
    files = [str(robot), str(tmp_path / "taught.json")] if command == "teach" else [str(robot)]
    master, slave = os.openpty()
    proc = subprocess.Popen(
        [sys.executable, "-m", "ics35_async.cli", "--timeout", "0.5", command, *files, "--joints", "a,d"],
        stdin=slave,
        stdout=slave,
        stderr=slave,
        env={**os.environ, "COLUMNS": "120", "TERM": "xterm"},
        start_new_session=True,
    )
    os.close(slave)
    screen = TerminalOutput(master)
    try:
        os.write(master, b"\n")  # typed at once: the command is still starting
        prompt = "Enter: capture" if command == "teach" else "Enter: this is the neutral pose"
        screen.read_until(screen.shows(prompt), 60)
        time.sleep(0.5)  # (an Enter still waiting would have been taken by now)
        os.write(master, b"q\n" if command == "teach" else b"\x04")  # ends teach; the end of input ends calibrate
        screen.read_until(lambda: proc.poll() is not None, 60)
        proc.wait(30)
        screen.read_until(lambda: False, 1)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        os.close(master)
    text = " ".join(screen.text.split())
    assert "Traceback" not in text, text
    assert proc.returncode == 5, text
    assert "pose 1 at" not in text and "now move each joint" not in text, text


@pytest.mark.parametrize("key", [b"q\n", b"\x03"], ids=["q", "ctrl-c"])
def test_teach_quits_at_once_with_a_line_where_nothing_answers(tmp_path: Path, key: bytes) -> None:
    # A robot's leg line unplugged (nothing answers there) under `teach --timeout 1`: after q each leg joint's free
    # waited the whole allowance for a reply, one after the other (ten joints: eleven seconds with nothing said),
    # though the stream had found them all silent.  Their frees still go out, but are waited for only briefly.
    # (what the test is about: each silent joint cost one of these; long enough that a quit's own time on a loaded
    # machine, over two seconds beside two CPU burners, stays well under it)
    allowance = scaled(4.0)
    legs = range(1, 6)
    robot = tmp_path / "robot.toml"
    # The main line in process, not on the pty simulator: a loaded machine's late reply there holds its servo for a
    # whole allowance (as it must: its reply could still come), and the quit's free to it waits that out.
    robot.write_text(
        ROBOT.format(port=f"sim://teach-quit-main-{key[0]}?ids=1-3")
        + f'\n[lines.legs]\nport = "sim://teach-quit-{key[0]}?ids=none"\n'
        + "".join(f'\n[joints.leg{i}]\nline = "legs"\nid = {i}\n' for i in legs)
    )
    typed: list[float] = []

    def now() -> bool:
        typed.append(time.monotonic())
        return True

    code, shown = typed_on_a_terminal(
        ["--timeout", str(allowance), "teach", str(robot), str(tmp_path / "taught.json"), "--yes"],
        # (q an allowance after the screen shows: the offline joints' probes, due half a second after the start,
        # each waiting the whole allowance, are on the wire one after the other by then)
        [("captured", b""), (allowance, b""), (now, key)],
    )
    took = time.monotonic() - typed[0]
    screen = "\n".join(screen_of(shown))
    assert "Traceback" not in shown, screen
    assert code == 5 and "no pose captured" in screen, screen  # (nothing captured: nothing written)
    said = " ".join(screen.split())  # (the warning wrapped at words, its further lines indented)
    assert "leg1, leg2, leg3, leg4, leg5 (servo IDs 1, 2, 3, 4, 5 on line legs) did not answer" in said, screen
    # Not even the leg line's transaction on the wire as q came (an offline joint's probe, a whole allowance, then
    # a guard read's before that joint's free): under one allowance in all (six allowances before, then two).
    assert took < allowance, took
