"""The pty server as an outside program sees it: a plain blocking pyserial client, no code of ours.

The client opens the port 8E1 with every setting in the constructor and never
re-configures it (see ics35_async.sim.pty_port for why), then checks every
byte of every command against the spec.
"""

from __future__ import annotations

import contextlib
import itertools
import os
import re
import select
import signal
import subprocess
import sys
import termios
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import serial

from ics35_async.protocol import Param, ReadParam
from ics35_async.sim import VirtualLine, start_subprocess, stop_subprocess
from ics35_async.sim.pty_port import PtyPort
from ics35_async.sim.pty_server import PtyServer
from tests.support.sim_servos import UnplugsWhenAsked
from tests.support.timing import GUARD

pytestmark = [pytest.mark.pty, pytest.mark.skipif(not sys.platform.startswith("linux"), reason="needs Linux ptys")]


def h(text: str) -> bytes:
    return bytes.fromhex(text)


@pytest.fixture(scope="module")
def four_servos() -> Iterator[str]:
    # Fast mode: the motion check below counts on time moving only with commands.
    proc, path = start_subprocess(["--ids", "0-3", "--memory", "20", "--fast"])
    yield path
    assert stop_subprocess(proc) == 0


def open_port(path: str, baud: int = 115200, timeout: float = 2.0) -> serial.Serial:
    return serial.Serial(path, baud, parity=serial.PARITY_EVEN, stopbits=1, bytesize=8, timeout=timeout)


def transact(port: serial.Serial, tx: bytes, reply_len: int) -> bytes:
    """Write, check the echo, return the reply (exactly ``reply_len`` bytes)."""
    port.write(tx)
    echo = port.read(len(tx))
    assert echo == tx, f"echo of {tx.hex(' ')} was {echo.hex(' ')}"
    reply = port.read(reply_len) if reply_len else b""
    assert len(reply) == reply_len, f"reply to {tx.hex(' ')}: {reply.hex(' ')}"
    return reply


# The spec's factory example (section 7), nibble pairs, for ID 1 at 115200; None = calibration.
FACTORY_ID1 = [
    *h(
        "05 0A 03 0C 07 0F 00 01 00 02 02 08 0F 0A 00 00"
    ),  # 5A, stretch 60, speed 127, punch 1, dead 2, damp 40, safe 250, flags 0
    *h("02 0C 0E 0C 00 0D 0A 0C"),  # pulse limits 11500, 3500
    None,
    None,
    *h("00 0A 05 00 03 0F"),  # baud code 10, temperature limit 80, current limit 63
    *[None] * 18,
    *h("00 03 00 00"),  # response 3, user offset 0
    None,
    None,
    *h("00 01 07 08 03 0C 0F 0E"),  # ID 1, stretch presets 120, 60, 254
]


