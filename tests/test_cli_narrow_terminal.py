"""The command line's words on a narrow terminal: ``error:`` and ``hint:`` lines and the [y/N] questions wrap at
words, each further line under the text, and so do its other lines (status lines, a stream's warning, click's usage
errors); into a pipe they stay one line each, as a log keeps them."""

from __future__ import annotations

import ast
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from ics35_async.cli import ExitCode
from ics35_async.cli._errors import NO_REPLY_HINTS
from ics35_async.cli._runner import simulator_note
from ics35_async.policies import trying_rate
from ics35_async.policies.eeprom_backup import backup_document, backups_document
from ics35_async.sim import VirtualServo
from tests.support.terminal import screen_of, typed_on_a_terminal

pytestmark = [
    pytest.mark.pty,
    pytest.mark.skipif(not sys.platform.startswith("linux"), reason="a pseudo-terminal"),
]

# A servo that does not answer on a line of none: an error with three long hints.
SILENT = ["--port", "sim://?ids=none", "get", "1", "speed"]
SILENT_SAYS = "servo 1 did not answer on sim://?ids=none at 115200 baud, nor at 625000 or 1250000 baud"


def said(screen: list[str], label: str) -> list[str]:
    """Each ``label`` line's words (``error:``, ``hint:``) with its further lines (those indented under its text),
    checked to be laid out so: every further line starts where the text after the label does, and none is wider
    than the terminal."""
    found: list[str] = []
    indent = None
    for line in screen:
        if line.lstrip().startswith(label):
            indent = line.index(label) + len(label) + 1
            found.append(line[indent:])
        elif indent is not None and line.startswith(" " * indent) and line[indent] != " ":
            found[-1] += " " + line[indent:]
        else:
            indent = None
    return found


@pytest.mark.parametrize("columns", [40, 50, 80])
def test_an_error_and_its_hints_wrap_at_words_under_their_text(columns: int) -> None:
    # At 45 columns: "error: servo 1 did not answer on sim://?ids=n" / "one at 115200 baud, ..." and
    # "  hint: check the wiring and the servo ID (ic" / "s35 scan tries ...": words cut, lines at the left edge.
    code, written = typed_on_a_terminal(SILENT, [], columns=columns)
    screen = screen_of(written, width=columns)
    assert code == ExitCode.NO_REPLY, screen
    assert all(len(line) <= columns for line in screen), screen
    assert said(screen, "error:") == [SILENT_SAYS], screen
    assert said(screen, "hint:") == list(NO_REPLY_HINTS), screen


def test_into_a_pipe_an_error_and_each_hint_stay_one_line() -> None:
    # A log is read later, in a wider window, and grep finds a line whole: as the tables into a log, not fitted.
    done = subprocess.run(
        [sys.executable, "-m", "ics35_async.cli", *SILENT],
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, "COLUMNS": "40"},
    )
    assert done.returncode == ExitCode.NO_REPLY, done.stderr
    lines = done.stderr.splitlines()
    assert f"error: {SILENT_SAYS}" in lines and all(f"  hint: {hint}" in lines for hint in NO_REPLY_HINTS), lines


@pytest.mark.parametrize("columns", [30, 45])
def test_a_question_wraps_at_words_and_keeps_its_y_n_on_its_last_line(columns: int) -> None:
    # At 32 columns: "Write these 1 change(s) to the E" / "EPROM of servo 1? [y/N]: n".
    args = ["--port", "sim://?ids=1", "eeprom", "set", "1", "speed=100"]
    code, written = typed_on_a_terminal(args, [("[y/N]", b"n\r")], columns=columns)
    screen = screen_of(written, width=columns)
    assert code == ExitCode.REFUSED, screen
    last = next(k for k, line in enumerate(screen) if "[y/N]" in line)
    first = next(k for k, line in enumerate(screen) if line.startswith("Write"))
    asked = " ".join(screen[first : last + 1])
    assert asked.startswith("Write") and asked.endswith("EEPROM of servo 1? [y/N]: n"), screen
    assert all(len(line) <= columns for line in screen[first : last + 1]), screen
    assert screen[last] != "[y/N]: n" and not screen[last].startswith(" "), screen  # (with the question's end)


