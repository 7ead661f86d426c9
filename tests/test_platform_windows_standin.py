"""The Windows stand-in: the whole package on a Linux that looks, to our code, like Windows.

A subprocess loads pyserial (which keeps its POSIX backend working), then makes
``termios``, ``fcntl``, ``tty`` and ``pty`` unimportable (a ``sys.meta_path``
finder raising ImportError, as in tests/test_sim_no_posix.py) and makes
``serial.Serial.fileno`` raise ``io.UnsupportedOperation``, as a Windows COM
port's does.  Then it imports the package and, with every driver:

* opens the pty of a simulator running in ANOTHER process (``python -m
  ics35_async.sim``, started by the test), sends requests and streams to it;
* uses ``sim://``;
* checks that port errors come out typed (a missing port, a busy one, a
  refused ``socket://`` connection, a file that is not a serial port);
* runs ``ics35 --help`` and ``ics35 --port <pty> read 1 stretch``.

What this proves: nothing on these paths needs a POSIX terminal module of
ours or a file descriptor of the port; ports without one are read by a
thread; port errors are typed there too.  What it does not prove: pyserial's
Windows backend itself (serialwin32: overlapped I/O, its timeouts, the
"Access is denied" of a COM port in use, which is translated from its message
text -- see test_windows_open_errors_are_typed), Windows' event loop
(Proactor) and timer resolution, or a real COM port's latency.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from collections.abc import Iterator
from pathlib import Path

import pytest

from ics35_async.errors import PortBusy, PortNotFound, PortPermissionDenied, SerialPortError
from ics35_async.sim import start_subprocess, stop_subprocess
from ics35_async.transports.serial_port import translate_open_error
from tests.support.timing import NO_TIMEOUTS

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the stand-in runs on Linux ptys")

BLOCKED = ("termios", "fcntl", "tty", "pty")

SCRIPT = textwrap.dedent(
    """
    import asyncio
    import io
    import json
    import sys

    import serial  # loaded first: on Windows pyserial has its own backend; here the POSIX one keeps working

    BLOCKED = {blocked!r}
    PTY = sys.argv[1]
    LATENCY = {latency!r}  # the no-timeouts allowance: a server in another process, on a loaded machine


    class Blocker:
        importers = []

        def find_spec(self, name, path=None, target=None):
            if name not in BLOCKED:
                return None
            frame = sys._getframe(1)
            while frame is not None and frame.f_code.co_filename.startswith("<frozen"):
                frame = frame.f_back
            self.importers.append((name, frame.f_code.co_filename if frame else "?"))
            raise ImportError(f"No module named {{name!r}} (blocked: not on this platform)", name=name)


    for mod in list(sys.modules):
        if mod in BLOCKED:
            del sys.modules[mod]
    blocker = Blocker()
    sys.meta_path.insert(0, blocker)


    def no_fileno(self):
        raise io.UnsupportedOperation("fileno")  # what a Windows COM port's Serial does


    serial.Serial.fileno = no_fileno

    import ics35_async
    from ics35_async import open_bus, protocol

    results = {{"import": sorted(m for m in BLOCKED if m in sys.modules)}}


    async def on_the_pty(driver):
        async with open_bus(PTY, driver=driver, retries=2, adapter_latency=LATENCY) as bus:
            out = {{"stretch": await bus.servo(1).read_stretch(), "scan": await bus.scan(range(4))}}
            seen = set()
            frames = 0
            async with bus.stream([1, 2], rate_hz=100) as stream:
                stream.set_targets({{1: 7000, 2: 8000}})
                for _ in range(10):
                    frame = await stream.next_frame()
                    seen.update(frame.positions)
                    frames += 1
            out["stream_ids"] = sorted(seen)
            out["stream_frames"] = frames
            out["driver"] = bus.driver
        return out


    async def on_the_simulator(driver):
        async with open_bus("sim://?ids=3", driver=driver) as bus:
            return await bus.servo(3).read_stretch()


    async def typed_errors(driver):
        out = {{}}
        cases = {{
            "missing": "/dev/ttyICS-no-such-port",
            "refused": "socket://127.0.0.1:1",
            "not_serial": "/dev/null",
        }}
        for name, port in cases.items():
            try:
                async with open_bus(port, driver=driver):
                    out[name] = "opened"
            except Exception as exc:
                out[name] = [c.__name__ for c in type(exc).__mro__]
        async with open_bus(PTY, driver=driver):
            try:
                async with open_bus(PTY, driver=driver):
                    out["busy"] = "opened"
            except Exception as exc:
                out["busy"] = [c.__name__ for c in type(exc).__mro__]
        return out


    for driver in ("asyncio", "thread", "anyio"):
        results[driver] = {{
            "pty": asyncio.run(on_the_pty(driver)),
            "sim": asyncio.run(on_the_simulator(driver)),
            "errors": asyncio.run(typed_errors(driver)),
        }}

    from ics35_async.cli import main

    read = ["--port", PTY, "--timeout", str(LATENCY), "get", "1", "stretch"]
    for name, argv in (("help", ["--help"]), ("read", read)):
        try:
            main(argv)
        except SystemExit as exc:
            results["cli_" + name] = exc.code
    results["importers"] = blocker.importers
    results["loaded"] = sorted(m for m in BLOCKED if m in sys.modules)
    print(json.dumps(results))
    """
).format(blocked=BLOCKED, latency=NO_TIMEOUTS["adapter_latency"])


@pytest.fixture(scope="module")
def far_pty() -> Iterator[str]:
    """The simulator's pty, served by another process."""
    proc, path = start_subprocess(["--ids", "1-3"], quiet=True)
    try:
        yield path
    finally:
        stop_subprocess(proc)