def test_every_command_byte_for_byte(four_servos: str) -> None:
    with open_port(four_servos) as port:
        # Position: ID 0 at 115200 keeps the MSB; the others clear it.
        assert transact(port, h("80 3A 4C"), 3) == h("80 3A 4C")
        assert transact(port, h("81 3A 4C"), 3) == h("01 3A 4C")
        assert transact(port, h("81 00 00"), 3) == h("01 3A 4C")  # free, still at 7500
        # Parameter reads: the factory values.
        assert transact(port, h("A1 01"), 3) == h("21 01 1E")  # stretch 30
        assert transact(port, h("A1 02"), 3) == h("21 02 7F")  # speed 127
        assert transact(port, h("A1 03"), 3) == h("21 03 00")  # free: no current
        assert transact(port, h("A1 04"), 3) == h("21 04 7F")  # cold
        # Parameter writes (RAM), read back.
        assert transact(port, h("C1 01 14"), 3) == h("41 01 14")
        assert transact(port, h("C1 02 32"), 3) == h("41 02 32")
        assert transact(port, h("C1 03 1E"), 3) == h("41 03 1E")
        assert transact(port, h("C1 04 3C"), 3) == h("41 04 3C")
        assert transact(port, h("A1 01"), 3) == h("21 01 14")
        assert transact(port, h("A1 02"), 3) == h("21 02 32")
        # EEPROM read: the spec's factory image, unchanged by the RAM writes.
        reply = transact(port, h("A1 00"), 66)
        assert reply[:2] == h("21 00")
        image = reply[2:]
        for i, expected in enumerate(FACTORY_ID1):
            if expected is None:
                assert image[i] <= 0x0F
            else:
                assert image[i] == expected, f"EEPROM byte {i + 1}"
        # EEPROM write (speed 100 = 0x64), then read back.
        changed = bytearray(image)
        changed[4:6] = h("06 04")
        assert transact(port, h("C1 00") + changed, 2) == h("41 00")
        assert transact(port, h("A1 00"), 66) == h("21 00") + changed
        # Unknown sub-command and absent ID: echo only (the next exchange proves nothing followed).
        assert transact(port, h("A1 05"), 0) == b""
        assert transact(port, h("85 3A 4C"), 0) == b""
        # Generic memory device 20: write two bytes, read them back.
        write_reply = transact(port, h("D4 7F 00 02 0A 0B 0C 0D"), 4)
        assert write_reply in (h("D4 7F 00 02"), h("54 7F 00 02"))
        read_reply = transact(port, h("B4 7F 00 02"), 8)
        assert read_reply[:4] in (h("B4 7F 00 02"), h("34 7F 00 02")) and read_reply[4:] == h("0A 0B 0C 0D")
        # The ID command with four servos on the line: a garbled answer (wired-AND plus a glitch).
        assert transact(port, h("FF 00 00 00"), 2) == bytes([0xE0 & 0xE1 & 0xE2 & 0xE3, 0x00])
        # Motion: the reported position climbs toward the target.
        positions = []
        for _ in range(5):
            reply = transact(port, h("82 46 50"), 3)  # ID 2 to 9040
            positions.append((reply[1] << 7) | reply[2])
        assert positions[0] == 7500
        assert all(a < b for a, b in itertools.pairwise(positions))
        assert positions[-1] < 9040
        time.sleep(0.05)
        assert port.in_waiting == 0


def test_id_read_and_write_on_a_single_servo_line(pty_sim: Any) -> None:
    path = pty_sim("--ids", "5").path
    with open_port(path) as port:
        assert transact(port, h("FF 00 00 00"), 1) == h("E5")
        assert transact(port, h("F4 01 01 01"), 1) == h("F4")
        assert transact(port, h("FF 00 00 00"), 1) == h("F4")
        assert transact(port, h("94 3A 4C"), 3) == h("14 3A 4C")  # answers as ID 20 now
        assert transact(port, h("85 3A 4C"), 0) == b""


def test_line_runs_at_the_clients_baud(four_servos: str) -> None:
    with open_port(four_servos, 1250000) as port:
        assert transact(port, h("81 3A 4C"), 0) == b""  # servos at 115200 do not hear it
        time.sleep(0.05)
        assert port.in_waiting == 0
    with open_port(four_servos, 115200) as port:
        assert transact(port, h("81 3A 4C"), 3) == h("01 3A 4C")


def test_reopening_at_the_same_speed_works(four_servos: str) -> None:
    for _ in range(3):
        with open_port(four_servos) as port:
            assert transact(port, h("A3 02"), 3) == h("23 02 7F")


@pytest.mark.realtime
def test_high_speed_servos(pty_sim: Any) -> None:
    path = pty_sim("--ids", "1", "--baud", "1250000", "--realtime").path
    with open_port(path, 1250000) as port:
        started = time.perf_counter()
        assert transact(port, h("81 3A 4C"), 3) == h("01 3A 4C")
        elapsed = time.perf_counter() - started
        # Never faster than the wire (6 bytes at 1.25 Mbit/s + 100 us turnaround);
        # the upper bound is only there to catch a hang.
        assert 6 * 11 / 1250000 + 100e-6 <= elapsed < 1.0
    with open_port(path, 115200, timeout=0.3) as port:
        assert transact(port, h("81 3A 4C"), 0) == b""
        assert port.read(1) == b""


