"""Line options after the command, the port rule for writes, and what ``ics35 --version`` imports."""

from __future__ import annotations

import importlib
import json
import os
import re
import signal
import subprocess
import sys
import time
from typing import Any

import pytest

from ics35_async.cli import COMMAND_MODULES, ExitCode
from ics35_async.drivers.burst import burst_path
from ics35_async.sim import VirtualServo, serving

# --------------------------------------------------------------------------- line options after the command


def test_port_after_the_command(cli: Any, sim_line: Any) -> None:
    _, url = sim_line([4, 9])
    result = cli("scan", "--port", url, "--bauds", "115200", "--ids", "0-10", "--quick", "--json")
    assert result.code == 0, result.err
    assert [s["id"] for s in result.json()["servos"]] == [4, 9]


def test_short_port_and_baud_after_the_command(cli: Any, sim_line: Any) -> None:
    sim, url = sim_line([VirtualServo(1, baud_rate=1250000)])
    result = cli("move", "1", "8000", "-p", url, "-b", "1250000", "--json")
    assert result.code == 0, result.err
    assert sim.servo(1).target == 8000


def test_long_baud_after_the_positional_arguments(cli: Any, sim_line: Any) -> None:
    sim, url = sim_line([VirtualServo(1, baud_rate=625000)])
    result = cli("--port", url, "move", "1", "8000", "--baud", "625000")
    assert result.code == 0, result.err
    assert sim.servo(1).target == 8000


def test_flags_and_timeouts_after_the_command_take_effect(cli: Any, sim_line: Any) -> None:
    _, url = sim_line([1])
    # --no-echo on an echoing line is diagnosed: proof that the flag reached the bus.
    result = cli("get", "1", "speed", "--port", url, "--no-echo", "--timeout", "0.005", "--retries", "0")
    assert result.code == ExitCode.COMMUNICATION
    assert "drop --no-echo" in result.err


def test_options_after_a_subcommand_of_a_group(cli: Any, sim_line: Any) -> None:
    _, url = sim_line([1])
    result = cli("eeprom", "dump", "1", "--port", url)
    assert result.code == 0, result.err
    assert json.loads(result.out)["servo_id"] == 1


def test_an_option_after_the_command_wins_over_the_same_before(cli: Any, sim_line: Any) -> None:
    _, url = sim_line([1])
    result = cli("--port", "/dev/ics35-no-such-port", "get", "1", "speed", "--port", url, "--json")
    assert result.code == 0, result.err
    assert result.json()["value"] == 127


# --------------------------------------------------------------------------- the port rule for writes


@pytest.mark.parametrize(
    "args",
    [
        ["move", "1", "7500"],
        ["free", "1"],
        ["set", "1", "speed", "5"],
        ["set-id", "3", "--yes"],
        ["eeprom", "set", "1", "speed=5", "--yes"],
        ["eeprom", "restore", "1", "-", "--yes"],
    ],
    ids=lambda a: " ".join(a[:2]),
)
def test_a_write_on_the_implicit_simulator_is_refused(cli: Any, args: list[str]) -> None:
    backup = cli("eeprom", "dump", "1").out  # a read: the implicit simulator is fine for it
    result = cli(*args, stdin=backup)
    assert result.code == ExitCode.USAGE, result.err
    assert "--port /dev/ttyUSB0" in result.err and "--port sim://" in result.err
    assert "written" not in result.out and "target" not in result.out


@pytest.mark.parametrize(
    ("args", "said"),
    [
        (["set", "1", "speed", "0"], "speed"),
        (["move", "1", "99999"], "99999"),
        (["eeprom", "set", "1", "speed=500", "--yes"], "speed"),
    ],
    ids=lambda a: " ".join(a[:2]) if isinstance(a, list) else a,
)
def test_a_bad_value_is_named_before_the_missing_port(cli: Any, args: list[str], said: str) -> None:
    # Told one mistake at a time, the value's first would cost a second run: the value's is checked first.
    result = cli(*args)
    assert result.code == ExitCode.USAGE, result.err
    assert said in result.err and "no --port given" not in result.err, result.err


