"""``import ics35_async.sim`` on a system without termios, fcntl, tty and pty (the Windows stand-in).

A subprocess makes those four modules unimportable (a ``sys.meta_path``
finder that raises ImportError, installed after ``import serial``, which may
use them), imports the simulator package and drives the in-process simulator
through its device API (connect / write / deliver), fast and real-time, plus
``open_url``.  The pty server itself needs them: asking for it must raise a
plain ImportError, not break the package.

What this proves: nothing in ``ics35_async.sim`` that the in-process simulator
needs imports a POSIX-only module, and the sim package loads the pty server
only on demand.  What it does not prove: that Windows' own ctypes, threading
and timers behave (``clock.lower_timer_slack`` is a no-op off Linux).

The package root imports under the blocker too (the whole-package stand-in
for Windows is tests/test_platform_windows_standin.py).
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

BLOCKED = ("termios", "fcntl", "tty", "pty")

SCRIPT = textwrap.dedent(
    """
    import json
    import os
    import sys
    import threading

    import serial  # pyserial may use the blocked modules itself; on Windows it has its own backend

    BLOCKED = {blocked!r}
    SIM_DIR = os.sep + os.path.join("ics35_async", "sim") + os.sep


    class Blocker:
        enabled = True
        importers = []  # (module, file of the importing code)

        def find_spec(self, name, path=None, target=None):
            if not self.enabled or name not in BLOCKED:
                return None
            frame = sys._getframe(1)
            while frame is not None and frame.f_code.co_filename.startswith("<frozen"):
                frame = frame.f_back
            self.importers.append((name, frame.f_code.co_filename if frame else "?"))
            raise ImportError(f"No module named {{name!r}} (blocked: not on this platform)", name=name)


    def forget(prefixes):
        for mod in list(sys.modules):
            if any(mod == p or mod.startswith(p + ".") for p in prefixes):
                del sys.modules[mod]


    blocker = Blocker()
    forget(BLOCKED)
    sys.meta_path.insert(0, blocker)
    path_taken = "strict"
    import ics35_async.sim as sim

    outside = []

    loaded = sorted(m for m in BLOCKED if m in sys.modules)


    class Host:
        def __init__(self):
            self.data = bytearray()
            self.got = threading.Event()

        def deliver(self, data):
            self.data += data
            self.got.set()

        def lost(self, exc):
            pass


    def transact(device, tx, expected_len, baud=115200):
        host = Host()
        device.connect(host, baud)
        try:
            device.write(tx)
            while len(host.data) < expected_len:
                assert host.got.wait(10), bytes(host.data).hex(" ")
                host.got.clear()
        finally:
            device.disconnect()
        return bytes(host.data)


    results = {{}}
    line = sim.VirtualLine([sim.VirtualServo(1, position=8000)])
    results["fast"] = transact(line, bytes.fromhex("81 00 00"), 6).hex(" ")  # free: echo + position
    line.close()
    realtime = sim.VirtualLine([sim.VirtualServo(2)], realtime=True)
    results["realtime"] = transact(realtime, bytes.fromhex("A2 02"), 5).hex(" ")  # read speed
    realtime.close()
    results["url"] = transact(sim.open_url("sim://?ids=3"), bytes.fromhex("A3 01"), 5).hex(" ")
    results["timer_slack"] = sim.lower_timer_slack()  # ctypes prctl on Linux, a no-op elsewhere
    importers = list(blocker.importers)  # before asking for the pty server, which needs them
    try:
        sim.PtyServer
    except ImportError as exc:
        results["pty_server"] = "ImportError: " + str(exc)
    else:
        results["pty_server"] = "loaded"
    print(json.dumps({{
        "path": path_taken,
        "outside": outside,
        "importers": importers,
        "loaded": loaded,
        "results": results,
    }}))
    """
).format(blocked=BLOCKED)


def test_sim_imports_and_runs_without_posix_tty_modules() -> None:
    proc = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout.strip().splitlines()[-1])
    # No module of the simulator asked for a blocked module while importing or running.
    assert report["loaded"] == [], report
    assert all("/ics35_async/sim/" not in importer for _, importer in report["importers"]), report
    results = report["results"]
    assert results["fast"] == "81 00 00 01 3e 40"  # echo, then ID 1 at 8000
    assert results["realtime"] == "a2 02 22 02 7f"  # echo, then speed 127
    assert results["url"] == "a3 01 23 01 1e"  # echo, then stretch 30
    assert isinstance(results["timer_slack"], bool)
    # The pty server is the one part that needs them, and says so when asked for.
    assert results["pty_server"].startswith("ImportError"), results
    print(f"import path: {report['path']} (outside sim: {report['outside']})")