def test_a_note_wraps_at_words_under_its_text() -> None:
    # "note: no --port given: this is the built-in simula" / "tor (for hardware: ...)" at 50 columns.
    code, written = typed_on_a_terminal(["get", "1", "speed"], [], columns=50, env={"ICS35_PORT": ""})
    screen = screen_of(written, width=50)
    assert code == 0, screen
    assert said(screen, "note:") == [simulator_note().removeprefix("note: ")], screen


def test_a_restores_note_wraps_at_words_under_its_text(tmp_path: Path) -> None:
    # A restore's note of a servo the file holds no backup of was printed whole, cut by the terminal mid-word.
    backup = tmp_path / "servos.json"
    saved = [backup_document(VirtualServo(1).eeprom, 1, baud=115200, port="/dev/ttyUSB0")]
    backup.write_text(json.dumps(backups_document(saved, {5: "no reply at 115,200 baud"})))
    args = ["--port", "sim://?ids=1", "eeprom", "restore", str(backup), "--yes"]
    code, written = typed_on_a_terminal(args, [], columns=40)
    screen = screen_of(written, width=40)
    assert code == 0, screen
    assert all(len(line) <= 40 for line in screen), screen
    (note,) = [line for line in said(screen, "note:") if "holds no backup" in line]
    assert note.endswith("holds no backup of servo 5 (when it was saved: no reply at 115,200 baud)"), screen


def sentence(screen: list[str], start: str, end: str) -> str:
    """The lines of ``screen`` from the first starting with ``start`` to the next ending with ``end``, joined by
    spaces as a person reads them: a word the terminal cut at its last column reads as two (``1291`` / ``.9``)."""
    first = next((k for k, line in enumerate(screen) if line.startswith(start)), None)
    assert first is not None, f"no line starts with {start!r}: {screen}"
    last = next((k for k in range(first, len(screen)) if screen[k].endswith(end)), None)
    assert last is not None, f"no line from {screen[first]!r} on ends with {end!r}: {screen}"
    return " ".join(line.strip() for line in screen[first : last + 1])


@pytest.mark.parametrize("columns", [40, 50])
def test_demos_status_lines_wrap_at_words(columns: int) -> None:
    # At 40 columns: "demo done after 2.0 s: 2572 cycles, 1291" / ".9 cycles/s over 2 servos; all servos le" /
    # "ft free"; at 50, the scan's "... at 11" / "5200 baud ...".
    code, written = typed_on_a_terminal(["--port", "sim://?ids=1,2", "demo", "--seconds", "1"], [], columns=columns)
    screen = screen_of(written, width=columns)
    assert code == 0, screen
    assert screen_of(written) == screen, screen  # (every line written fits: the terminal cut none)
    assert sentence(screen, "no IDs given:", "...") == "no IDs given: scanning sim://?ids=1,2 at 115200 baud ..."
    summary = sentence(screen, "demo done after", "free")
    assert re.fullmatch(
        r"demo done after \d+\.\d s: \d+ cycles, \d+\.\d cycles/s over 2 servos; all servos left free", summary
    ), screen


@pytest.mark.parametrize("columns", [30, 50])
def test_the_rate_searchs_lines_wrap_at_words(columns: int) -> None:
    # At 50 columns a line of the search was cut mid-word ("... trying 1250000 b" / "aud ...").
    args = ["--port", "sim://?ids=1&baud=625000", "get", "1", "speed"]
    code, written = typed_on_a_terminal(args, [], columns=columns)
    screen = screen_of(written, width=columns)
    assert code == ExitCode.WRONG_BAUD, screen
    assert screen_of(written) == screen, screen  # (every line written fits: the terminal cut none)
    for said_first in (trying_rate(115200, 625000), trying_rate(115200, 1250000, 625000)):
        assert sentence(screen, said_first[:20], "...") == said_first, screen