@pytest.mark.realtime
def test_unplug_and_replug_keep_the_path(pty_sim: Any) -> None:
    path = pty_sim("--ids", "1,7", "--faults", "unplug@7:1", "--replug-after", "0.3").path
    first_target = os.path.realpath(path)
    assert first_target.startswith("/dev/pts/")
    with open_port(path) as port:
        assert transact(port, h("81 3A 4C"), 3) == h("01 3A 4C")
        # Answered, then the port goes.  A client slower than the hang-up (a loaded machine) loses the
        # reply with the port, as it would with a real adapter's tty: the hang-up discards unread input.
        try:
            answered: bytes | None = transact(port, h("87 3A 4C"), 3)
        except serial.SerialException:
            answered = None
        assert answered in (h("07 3A 4C"), None)
        with pytest.raises(serial.SerialException):
            for _ in range(50):
                port.read(1)
    deadline = time.monotonic() + 10
    while not os.path.exists(path):
        assert time.monotonic() < deadline, "the port did not come back"
        time.sleep(0.02)
    with open_port(path) as port:
        assert transact(port, h("81 3A 4C"), 3) == h("01 3A 4C")


def test_a_servo_that_pulls_its_line_as_it_hears_a_command_gets_no_reply_out() -> None:
    # A device that unplugs the line from inside its own handling (the tests' servo that pulls the line as a scan
    # probes it) still gave its answer: the server wrote the reply when it was due at once, and only then
    # followed the unplug.  A scan then counted the servo whose line went (a browser test, now and then).
    puller = UnplugsWhenAsked(3, ReadParam)
    line = VirtualLine([puller], realtime=False)  # every answer due at once: the reply is never late for the race
    server = PtyServer(line)
    path = str(server.open())
    thread = threading.Thread(target=server.serve, daemon=True)
    thread.start()
    try:
        puller.line = line
        probe = ReadParam(3, Param.STRETCH)
        fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        received = b""
        try:
            os.write(fd, probe.tx)
            deadline = time.monotonic() + GUARD
            while time.monotonic() < deadline:
                readable, _, _ = select.select([fd], [], [], 0.05)
                if readable:
                    try:
                        chunk = os.read(fd, 64)
                    except OSError:  # the hang-up
                        break
                    if not chunk:
                        break
                    received += chunk
        finally:
            os.close(fd)
        assert not line.plugged
        assert received[probe.echo_len :] == b"", f"a reply got out after the line was pulled: {received.hex(' ')}"
    finally:
        server.stop()
        thread.join(5)
        server.close()
        line.close()


def test_bad_arguments_exit_with_usage_error() -> None:
    with pytest.raises(RuntimeError):
        start_subprocess(["--ids", "0-99"], timeout=10)


def run_sim(*args: str) -> subprocess.CompletedProcess[str]:
    """``ics35 sim`` with ``args``, for arguments it must refuse (it would otherwise serve until stopped)."""
    return subprocess.run(
        [sys.executable, "-m", "ics35_async.cli", "sim", "--ids", "1", *args],
        capture_output=True,
        text=True,
        timeout=30,
    )


@pytest.mark.parametrize("value", ["inf", "nan", "1e12"])
def test_a_replug_time_no_timer_can_wait_is_a_usage_error(value: str) -> None:
    """``--replug-after inf`` served, said the port "comes back in inf s" as it was pulled, then printed a timer
    thread's ``OverflowError`` traceback."""
    proc = run_sim("--unplug-after", "0.1", "--replug-after", value)
    assert proc.returncode == 2, proc.stderr
    assert "--replug-after" in proc.stderr and "Traceback" not in proc.stderr, proc.stderr