def test_a_write_on_an_explicit_simulator_runs(cli: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    assert cli("--port", "sim://", "move", "1", "7600").code == 0
    assert cli("move", "1", "7600", "--port", "sim://").code == 0
    monkeypatch.setenv("ICS35_PORT", "sim://")
    assert cli("move", "1", "7600").code == 0


def test_a_read_on_the_implicit_simulator_says_so_once(cli: Any) -> None:
    result = cli("get", "1", "speed", "--json")
    assert result.code == 0
    notes = [ln for ln in result.err.splitlines() if "simulator" in ln]
    assert len(notes) == 1 and "--port" in notes[0]


def test_demo_on_the_implicit_simulator_says_so(cli: Any) -> None:
    result = cli("demo", "--ids", "0-1", "--seconds", "0.2", "--telemetry", "0")
    assert result.code == 0, result.err
    assert [ln for ln in result.err.splitlines() if "built-in simulator" in ln]


@pytest.fixture(scope="module")
def pty_port() -> Any:
    """Two servos on a pty: to the CLI, hardware."""
    with serving(["--ids", "1,2"]) as path:
        yield path


def test_demo_on_hardware_without_ids_asks_first(cli: Any, pty_port: str) -> None:
    result = cli("--port", pty_port, "demo", "--seconds", "0.2", stdin="n\n")
    assert result.code == ExitCode.REFUSED, result.err
    assert "1, 2" in result.err and "[y/N]" in result.err
    # A robot standing on these servos would fall: the question says they go limp, as they start and at the end.
    assert "limp as it starts and when it ends" in " ".join(result.err.split()), result.err
    assert "demo done" not in result.out
    result = cli("--port", pty_port, "demo", "--seconds", "0.2", "--telemetry", "0", stdin="y\n")
    assert result.code == 0, result.err
    assert "demo done" in result.out


# --------------------------------------------------------------------------- a quick --version

PROBE = """
import json, sys
import ics35_async
package = set(sys.modules)
from ics35_async.cli import main
try:
    main(["--version"])
except SystemExit:
    pass
print(json.dumps({"package": sorted(package), "after": sorted(sys.modules)}))
"""


def test_version_imports_none_of_the_heavy_parts() -> None:
    done = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, timeout=60, env=os.environ)
    assert done.returncode == 0, done.stderr
    doc = json.loads(done.stdout.splitlines()[-1])
    package, after = set(doc["package"]), set(doc["after"])
    heavy = ("rich", "uvloop", "matplotlib", "importlib.metadata")
    assert not [m for m in after if m.split(".")[0] in heavy or m.startswith("importlib.metadata")]
    # Beyond what `import ics35_async` itself loads, the CLI adds only its light front (and the handlers
    # that make SIGTERM and SIGHUP stop every command as Ctrl-C does: standard modules only).
    added = {m for m in after - package if m.startswith("ics35_async")}
    front = {
        "ics35_async.cli",
        "ics35_async.cli._line_options",
        "ics35_async.cli._numbers",
        "ics35_async.cli._settings",
        "ics35_async.cli._signals",
        "ics35_async.terminal",
    }
    assert added <= front, added
    if "ics35_async.bus" not in package:
        # Once the package imports lazily, --version must not pull the bus or the simulator in either.
        assert not {"ics35_async.bus", "ics35_async.sim", "ics35_async.transport"} & after


# The console script as pip writes it for the entry point pyproject.toml names, with a line first that says
# Python itself has started (its own start-up, before any of the project's code, is not the project's to guard).
CONSOLE_SCRIPT = """
import sys
sys.stdout.write("started\\n"); sys.stdout.flush()
from {module} import {function}
sys.exit({function}())
"""


def console_script() -> str:
    import tomllib

    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    with open(os.path.join(root, "pyproject.toml"), "rb") as file:
        module, function = tomllib.load(file)["project"]["scripts"]["ics35"].split(":")
    return CONSOLE_SCRIPT.format(module=module, function=function)


def read_started(fd: int) -> bytes:
    """The console script's first line, read to its end and no further: a readline's buffer would keep what came
    behind it, out of ``communicate``'s reach (the reading of a command that ran to its end while this process
    was held up on a loaded machine: exit 0 and nothing printed, it looked)."""
    line = b""
    while len(line) < len(b"started\n") and (chunk := os.read(fd, len(b"started\n") - len(line))):
        line += chunk
    return line