@pytest.mark.parametrize(
    "args",
    [["get", "--bogus"], ["get", "1", "bogus"], ["eeprom", "restore"], ["sim", "--bogus", "--also-bogus", "--more"]],
    ids=" ".join,
)
def test_a_usage_error_wraps_at_words_with_its_text_and_exit_code_kept(args: list[str]) -> None:
    # At 40 columns: "Error: No such option '--bogus'. (Did yo" / "u mean one of: '--baud', '--verbose'?)", as
    # click writes it; its usage, laid out for 50 columns at least, and "Try 'ics35 eeprom restore --help' for h" /
    # "elp." were cut too.
    logged = subprocess.run(
        [sys.executable, "-m", "ics35_async.cli", *args],
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, "COLUMNS": "40"},
    )
    assert logged.returncode == ExitCode.USAGE, logged.stderr
    (error,) = [line.removeprefix("Error: ") for line in logged.stderr.splitlines() if line.startswith("Error: ")]
    code, written = typed_on_a_terminal(args, [], columns=40)
    screen = screen_of(written, width=40)
    assert code == ExitCode.USAGE, screen
    assert screen_of(written) == screen, screen  # (every line written fits: the terminal cut none)
    assert " ".join(screen).split() == logged.stderr.split(), screen  # (the same words, none cut in two)
    assert said(screen, "Error:") == [error], screen


def test_a_streams_warning_wraps_at_words_under_its_text() -> None:
    # A paced stream that falls behind says so through logging, written whole: at 50 columns "... cannot keep rate_
    # hz=100: 20 of its first 20 cycles ran past their slot (about 34 cyc" / "les/s); ...".  At 115200 baud the wire
    # alone keeps 32 IDs under 55 cycles/s; the warning comes after 20 cycles, which a loaded machine (the simulator
    # shares its CPU) can take seconds to run: the monitor runs until the warning is written (whole, in one write),
    # then Ctrl-C.
    args = ["--port", "sim://?ids=0-31&realtime=1", "monitor", "0-31", "--free", "--rate", "100"]
    code, written = typed_on_a_terminal(args, [("warning:", b""), (0.5, b"\x03")], columns=50)
    screen = screen_of(written, width=50)
    assert code == 0, screen  # (Ctrl-C is how a monitor is stopped)
    assert screen_of(written) == screen, screen  # (every line written fits: the terminal cut none)
    (warning,) = [line for line in said(screen, "warning:") if line.startswith("stream of 32 IDs")]
    assert re.fullmatch(
        r"stream of 32 IDs cannot keep rate_hz=100: .*; at 115200 baud .* \(or the host is busy\)", warning
    ), screen