@contextlib.contextmanager
def serving_sim(*args: str) -> Iterator[subprocess.Popen[str]]:
    """``ics35 sim --ids 1 --fast`` with ``args`` in a process of its own, its output piped (its first line: the
    port's path); killed after the block if it still runs."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "ics35_async.cli", "sim", "--ids", "1", "--fast", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        yield proc
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


@pytest.mark.parametrize("option", ["--link", "--tap"])
def test_a_link_path_that_is_not_the_simulators_own_is_refused_and_left_alone(tmp_path: Path, option: str) -> None:
    precious = tmp_path / "notes.txt"
    precious.write_text("keep me")
    (tmp_path / "adir").mkdir()
    for path, words in (
        (precious, "exists"),
        (tmp_path / "adir", "exists"),
        (tmp_path / "no" / "such" / "dir" / "tty", "no such directory"),
    ):
        before = sorted(p.name for p in tmp_path.iterdir())
        proc = run_sim(option, str(path))
        assert proc.returncode == 2, proc.stderr
        assert "Traceback" not in proc.stderr and words in proc.stderr and str(path) in proc.stderr
        assert sorted(p.name for p in tmp_path.iterdir()) == before  # nothing made, nothing removed
    assert precious.read_text() == "keep me" and not precious.is_symlink()


@pytest.mark.parametrize("option", ["--link", "--tap"])
@pytest.mark.parametrize("path", ["", ".", "/"])
def test_a_link_path_without_a_file_name_is_refused_in_words(option: str, path: str) -> None:
    proc = run_sim(option, path)  # (an empty variable in a script: --link "$DIR/$NAME" with neither set)
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr and ("file name" in proc.stderr or "empty" in proc.stderr), proc.stderr


def test_a_relative_link_is_printed_as_a_path_from_anywhere(tmp_path: Path) -> None:
    # The path printed is what another terminal, in another directory, opens as --port.
    port = PtyPort("tty-rel")
    try:
        assert port.path.is_absolute() and port.path == Path.cwd() / "tty-rel"
    finally:
        port.dispose()


@pytest.mark.parametrize("option", ["--replay", "--record"])
def test_a_session_file_that_is_a_directory_is_named_with_its_option(tmp_path: Path, option: str) -> None:
    proc = run_sim(option, str(tmp_path))
    assert proc.returncode == 2, proc.stderr
    assert f"{option} {tmp_path}: Is a directory" in proc.stderr and "Errno" not in proc.stderr, proc.stderr


def test_a_link_the_simulator_left_behind_is_replaced(tmp_path: Path) -> None:
    # A simulator killed with SIGKILL leaves its link pointing at a pty that is gone: the next takes it over.
    link = tmp_path / "ttyICS"
    os.symlink("/dev/pts/999999", link)
    port = PtyPort(link)
    port.open()
    try:
        assert os.readlink(link) == port.pts_name
    finally:
        port.dispose()
    assert not link.exists() and not link.is_symlink()


def test_a_link_a_running_simulator_serves_is_refused(tmp_path: Path) -> None:
    # Taken over, the first simulator's clients would find other servos, and the link would be gone
    # for good once the second stopped.
    link = tmp_path / "tty"
    first = PtyPort(link)
    first.open()
    try:
        proc = run_sim("--link", str(link))
        assert proc.returncode == 2, proc.stderr
        assert "in use" in proc.stderr and str(link) in proc.stderr
        assert os.readlink(link) == first.pts_name
    finally:
        first.dispose()


def test_a_link_whose_folder_is_removed_while_serving_stops_the_simulator_in_words(tmp_path: Path) -> None:
    # A temporary folder cleaned away under a running simulator: at the next replug the link could not be made
    # again, and the simulator died with a traceback (FileNotFoundError of the link's .new sibling).
    folder = tmp_path / "run"
    folder.mkdir()
    link = folder / "tty"
    replug = ["--unplug-after", "0.3", "--replug-after", "0.3"]
    with serving_sim("--link", str(link), *replug) as proc:
        assert proc.stdout is not None and proc.stdout.readline().strip() == str(link)
        for left in folder.iterdir():  # (the link, and the lock the simulator keeps beside it)
            left.unlink()
        folder.rmdir()
        _, err = proc.communicate(timeout=GUARD)
    assert proc.returncode == 1, err
    assert "Traceback" not in err and f"{folder}" in err and "gone" in err, err
    assert "served 0 transactions" in err  # its end said as ever


def test_a_link_to_a_pty_in_use_names_the_process_that_holds_it(tmp_path: Path) -> None:
    # A link a killed simulator left leads to a /dev/pts number since reused (a terminal): refused, as a running
    # simulator's is, but naming who holds the pty, so the user can tell which of the two it is before removing.
    master, slave = os.openpty()
    try:
        link = tmp_path / "tty"
        os.symlink(os.ttyname(slave), link)
        proc = run_sim("--link", str(link))
        said = " ".join(proc.stderr.split())
        assert proc.returncode == 2, proc.stderr
        assert "in use" in said and f"process {os.getpid()}" in said, said
        assert os.readlink(link) == os.ttyname(slave)  # left as it was
    finally:
        os.close(slave)
        os.close(master)


@contextlib.contextmanager
def killed_simulators_link(link: Path) -> Iterator[str]:
    """``ics35 sim --link link`` started, then killed with SIGKILL (no chance to remove its link); yields the
    /dev/pts path its link leads to (free, or already another program's: other processes open ptys too)."""
    with serving_sim("--link", str(link)) as proc:
        assert proc.stdout is not None and proc.stdout.readline().strip() == str(link)
        pts = os.readlink(link)
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=GUARD)
    assert link.is_symlink()  # left behind
    yield pts