def started_reading_stretch() -> subprocess.Popen[str]:
    """``ics35 --port sim:// get 1 stretch`` through the console script, once it says it has started."""
    proc = subprocess.Popen(
        [sys.executable, "-c", console_script(), "--port", "sim://", "get", "1", "stretch"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=os.environ,
    )
    assert proc.stdout is not None
    assert read_started(proc.stdout.fileno()) == b"started\n"
    return proc


@pytest.mark.parametrize("delay", [0.0, 0.005, 0.01, 0.02, 0.03, 0.045, 0.06, 0.08])
def test_ctrl_c_while_the_command_line_loads_ends_in_one_line(delay: float) -> None:
    # Ctrl-C at once after start: the package and the command line are still being imported.
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    for _ in range(2):
        proc = started_reading_stretch()
        time.sleep(delay)
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
        if "Traceback" in err:
            # Only the generated script's own import statement (finding and loading the entry module, about a
            # millisecond) is beyond the project's reach: no traceback may pass through the package's files.
            assert f'File "{os.path.join(root, "ics35_async")}{os.sep}' not in err, err
            continue
        # Stopped (one line, the interrupted exit code), or done before the signal came (the reading printed).
        # The delay counts from when this process read "started": held up on a loaded machine, it sends the signal
        # later in the command's life, once the command runs (its own stop's one line) or after its reading, as
        # Python itself ends (Python's end, beyond the project's code, is ended by it: nothing more is said).
        assert (
            (proc.returncode, err.strip().splitlines()[-1:])
            in (
                # (before the command runs, as click parses it, and once it runs: said alike, as every failure is)
                (ExitCode.INTERRUPTED, ["error: interrupted"]),
            )
            or (proc.returncode == 0 and "stretch" in out)
            or (proc.returncode == -signal.SIGINT and "stretch" in out and not err)
        ), (proc.returncode, out, err)


# A Ctrl-C as the command line's main begins (installing its signal handlers), as the command's event loop is to start
# (run_loop called, the command's coroutine made but not begun), or as the command line, the command over and its
# reading printed, works out its exit code.
PRESS_AT = """
import os, signal, sys
from ics35_async.cli import main

def press(frame, event, arg):
    if event == "call" and frame.f_code.co_name == {function!r}:
        sys.setprofile(None)
        os.kill(os.getpid(), signal.SIGINT)

sys.setprofile(press)
main(["--port", "sim://", "get", "1", "stretch"])
"""


@pytest.mark.parametrize(
    ("where", "said"),
    [
        ("install", "error: interrupted"),  # (it said "interrupted" alone before the command ran, and as it ended)
        (
            "parse_args",
            "error: interrupted",
        ),  # (click makes it an Abort: still named as every Ctrl-C is, not "aborted")
        ("run_loop", "error: interrupted"),
        ("received", "error: interrupted"),
    ],
)
def test_ctrl_c_as_a_command_starts_or_ends_ends_in_one_line(where: str, said: str) -> None:
    # As it started, the command's coroutine was made and never begun: Python warned, as it ended, that it was never
    # awaited ("sys:1: RuntimeWarning: coroutine 'get.<locals>.body' was never awaited") under the one line.  As it
    # ended, and as main began, KeyboardInterrupt's traceback came through the command line's main.
    done = subprocess.run(
        [sys.executable, "-c", PRESS_AT.format(function=where)],
        capture_output=True,
        text=True,
        timeout=60,
        env=os.environ,
    )
    assert (done.returncode, done.stderr.strip()) == (ExitCode.INTERRUPTED, said), done.stderr


# A Ctrl-C landing inside a weakref callback (one runs as each import's module lock is let go): Python prints
# "Exception ignored in ..." and drops the KeyboardInterrupt there, and the command went on as if never pressed
# (seen: `get` at a silent servo ran its four waits to the end, the Ctrl-C's traceback at the top of the screen).
# Pressed as the package loads (through the console script's entry point) or as click parses the command line.
PRESS_IN_A_WEAKREF_CALLBACK = """
import os, signal, sys, weakref

def press(frame, event, arg):
    if event == "call" and frame.f_code.co_name == {function!r}:
        sys.setprofile(None)

        class Lock:
            pass

        def callback(ref):
            os.kill(os.getpid(), signal.SIGINT)
            for _ in range(100_000):  # (the default handler raises here: in the callback, where it is dropped)
                pass

        lock = Lock()
        ref = weakref.ref(lock, callback)
        del lock

sys.setprofile(press)
from {module} import main
main({args})
"""


@pytest.mark.parametrize(
    ("module", "function", "args"),
    [
        ("_ics35_async_entry", "dataclass", ""),  # (the package's import: a dataclass made)
        ("ics35_async.cli", "parse_args", '["--port", "sim://", "get", "1", "stretch"]'),
    ],
    ids=["loading", "parsing"],
)
def test_a_ctrl_c_python_drops_in_a_weakref_callback_still_stops_the_command(
    module: str, function: str, args: str
) -> None:
    script = PRESS_IN_A_WEAKREF_CALLBACK.format(function=function, module=module, args=args)
    argv = ["--port", "sim://", "get", "1", "stretch"] if not args else []
    done = subprocess.run(
        [sys.executable, "-c", script, *argv], capture_output=True, text=True, timeout=60, env=os.environ
    )
    assert (done.returncode, done.stderr.strip()) == (ExitCode.INTERRUPTED, "error: interrupted"), (
        done.stdout,
        done.stderr,
    )


COMMAND_PROBE = """
import json, sys
from ics35_async.cli import main
try:
    main(["get", "1", "stretch"])
except SystemExit:
    pass
print(json.dumps(sorted(sys.modules)))
"""


def test_a_command_imports_its_own_module_and_not_the_others() -> None:
    done = subprocess.run(
        [sys.executable, "-c", COMMAND_PROBE], capture_output=True, text=True, timeout=60, env=os.environ
    )
    assert done.returncode == 0, done.stderr
    assert "stretch = " in done.stdout
    loaded = {m.rsplit(".", 1)[1] for m in json.loads(done.stdout.splitlines()[-1]) if m.startswith("ics35_async.cli.")}
    others = set(COMMAND_MODULES.values()) - {"_basic"}
    assert "_basic" in loaded and not loaded & others, loaded & others
    assert "ics35_async.robot" not in done.stdout and "ics35_async.web" not in done.stdout


def test_a_mistyped_command_is_answered_with_the_one_meant(cli: Any) -> None:
    result = cli("sacn")
    assert result.code == ExitCode.USAGE
    assert "No such command 'sacn'" in result.err and "Did you mean 'scan'" in result.err


def test_the_table_of_command_modules_names_every_command_where_it_is() -> None:
    found = {}
    for module_name in set(COMMAND_MODULES.values()):
        module = importlib.import_module(f"ics35_async.cli.{module_name}")
        found.update({command.name: module_name for command in module.COMMANDS})
    assert found == COMMAND_MODULES


@pytest.mark.parametrize("env", ["1", None, "0"], ids=["asked", "default", "turned-off"])
def test_version_with_verbose_and_doctor_say_which_path_runs(env: str | None) -> None:
    environ = {k: v for k, v in os.environ.items() if k != "ICS35_BURST"}
    if env is not None:
        environ["ICS35_BURST"] = env
    for args in (["--version", "-v"], ["-v", "--version"], ["doctor"]):
        done = subprocess.run(
            [sys.executable, "-m", "ics35_async.cli", *args], capture_output=True, text=True, timeout=60, env=environ
        )
        assert done.returncode == 0, done.stderr
        (said,) = [ln for ln in done.stdout.splitlines() if ln.startswith("compiled stream path:")]
        if env == "0":
            assert said == "compiled stream path: off (ICS35_BURST=0; unset it to turn the path on)"
        else:  # on by default where it is built
            assert said.startswith(("compiled stream path: on (", "compiled stream path: off, not built ("))
    plain = subprocess.run([sys.executable, "-m", "ics35_async.cli", "--version"], capture_output=True, text=True)
    assert plain.stdout.strip().startswith("ics35, version") and "burst" not in plain.stdout


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="a timerfd is Linux's")
def test_version_with_verbose_and_doctor_say_how_deadlines_are_timed() -> None:
    for args in (["--version", "-v"], ["doctor"]):
        done = subprocess.run([sys.executable, "-m", "ics35_async.cli", *args], capture_output=True, text=True)
        assert done.returncode == 0, done.stderr
        (said,) = [ln for ln in done.stdout.splitlines() if ln.startswith("deadline timer:")]
        assert said.startswith("deadline timer: a timerfd, to the microsecond ("), said
    done = subprocess.run([sys.executable, "-m", "ics35_async.cli", "doctor", "--json"], capture_output=True, text=True)
    assert json.loads(done.stdout)["fine_deadlines"] is True


