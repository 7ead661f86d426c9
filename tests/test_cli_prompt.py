"""Ctrl-C at a [y/N] question: the first one ends the command with exit code 130, nothing written.

A real process gets a real SIGINT while it waits on the question (no mocks):
the question is asked inside the event loop, whose own SIGINT handler used to
swallow the first Ctrl-C.
"""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator

import pytest

from ics35_async.sim import serving
from tests.support.cli_runs import DUMP_ON_USR1
from tests.support.terminal import screen_of, typed_on_a_terminal

pytestmark = [
    pytest.mark.pty,
    pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the pty simulator needs Linux"),
]

# Each program dumps its threads' stacks on SIGUSR1, so a command that outlives its Ctrl-C says where it is.
LOOPS = {
    "asyncio": DUMP_ON_USR1 + "import sys; sys.modules['uvloop'] = None; from ics35_async.cli import main; main()",
    "uvloop": DUMP_ON_USR1 + "from ics35_async.cli import main; main()",
}


@pytest.fixture(scope="module")
def port() -> Iterator[str]:
    with serving(["--ids", "1,2"]) as path:
        yield path


def read_until(fd: int, marker: bytes, limit: float = 30.0) -> bytes:
    """Bytes from ``fd`` up to ``marker`` (a generous limit: this waits for the process, it measures nothing)."""
    seen = b""
    end = time.monotonic() + limit
    while marker not in seen:
        ready, _, _ = select.select([fd], [], [], max(0.0, end - time.monotonic()))
        if not ready:
            raise AssertionError(f"no {marker!r} from the command; it wrote: {seen.decode(errors='replace')}")
        chunk = os.read(fd, 4096)
        if not chunk:
            raise AssertionError(f"the command ended before {marker!r}: {seen.decode(errors='replace')}")
        seen += chunk
    return seen


# demo on "hardware" (a pty) asks before moving the servos a scan found; eeprom set asks before writing.
COMMANDS = {
    "demo": ["--timeout", "0.05", "demo", "--seconds", "1"],
    "eeprom-set": ["eeprom", "set", "1", "speed=5"],
}


@pytest.mark.parametrize("command", list(COMMANDS))
@pytest.mark.parametrize("loop", list(LOOPS))
@pytest.mark.parametrize(
    ("signum", "exit_code"), [(signal.SIGINT, 130), (signal.SIGTERM, 143)], ids=["Ctrl-C", "SIGTERM"]
)
def test_first_ctrl_c_at_the_question_exits_130(
    port: str, loop: str, command: str, signum: int, exit_code: int
) -> None:
    # (SIGTERM as Ctrl-C: the question blocks the event loop, so it cannot be a cancelled task's end)
    if loop == "uvloop":
        pytest.importorskip("uvloop")
    where = port if command == "demo" else "sim://?ids=1"
    proc = subprocess.Popen(
        [sys.executable, "-c", LOOPS[loop], "--port", where, *COMMANDS[command]],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    try:
        assert proc.stderr is not None
        before = read_until(proc.stderr.fileno(), b"[y/N]")
        proc.send_signal(signum)
        try:
            code = proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.send_signal(signal.SIGUSR1)
            time.sleep(2)
            proc.kill()
            stacks = proc.stderr.read().decode(errors="replace")
            raise AssertionError(f"the command had not ended 20 s after its Ctrl-C; its stacks:\n{stacks}") from None
        rest = proc.stderr.read().decode(errors="replace")
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert code == exit_code, rest
    assert "Traceback" not in rest
    # In the words of what the command would have done: demo moves servos, eeprom set writes.
    assert ("nothing moved" if command == "demo" else "nothing was written") in rest, rest
    if command == "demo":
        assert b"Move servo(s) 1, 2" in before
        assert "written" not in rest


@pytest.mark.parametrize("command", list(COMMANDS))
@pytest.mark.parametrize("gap", [0.005, 0.03, 0.08])
def test_a_double_ctrl_c_at_the_question_ends_as_the_first_says(port: str, command: str, gap: float) -> None:
    # The second press landed as the command ended: Python's own handler, back after the question, printed a
    # KeyboardInterrupt traceback over the command's last words, or killed it as Python ended (by SIGINT).
    where = port if command == "demo" else "sim://?ids=1"
    code, written = typed_on_a_terminal(["--port", where, *COMMANDS[command]], [("[y/N]", b"\x03"), (gap, b"\x03")])
    screen = screen_of(written)
    assert code == 130, "\n".join(screen)
    assert "Traceback" not in written and "Exception" not in written, "\n".join(screen)
    nothing = "nothing moved" if command == "demo" else "nothing was written"
    assert any(f"error: interrupted at the question: {nothing}" in line for line in screen), "\n".join(screen)
    # The second press's ^C, echoed below the last words, was left for the shell's prompt to follow ("^C$ ").
    # (A press later than the process's own end, as a slower double Ctrl-C's can be, is the shell's to echo.)
    if gap < 0.05:
        assert "^C" not in [line for line in screen if line.strip()][-1], "\n".join(screen)


def test_ctrl_c_just_before_the_read_still_ends_the_question(monkeypatch: pytest.MonkeyPatch) -> None:
    """A Ctrl-C that lands between the question's last signal check and its blocking read.

    The C-level handler then only notes the signal and the read goes on waiting for
    a line that never comes. Here the note is made on another thread (its handler
    runs there, as it does when the signal lands in that window), so the main
    thread sits in the read exactly as it would. The read must notice within moments.
    """
    from ics35_async.cli._prompt import ask_yes_no
    from ics35_async.cli._settings import CliError, ExitCode

    reader, writer = os.pipe()
    monkeypatch.setattr(sys, "stdin", os.fdopen(reader, "r"))

    ended = threading.Event()
    answered: list[bytes] = []

    def ctrl_c_elsewhere() -> None:
        time.sleep(0.3)
        # To this helper thread itself: the handler runs here and only notes the signal, while the main
        # thread stays in its read, as when the signal lands between the last check and the read.
        signal.pthread_kill(threading.get_ident(), signal.SIGINT)
        # A read that never notices gets an answer after a while, so the test fails instead of hanging.
        if not ended.wait(10.0):
            answered.append(b"n\n")
            os.write(writer, b"n\n")

    helper = threading.Thread(target=ctrl_c_elsewhere, daemon=True)
    helper.start()
    try:
        with pytest.raises(CliError) as raised:
            ask_yes_no("Write?")
    finally:
        ended.set()
        helper.join()
        os.close(writer)
        sys.stdin.close()
    assert not answered, "the question went on waiting after the Ctrl-C, until the answer came"
    assert raised.value.code == ExitCode.INTERRUPTED


def eeprom_set_started_ignoring_sigint() -> subprocess.Popen[bytes]:
    """``ics35 eeprom set`` (it asks before it writes) as a script's background job starts: SIGINT ignored."""
    return subprocess.Popen(
        [sys.executable, "-c", LOOPS["asyncio"], "--port", "sim://?ids=1", "eeprom", "set", "1", "speed=5"],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN),  # (what a shell does)
    )