@contextlib.contextmanager
def killed_simulators_link_to_our_pty(link: Path) -> Iterator[tuple[str, int]]:
    """:func:`killed_simulators_link`, its /dev/pts number then taken by a new pty of ours, as another program (a
    terminal) would take it; yields the number's path and that pty's master (non-blocking).  Linux hands out the
    lowest free number, but a process of its own (the suite's other workers open ptys all the time) may take it
    first: then the simulator is started and killed again."""
    for _ in range(10):
        with killed_simulators_link(link) as pts:
            held: list[tuple[int, int]] = []
            try:
                for _ in range(64):
                    master, slave = os.openpty()
                    held.append((master, slave))
                    if os.ttyname(slave) == pts:
                        os.set_blocking(master, False)
                        yield pts, master
                        return
            finally:
                for master, slave in held:
                    os.close(master)
                    os.close(slave)
        link.unlink()
    pytest.fail("no pty freed by a killed simulator came to this process in 10 tries")


def test_a_killed_simulators_link_to_a_since_reused_pty_is_replaced_by_the_next(tmp_path: Path) -> None:
    # A SIGKILLed simulator leaves its link; its /dev/pts number goes to the next program that opens a pty (a
    # terminal). The next simulator at that path was refused ("in use") though no simulator served it: what the
    # running simulator holds beside its link tells a running one from a killed one, whatever the pty number.
    link = tmp_path / "tty"
    with killed_simulators_link_to_our_pty(link) as (pts, other):
        with serving_sim("--link", str(link)) as proc:
            assert proc.stdout is not None and proc.stdout.readline().strip() == str(link)
            assert os.readlink(link) != pts
            with open_port(str(link)) as port:
                assert transact(port, h("81 3A 4C"), 3) == h("01 3A 4C")
            proc.send_signal(signal.SIGINT)
            _, err = proc.communicate(timeout=GUARD)
        assert proc.returncode == 0 and "Traceback" not in err, err
        with pytest.raises(BlockingIOError):
            os.read(other, 100)  # the other program's pty heard nothing
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # a simulator that stops leaves nothing


def test_a_running_simulators_link_is_refused_naming_it(tmp_path: Path) -> None:
    link = tmp_path / "tty"
    with serving_sim("--link", str(link)) as first:
        assert first.stdout is not None and first.stdout.readline().strip() == str(link)
        pts = os.readlink(link)
        proc = run_sim("--link", str(link))
        said = " ".join(proc.stderr.split())
        assert proc.returncode == 2 and f"simulator (process {first.pid})" in said, said
        assert os.readlink(link) == pts
        # Its lock left as it was: a third is refused too.
        assert run_sim("--link", str(link)).returncode == 2