@pytest.mark.pty
def test_doctor_and_the_log_say_which_path_a_given_line_takes(monkeypatch: pytest.MonkeyPatch) -> None:
    # The helper runs on a serial port's descriptor: not for a sim:// URL, nor with --transport thread.
    monkeypatch.setenv("ICS35_BURST", "1")
    if not burst_path()[0]:
        pytest.fail(f"the compiled helper is not built here: {burst_path()[1]}")
    with serving(["--ids", "1", "--fast"]) as pty:
        for port, transport, takes in (
            (pty, "auto", True),
            (pty, "thread", False),
            ("sim://?ids=1", "auto", False),
        ):
            done = subprocess.run(
                [sys.executable, "-m", "ics35_async.cli", "-v", "--port", port, "--transport", transport, "doctor"],
                capture_output=True,
                text=True,
                timeout=60,
            )
            assert done.returncode == 0, done.stderr
            (said,) = [ln for ln in done.stdout.splitlines() if ln.startswith("compiled stream path:")]
            assert said.startswith("compiled stream path: on" if takes else "compiled stream path: off"), (port, said)
            (opened,) = [ln for ln in done.stderr.splitlines() if "opened" in ln and "driver" in ln]
            assert ("compiled stream path" in opened) == takes, (port, transport, opened)