def test_a_command_started_ignoring_sigint_keeps_ignoring_it_at_the_question() -> None:
    # A script's background job starts with SIGINT ignored (the Ctrl-C typed for the script's foreground
    # command is not for it): the question turned Ctrl-C back on while it asked, so that Ctrl-C ended it.
    proc = eeprom_set_started_ignoring_sigint()
    try:
        assert proc.stderr is not None and proc.stdin is not None
        read_until(proc.stderr.fileno(), b"[y/N]")
        proc.send_signal(signal.SIGINT)
        time.sleep(0.5)  # (a Ctrl-C heard would end it at once: see the test above)
        assert proc.poll() is None, proc.stderr.read().decode(errors="replace")
        proc.stdin.write(b"n\n")
        proc.stdin.close()
        code = proc.wait(timeout=20)
        rest = proc.stderr.read().decode(errors="replace")
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert code != 130 and "interrupted" not in rest, rest


def test_sigterm_still_ends_the_question_of_a_command_started_ignoring_sigint() -> None:
    # The question told a stop signal it was asking by finding Ctrl-C's handler on: with SIGINT left ignored,
    # SIGTERM only cancelled the loop's task, which the question's blocking read holds up: it waited on.
    proc = eeprom_set_started_ignoring_sigint()
    try:
        assert proc.stderr is not None
        read_until(proc.stderr.fileno(), b"[y/N]")
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(timeout=20)
        rest = proc.stderr.read().decode(errors="replace")
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert code == 143 and "nothing was written" in rest, rest


def test_demos_question_names_the_servos_the_scan_found_as_ranges() -> None:
    # `ics35 demo` on a line of 32 servos asked "Move servo(s) 0, 1, 2, 3, ..., 31 (every servo the scan found)": three
    # lines of numbers on an 80-column terminal to read before the [y/N].
    with serving(["--ids", "0-31", "--fast"]) as path:
        args = ["--port", path, "--timeout", "0.05", "demo", "--seconds", "1"]
        code, written = typed_on_a_terminal(args, [("[y/N]", b"n\r")], columns=80)
    screen = " ".join(" ".join(screen_of(written, width=80)).split())
    assert code == 5, screen
    assert "Move servo(s) 0-31 (every servo the scan found) in a 15° wave" in screen, screen