def scan_at(port: Path) -> subprocess.CompletedProcess[str]:
    """``ics35 --port PORT scan``, as a person runs it."""
    command = [sys.executable, "-m", "ics35_async.cli", "--port", str(port), "scan"]
    return subprocess.run(command, capture_output=True, text=True, timeout=30)


def test_a_killed_simulators_link_to_a_since_reused_pty_is_not_opened(tmp_path: Path) -> None:
    # ics35 --port LINK sent its frames to whatever program had taken the pty number since (a terminal's screen).
    link = tmp_path / "tty"
    with killed_simulators_link_to_our_pty(link) as (pts, other):
        proc = scan_at(link)
        said = " ".join(proc.stderr.split())
        assert proc.returncode == 3 and "Traceback" not in said, said
        assert "simulator" in said and "killed" in said and pts in said and "another program" in said, said
        with pytest.raises(BlockingIOError):
            os.read(other, 100)  # nothing written to it


def test_a_killed_simulators_link_says_the_simulator_was_killed(tmp_path: Path) -> None:
    link = tmp_path / "tty"
    with killed_simulators_link(link) as pts:
        proc = scan_at(link)
    said = " ".join(proc.stderr.split())
    assert proc.returncode == 3 and "Traceback" not in said, said
    # (The number may have gone to a program of another user's meanwhile: said so, and still not opened.)
    assert pts in said and "killed" in said and ("no longer exists" in said or "another program's" in said), said
    assert "ics35 sim --link" in said and "cable" not in said and "list ports" not in said, said


@pytest.mark.realtime
def test_scheduled_unplug_from_the_command_line(pty_sim: Any) -> None:
    path = pty_sim("--ids", "1", "--unplug-after", "0.4", "--replug-after", "0.4").path
    deadline = time.monotonic() + 10
    while os.path.exists(path):
        assert time.monotonic() < deadline, "the port was never unplugged"
        time.sleep(0.01)
    while not os.path.exists(path):
        assert time.monotonic() < deadline, "the port did not come back"
        time.sleep(0.01)
    with open_port(path) as port:
        assert transact(port, h("81 3A 4C"), 3) == h("01 3A 4C")


SCHEDULED = ("--unplug-after", "0.3", "--replug-after", "0.5")


def test_a_scheduled_unplug_is_said_on_the_simulators_terminal_with_when_the_port_comes_back() -> None:
    # ics35 sim --unplug-after said nothing as the port went: a person watching its terminal could not tell the
    # simulator's doing from their program's fault, nor when to expect the port back.
    with serving_sim(*SCHEDULED) as proc:
        assert proc.stdout is not None and proc.stderr is not None
        path = proc.stdout.readline().strip()
        deadline = time.monotonic() + GUARD
        while os.path.exists(path):
            assert time.monotonic() < deadline, "the port was never unplugged"
            time.sleep(0.01)
        while not os.path.exists(path):
            assert time.monotonic() < deadline, "the port did not come back"
            time.sleep(0.01)
        proc.terminate()
        _, err = proc.communicate(timeout=GUARD)
    assert proc.returncode == 0, err
    said = [line for line in err.splitlines() if "unplugged" in line]
    assert len(said) == 1, err  # one line, between the serving line and the end's
    assert re.fullmatch(
        r"ics35 sim: the port was unplugged \(\d+\.\d s after the start\): it comes back in 0\.5 s, at the same path",
        said[0],
    ), said
    lines = err.splitlines()
    assert lines.index(said[0]) > 0 and lines[-1].startswith("ics35 sim: served"), err