def test_package_runs_without_posix_terminal_modules_or_port_descriptors(far_pty: str) -> None:
    proc = subprocess.run(
        [sys.executable, "-c", SCRIPT, far_pty], capture_output=True, text=True, timeout=120, cwd=Path.cwd()
    )
    assert proc.returncode == 0, proc.stderr[-4000:]
    report = json.loads(proc.stdout.strip().splitlines()[-1])
    # Our modules may ask for termios (and cope without it); none of the four got loaded.
    assert report["import"] == [], report
    assert report["loaded"] == [], report
    for driver in ("asyncio", "thread", "anyio"):
        run = report[driver]
        assert run["pty"]["stretch"] == 30, (driver, run)
        assert run["pty"]["scan"] == [1, 2, 3], (driver, run)
        assert run["pty"]["stream_frames"] == 10
        assert run["pty"]["stream_ids"] == [1, 2], (driver, run)
        assert run["sim"] == 30
        errors = run["errors"]
        assert errors["missing"][0] == "PortNotFound", (driver, errors)
        assert errors["busy"][0] == "PortBusy", (driver, errors)
        assert "SerialPortError" in errors["refused"], (driver, errors)
        assert "SerialPortError" in errors["not_serial"], (driver, errors)
    assert report["cli_help"] == 0
    assert report["cli_read"] == 0, (report, proc.stderr[-2000:])
    # The CLI's output went to the subprocess's stdout before the report.
    assert "Usage: ics35" in proc.stdout


# pyserial's Windows backend (serialwin32) says what went wrong only in its message:
# SerialException("could not open port {!r}: {!r}".format(port, ctypes.WinError())).
WINDOWS_OPEN_ERRORS = [
    ("FileNotFoundError(2, 'The system cannot find the file specified.', None, 2)", PortNotFound),
    ("PermissionError(13, 'Access is denied.', None, 5)", PortBusy),
    ("OSError(22, 'The semaphore timeout period has expired.', None, 121)", SerialPortError),
]


@pytest.mark.parametrize(("winerror", "expected"), WINDOWS_OPEN_ERRORS)
def test_windows_open_errors_are_typed(winerror: str, expected: type[Exception]) -> None:
    import serial

    exc = serial.SerialException(f"could not open port 'COM7': {winerror}")
    translated = translate_open_error("COM7", exc)
    assert type(translated) is expected
    assert not isinstance(translated, PortPermissionDenied)
    assert "COM7" in str(translated)