def test_the_commands_say_their_sentences_through_the_wrapping_helpers() -> None:
    # A sentence printed straight on a console (out.print(f"...")) is cut mid-word by a narrow terminal: the consoles
    # soft-wrap, so that a log gets each line whole.  say and say_labelled wrap it at words on a terminal only.
    # (Data printed as it is, markup=False, is no sentence: teach's motion as JSON.)
    package = Path(__file__).parent.parent / "ics35_async" / "cli"
    printed: list[str] = []
    for path in sorted(package.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if not (
                isinstance(node, ast.Call)
                and isinstance(node.func, ast.Attribute)
                and node.func.attr == "print"
                and ast.unparse(node.func.value) in ("out", "err", "(err if as_json else out)")
                and node.args
            ):
                continue
            verbatim = any(k.arg == "markup" and ast.unparse(k.value) == "False" for k in node.keywords)
            if not verbatim and _words(node.args[0]):
                printed.append(f"{path.name}:{node.lineno}: {ast.unparse(node)[:80]}")
    assert printed == [], "\n".join(printed)


def _words(expression: ast.expr) -> bool:
    """Whether ``expression`` is text written in the source (a string, an f-string, one escaped, joined or chosen)."""
    if isinstance(expression, ast.Constant):
        return isinstance(expression.value, str)
    if isinstance(expression, ast.IfExp):
        return _words(expression.body) or _words(expression.orelse)
    if isinstance(expression, ast.BinOp):
        return _words(expression.left) or _words(expression.right)
    return isinstance(expression, ast.JoinedStr) or (
        isinstance(expression, ast.Call) and ast.unparse(expression.func) == "escape"
    )


def test_the_version_with_verbose_wraps_at_words() -> None:
    # At 40 columns: "compiled stream path: on (streams on ser" / "ial ports run in ...", as click.echo wrote it.
    logged = subprocess.run(
        [sys.executable, "-m", "ics35_async.cli", "--version", "-v"], capture_output=True, text=True, timeout=60
    )
    assert logged.returncode == 0 and "compiled stream path" in logged.stdout, logged.stderr
    code, written = typed_on_a_terminal(["--version", "-v"], [], columns=40)
    screen = screen_of(written, width=40)
    assert code == 0, screen
    assert screen_of(written) == screen, screen  # (every line written fits: the terminal cut none)
    # The same words, none cut in two but one wider than the terminal (the platform's name), cut where it must.
    words = [word[k : k + 40] for word in logged.stdout.split() for k in range(0, len(word), 40)]
    assert " ".join(screen).split() == words, screen


def test_the_simulators_own_lines_and_its_consoles_answers_wrap_at_words() -> None:
    # `ics35 sim --console` at 50 columns: its "ics35 sim: ..." lines and the console's answers (unplug port) were
    # printed whole, cut by the terminal mid-word ("a program on it lo" / "ses it").
    columns = 50
    code, written = typed_on_a_terminal(
        ["sim", "--ids", "1-3", "--console"],
        [("sim>", b"unplug port\n"), ("replug port", b"quit\n")],
        columns=columns,
    )
    screen = screen_of(written, width=columns)
    assert code == 0, screen
    assert all(len(line) <= columns for line in screen), screen
    text = " ".join(line.strip() for line in screen)
    for sentence in (
        "ics35 sim: console: type help for its commands, quit to stop",
        "is gone and a program on it loses it (replug port plugs it back in)",
    ):
        assert sentence in text, screen
    words = {word for line in screen for word in line.split()}
    assert {"loses", "console:", "commands,"} <= words, screen


@pytest.mark.parametrize("columns", [40, 50])
def test_help_below_fifty_columns_wraps_at_words(columns: int) -> None:
    # click lays its help out for 50 columns at least: on a narrower terminal every line of it was cut mid-word
    # ("the cyc" / "le rate"), the options' descriptions in a column of ten letters past the edge.
    code, written = typed_on_a_terminal(["monitor", "--help"], [], columns=columns)
    screen = screen_of(written, width=columns)
    assert code == 0, screen
    assert all(len(line) <= columns for line in screen), screen
    text = " ".join(line.strip() for line in screen)
    assert "Watch servos live: position, current, temperature, per-ID errors and the cycle rate." in text, screen
    assert "Keep watching through a lost port (an adapter unplugged, a loose cable)" in text, screen


def test_infos_title_wraps_between_its_words() -> None:
    # `ics35 --port /tmp/trial3/tty1 info 1` at 40 columns: "servo 1 on /tmp/trial3/tty1 at 115200 ba" / "ud": the
    # table's title, which the consoles' soft wrap left to the terminal to cut.
    columns = 40
    port = "sim://a-line-of-18?ids=1"  # ("servo 1 on sim://a-line-of-18?ids=1 at 115200 baud": past 40 by a word)
    code, written = typed_on_a_terminal(["--port", port, "info", "1"], [], columns=columns, rows=80)
    screen = screen_of(written, width=columns)
    assert code == 0, screen
    assert screen[:2] == [f"servo 1 on {port} at", "115200 baud"], screen