def test_record_over_the_pty_then_replay_the_recording(tmp_path: Path, pty_sim: Any) -> None:
    recording = tmp_path / "session.txt"
    script = [h("81 3A 4C"), h("A2 02"), h("C3 02 14"), h("A3 02"), h("85 3A 4C")]
    # Echo and reply of each, and the echo alone for ID 5, which nobody has (the corrupt fault changes
    # bytes in place, not how many): read by count, with a timeout only against a hang, so a loaded
    # machine's slow answer is still waited for.
    sizes = [6, 5, 6, 5, 3]
    recorder = pty_sim("--ids", "1-3", "--record", str(recording), "--faults", "corrupt@2:1")
    with open_port(recorder.path, timeout=GUARD) as port:
        live = []
        for tx, size in zip(script, sizes, strict=True):
            port.write(tx)
            live.append(port.read(size))
    assert recorder.stop() == 0  # the recording is complete once the server has stopped
    assert live[1][:2] == h("A2 02") and live[1][2:] != h("22 02 7F")  # the corrupted reply
    assert len(recording.read_text().splitlines()) == 1 + len(script)

    path = pty_sim("--replay", str(recording)).path
    with open_port(path, timeout=GUARD) as port:
        for tx, expected in zip(script, live, strict=True):
            port.write(tx)
            assert port.read(len(expected)) == expected
        time.sleep(0.05)
        assert port.in_waiting == 0  # nothing more than was recorded


def test_noisy_servos_from_the_command_line_report_positions_that_never_agree() -> None:
    # The URL's noisy=IDS (a broken potentiometer) had no ics35 sim option: a program across a pty could not be
    # tried against one.  Servo 2 is noisy, servo 1 beside it is not; both stand still, free.
    with serving_sim("--ids", "1-2", "--noisy", "2") as proc:
        assert proc.stdout is not None
        with open_port(proc.stdout.readline().strip()) as port:
            reports = {sid: [] for sid in (1, 2)}
            for _ in range(6):
                for sid, positions in reports.items():
                    reply = transact(port, bytes([0x80 | sid, 0, 0]), 3)  # free: its reply reports the position
                    positions.append((reply[1] << 7) | reply[2])
        proc.terminate()
        proc.communicate(timeout=GUARD)
    assert len(set(reports[1])) == 1, reports
    assert all(a != b for a, b in itertools.pairwise(reports[2])), reports


def position_after_a_pause(pty_sim: Any, args: list[str], pause: float = 0.5) -> int:
    """Send servo 1 towards 9040, wait ``pause`` s of wall time, then free it: the position it reports."""
    path = pty_sim("--ids", "1", *args).path
    with open_port(path) as port:
        transact(port, h("81 46 50"), 3)
        time.sleep(pause)  # 1540 counts at full speed take 0.13 s of real time
        reply = transact(port, h("81 00 00"), 3)
        return (reply[1] << 7) | reply[2]


@pytest.mark.realtime
def test_pty_server_runs_in_real_time_by_default(pty_sim: Any) -> None:
    # Other programs use the pty in real time: a servo must keep moving between their commands.
    assert position_after_a_pause(pty_sim, []) == 9040


def test_fast_opts_out_of_real_time(pty_sim: Any) -> None:
    # Fast mode: time moves only with the wire time of commands, so the servo has barely moved.
    assert position_after_a_pause(pty_sim, ["--fast"]) < 7600


@pytest.mark.parametrize(
    "command", [[sys.executable, "-m", "ics35_async.sim"], [sys.executable, "-m", "ics35_async.cli", "sim"]]
)
def test_help_says_real_time_is_the_default(command: list[str]) -> None:
    proc = subprocess.run([*command, "--help"], capture_output=True, text=True, timeout=30)
    assert proc.returncode == 0, proc.stderr
    text = " ".join(proc.stdout.split())
    assert "--fast" in text
    assert "real time (wire timing) by default" in text


def test_on_exit_the_server_counts_one_transaction_in_the_singular(tmp_path: Path) -> None:
    notes_path = tmp_path / "notes.txt"  # ("served 1 transactions")
    with open(notes_path, "w", encoding="utf-8") as notes:
        proc, path = start_subprocess(["--fast", "--ids", "1"], notes=notes)
        try:
            with open_port(path) as port:
                assert transact(port, h("81 3A 4C"), 3) == h("01 3A 4C")
        finally:
            assert stop_subprocess(proc) == 0
    assert "ics35 sim: served 1 transaction" in notes_path.read_text(encoding="utf-8").splitlines()