# --------------------------------------------------------------------------- the event loop


def _run_with_loop(choice: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "ics35_async.cli", "-v", "--port", "sim://?ids=1", "get", "1", "stretch", "--json"],
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, "ICS35_LOOP": choice},
    )


@pytest.mark.parametrize("choice", ["asyncio", "uvloop"])
def test_ics35_loop_chooses_the_event_loop(choice: str) -> None:
    proc = _run_with_loop(choice)
    assert proc.returncode == 0, proc.stderr
    assert f"event loop: {choice}" in proc.stderr
    assert json.loads(proc.stdout)["value"] == 30  # the factory stretch gain, read through that loop


def test_an_unknown_ics35_loop_is_a_usage_error_before_anything_runs() -> None:
    proc = _run_with_loop("trio")
    assert proc.returncode == ExitCode.USAGE
    assert "ICS35_LOOP must be one of auto, asyncio, uvloop, not 'trio'" in proc.stderr
    assert "Traceback" not in proc.stderr and "never awaited" not in proc.stderr


def test_verbose_names_each_failed_transaction_and_only_double_verbose_dumps_bytes() -> None:
    # What the live table's error column counts must be findable with -v, without every byte.
    def demo(flag: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [
                sys.executable,
                "-m",
                "ics35_async.cli",
                flag,
                "--port",
                "sim://?ids=1,2",
                "demo",
                "--ids",
                "1-3",
                "--seconds",
                "1.2",  # (ID 3, silent as demo asks it, starts offline: the stream probes it twice a second)
            ],
            capture_output=True,
            text=True,
            timeout=60,
        )

    once, twice = demo("-v"), demo("-vv")
    # Each names its line's port (a robot's two lines both have an ID 1): here the simulator the command named.
    assert re.search(r"ics35_async\.faults: sim://[\w-]+\?ids=1,2: position to ID 3: no reply", once.stderr), (
        once.stderr
    )
    assert " tx 81 " not in once.stderr  # the byte dumps are -vv's
    assert " tx 81 " in twice.stderr and "position to ID 3: no reply" in twice.stderr


@pytest.mark.parametrize("delay", [0.02, 0.05, 0.1, 0.15])
def test_a_double_ctrl_c_as_the_command_starts_ends_in_its_one_line(delay: float) -> None:
    # The second press landed as the first one's "interrupted" (or "error: interrupted") was said or
    # the process ended: Python's own handler, back by then, killed it (by SIGINT, not with exit code 130) or
    # printed a KeyboardInterrupt traceback; a press before the loop ran the command left "coroutine ... was
    # never awaited" under its message.
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    for gap in (0.005, 0.02):
        proc = started_reading_stretch()  # (read to its end and no further: see read_started)
        time.sleep(delay)
        proc.send_signal(signal.SIGINT)
        time.sleep(gap)
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
        if "stretch" in out:
            continue  # done before the presses came: a press as it ended may end it by SIGINT (nothing lost)
        if "Traceback" in err and f'File "{os.path.join(root, "ics35_async")}' not in err and "_entry.py" not in err:
            continue  # (the generated script's own import statement: see the test above)
        assert proc.returncode == ExitCode.INTERRUPTED, (proc.returncode, err)
        assert "Traceback" not in err and "never awaited" not in err, err
        assert err.strip().splitlines()[-1:] == ["error: interrupted"], err