def test_on_exit_the_server_says_what_it_served_and_its_last_reads_and_writes(tmp_path: Path) -> None:
    # The notes a failing test is read against: the transaction count, and with --last the last
    # reads and writes stamped with time.monotonic(), the clock this process reads too.
    notes_path = tmp_path / "notes.txt"
    with open(notes_path, "w", encoding="utf-8") as notes:
        proc, path = start_subprocess(["--fast", "--ids", "1", "--last", "4"], notes=notes)
        try:
            before = time.monotonic()
            with open_port(path) as port:
                assert transact(port, h("81 3A 4C"), 3) == h("01 3A 4C")
                assert transact(port, h("A1 01"), 1) != b""
            after = time.monotonic()
        finally:
            assert stop_subprocess(proc) == 0
    lines = notes_path.read_text(encoding="utf-8").splitlines()
    assert "ics35 sim: served 2 transactions" in lines
    last = [line.split(maxsplit=4)[3:] for line in lines if line.startswith("ics35 sim: at ")]
    assert [what for _, what in last] == ["wrote 01 3a 4c", "read  a1 01", "wrote a1 01", last[3][1]]
    assert last[3][1].startswith("wrote 21 01 ")  # the stretch read's reply (its value: what the servo has)
    times = [float(when) for when, _ in last]
    assert before <= times[0] <= times[-1] <= after


def test_a_client_opening_as_the_last_one_closes_keeps_its_speed() -> None:
    # The server resets the pty when its last client closes.  A client that opens and sets its speed
    # while that reset runs must not have its speed overwritten: the server would take it to run at
    # the last client's speed and answer bytes sent at another.  The new client opens here at the
    # worst moment, the instant the reset has first looked at the pty, from a profile hook.
    port = PtyPort()
    port.open()
    try:
        with open_port(str(port.path), 1250000) as first:
            first.write(b"\x81")
            while port.read() is None:
                time.sleep(0.001)
            assert port.client_baudrate() == 1250000
            port.park_speed(only_if=1250000)  # as the server does at a client's first bytes
        second: list[serial.Serial] = []
        writes: list[object] = []

        def hook(frame: Any, event: str, arg: Any) -> None:
            # The reset's first look at the pty (its settings, or whether a client is there): open then.
            looked = arg is termios.tcgetattr or getattr(arg, "__name__", "") == "poll"
            if event == "c_return" and looked and not second:
                second.append(open_port(str(port.path), 115200))
            elif event == "c_call" and arg is termios.tcsetattr:
                writes.append(arg)

        def hang_up() -> None:
            """Read until the server sees the last client gone (and resets the pty), under the hook."""
            deadline = time.monotonic() + GUARD
            while time.monotonic() < deadline:
                sys.setprofile(hook)
                try:
                    closed = port.read() == b""
                finally:
                    sys.setprofile(None)
                if closed:
                    return
                time.sleep(0.001)
            pytest.fail("the server never saw the client go")

        hang_up()
        assert second, "the reset never looked at the pty"
        with second[0]:
            second[0].write(b"\x81")
            assert port.client_baudrate() == 115200
            assert port.read() == b"\x81"
            port.park_speed(only_if=115200)
        writes.clear()
        # With no one opening now, the reset after a pyserial client writes nothing at all (it left the
        # pty raw, and its speed was parked at its first bytes): no write, no window for the race.
        second.append(second[0])  # the hook opens no more clients
        hang_up()
        assert writes == []
    finally:
        port.dispose()


@pytest.mark.parametrize(("ids", "words"), [("1", "1 servo at 115200"), ("1-2", "2 servos at 115200")])
def test_its_first_note_counts_the_servos_in_words(tmp_path: Path, ids: str, words: str) -> None:
    notes = tmp_path / "notes.txt"
    with notes.open("w") as file:
        proc, _ = start_subprocess(["--ids", ids, "--fast"], notes=file)
        stop_subprocess(proc)
    first = notes.read_text().splitlines()[0]
    assert first.startswith(f"ics35 sim: {words} bit/s"), first