# Ctrl-C landing in a class's making as a command imports what it needs (rich's console, whose dataclasses have
# fields): Python 3.11 hands the KeyboardInterrupt on wrapped ("RuntimeError: Error calling __set_name__ on 'Field'
# instance 'buffer' in 'ConsoleThreadLocals'"), and the command line printed that traceback.  (The import is
# where a press landed under load; here it lands there every time.)
CTRL_C_IN_A_CLASS_AS_IT_IS_MADE = """
import sys

class Pressed:
    def __set_name__(self, owner, name):
        raise KeyboardInterrupt  # (as Ctrl-C's handler raises, wherever the main thread is)

class AsTheConsoleLoads:
    def find_spec(self, name, path=None, target=None):
        if name == "rich.console":
            type("ConsoleThreadLocals", (), {"buffer": Pressed()})
        return None

sys.meta_path.insert(0, AsTheConsoleLoads())
from ics35_async.cli import main
main(sys.argv[1:])
"""


def test_ctrl_c_landing_in_a_class_as_it_is_made_ends_in_one_line() -> None:
    done = subprocess.run(
        [sys.executable, "-c", CTRL_C_IN_A_CLASS_AS_IT_IS_MADE, "--port", "sim://", "get", "1", "stretch"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    if sys.version_info < (3, 12):
        assert (done.returncode, done.stderr) == (ExitCode.INTERRUPTED, "error: interrupted\n"), done.stderr
    else:
        # Python 3.12 no longer wraps it: the bare KeyboardInterrupt reaches click as it runs the command, and ends
        # as any press there does, named as every Ctrl-C is ("interrupted", not click's "aborted").
        assert done.returncode == ExitCode.INTERRUPTED, done.stderr
        assert done.stderr.strip().splitlines() == ["error: interrupted"], done.stderr


# --------------------------------------------------------------------------- one home for the line's numbers


async def test_the_reply_allowance_and_the_retries_bound_are_one_constant_everywhere(cli: Any) -> None:
    """The CLI's --help, the configurator's line, the robot file's check and the bus's check all read
    ``protocol.ADAPTER_LATENCY`` and ``protocol.MAX_RETRIES``: none keeps a copy that could drift."""
    from ics35_async import open_bus
    from ics35_async.engine.timing import BusTiming
    from ics35_async.errors import InvalidArgument
    from ics35_async.protocol import ADAPTER_LATENCY, MAX_RETRIES, Param, ReadParam
    from ics35_async.robot.description import DescriptionError, load_description
    from ics35_async.web.config import LineConfig

    shown = " ".join(cli("--help").out.split())
    assert f"[default: {ADAPTER_LATENCY:g}; 0..5]" in shown
    assert f"0..{MAX_RETRIES}]" in shown
    assert BusTiming().adapter_latency == LineConfig().adapter_latency == ADAPTER_LATENCY

    def robot(retries: int) -> object:
        line = {"port": "sim://?ids=1", "retries": retries}
        return load_description({"lines": {"a": line}, "joints": {"x": {"line": "a", "id": 1}}})

    assert robot(MAX_RETRIES)
    with pytest.raises(DescriptionError, match=f"0..{MAX_RETRIES}"):
        robot(MAX_RETRIES + 1)
    async with open_bus("sim://?ids=1", retries=MAX_RETRIES) as bus:
        assert bus.retries == MAX_RETRIES
        with pytest.raises(InvalidArgument, match=f"0..{MAX_RETRIES}"):
            await bus.request(ReadParam(1, Param.STRETCH), retries=MAX_RETRIES + 1)
    with pytest.raises(InvalidArgument, match=f"0..{MAX_RETRIES}"):
        await open_bus("sim://?ids=1", retries=MAX_RETRIES + 1)


def test_the_tools_retries_default_is_one_constant(cli: Any) -> None:
    """The retries the tools give a line when --retries is not given (the CLI's --help and its settings, the
    configurator's line) are ``protocol.TOOL_RETRIES``: a copy that drifted would make the two tools differ."""
    from ics35_async.cli._settings import Settings
    from ics35_async.protocol import TOOL_RETRIES
    from ics35_async.web.config import LineConfig

    shown = " ".join(cli("--help").out.split())
    default = re.search(r"--retries INTEGER Retries for reads and positions\. \[default: (\d+);", shown)
    assert default is not None, shown
    assert int(default[1]) == TOOL_RETRIES
    assert Settings().retries == LineConfig().retries == TOOL_RETRIES
    assert Settings().bus().retries == TOOL_RETRIES
