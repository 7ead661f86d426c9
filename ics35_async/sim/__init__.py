"""A virtual ICS 3.5 line: up to 32 servos (and generic memory devices) behind one port.

Two ways in:

* **In process**: :class:`VirtualLine` is a :class:`~ics35_async.transports.WireDevice`;
  a ``sim://`` port makes one (the scheme is known to the transports, which load this package for
  the first such port), so ``open_bus("sim://?ids=0-31&baud=1250000&realtime=1")`` talks to it.
  Tests build one from Python objects
  (``VirtualLine([VirtualServo(1), VirtualServo(2, position=9000)], faults="drop:0.1", seed=3, name="t")``)
  and reach it by name (``sim://t``).
* **On a pseudo-terminal**: ``python -m ics35_async.sim --ids 0-31 [--baud B]
  [--fast] [--faults SPEC] [--seed N]`` prints a device path on its first
  line; any serial program can open it (see :mod:`.pty_port` for pyserial's
  parity quirk on ptys).  It runs in real time unless ``--fast``: programs
  on the other end of a serial port expect time to pass between commands.

Modules, each using only those listed before it: :mod:`.transaction` (a log entry),
:mod:`.virtual_servo` (the devices), :mod:`.faults`, :mod:`.precise_wait` (precise waiting),
:mod:`.record` (record and replay), :mod:`.devices` (which devices answer a command),
:mod:`.framing` (the host's bytes cut into commands), :mod:`.model` (the sans-IO wire model,
optionally behind a USB adapter model from :mod:`ics35_async.transports.usb_timing`),
:mod:`.virtual_line` (:class:`VirtualLine`: the model as an in-process port), :mod:`.adapter`
(adapter models by name), :mod:`.url` (``sim://`` URLs; :func:`open_url` is what the core calls);
then, POSIX only and loaded on demand, :mod:`.pty_port` (pty plumbing), :mod:`.tap` (a pty that
hears the line), :mod:`.pty_server` (the pty driver), :mod:`.console` (plugging and unplugging
servos while it serves) and :mod:`.server_cli` (its command line); :mod:`.launch` runs that in a
subprocess.

URL syntax: ``sim://[NAME][?key=value&...]``.  ``sim://`` alone is 32
factory servos (IDs 0..31) at 115200 bit/s in fast mode.  Keys:
``ids`` (``0-31``, ``1,3,5-7``), ``baud``, ``realtime`` (1/0), ``echo``
(1/0), ``follow_baud`` (1/0), ``seed``, ``faults`` (e.g.
``drop:0.01,late@3:0.1,tail:0.05``, see :mod:`.faults`), ``turnaround``,
``eeprom_delay``, ``late_delay``, ``tail_delay``, ``unplug_after``,
``replug_after`` (seconds, or with ``us``/``ms``/``s``; finite, at most what a timer can wait: the port
pulled ``unplug_after`` seconds after the first connect comes back ``replug_after`` later, 0.2 s by default;
a long one, ``replug_after=1e6``, keeps it away), ``tail_bytes``
(what the held-tail fault holds back), ``ics36`` (IDs of servos that speak ICS 3.6),
``noisy`` (IDs of servos whose position readings jump at each reply), ``memory`` (IDs of generic devices),
``log`` (log size, ``all``), ``record`` (file), ``replay`` (file: serve a
recording), ``adapter=ftdi`` with ``latency_timer`` (ms): a USB adapter
model between line and host (:mod:`.adapter`; implies real time).  With a
NAME, the first URL creates the line and later ones (reconnects) return the
same object.

The line's baud rate is the host's: ``connect(host, baudrate)`` (or the
pty client's settings) sets it, and a servo whose EEPROM (power-up) baud
differs stays silent.  ``baud=`` sets the servos' EEPROM rate.

Modes and clocks.  Fast mode (the default in process; ``--fast`` on a pty): answers are delivered at once, and
the line keeps a simulated clock that advances by the modelled wire time of
every transaction (11 bit times a byte, plus a 100 us turnaround, plus 20 ms
for the EEPROM write) and by :meth:`VirtualLine.advance`, so motion is
deterministic whatever the host's speed.  Real-time mode: the clock is
``time.perf_counter()`` and each chunk is delivered no earlier than its wire
time, by a delivery thread (in process) or the server's loop (pty) that
sleeps with 1 ns timer slack and spins the last 250 us.

Measured accuracy (``benchmarks/sim_timing.py``, two runs of 2000-3000
samples on a shared, busy 2-core VM, Linux 6.18, Python 3.11; lateness =
arrival minus the modelled wire time, in microseconds):

========================================================  ======  ========  ==========
path                                                      median  p99       max
========================================================  ======  ========  ==========
``wait_until`` (sleep, then spin), the waiting primitive  0.2     2-44      36-2500
  baseline: ``time.sleep`` / ``asyncio.sleep`` (300 us)   73/790  120/860   850/3200
in process: delivery thread calls ``host.deliver``        1-2     8-90      1400-3700
in process, through asyncio to ``data_received``          9-35    40-100    800-4000
  baseline: fast mode, write to ``data_received``         19-21   42-57     110-1000
pty, blocking pyserial client, reply vs modelled time     64-79   170-190   950-4600
  baseline: pty in fast mode (no model; pty latency)      60-97   130-165   210-4500
========================================================  ======  ========  ==========

So a chunk never arrives early, typically arrives within 2 us of its wire
time at the device, and what remains is host-side latency (the event loop's
wake-up, the pty), the same as without the wire model.  Outliers of a few
ms come from the machine (other processes, the GIL: a delivery thread that
must wait for an event loop busy running Python code can be held up to
``sys.getswitchinterval()``, 5 ms).  In process such a delay is never the
servo's: a host that looks for input takes what is due by then on its own
thread (``deliver_due``), as a real port's bytes wait in the operating
system's buffer, so a busy program does not see a simulated reply late or
missing.  Fast-mode throughput: about 75 000
transactions/s (13 us each) through :meth:`VirtualLine.process`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from ..units import parse_ids
from .devices import garble
from .faults import FAULT_KINDS, FaultConfig, FaultInjector
from .launch import serving, start_subprocess, stop_subprocess
from .model import DEFAULT_EEPROM_WRITE_DELAY, DEFAULT_TURNAROUND, LineModel, LineModelOptions
from .precise_wait import Deliverer, lower_timer_slack, wait_until
from .record import Entry, Mismatch, ReplayDevice, TransactionRecorder, load_recording, parse_recording
from .transaction import Transaction
from .url import open_url, parse_url
from .virtual_line import ServoState, VirtualLine, named
from .virtual_servo import MemoryDevice, VirtualServo

if TYPE_CHECKING:  # loaded on first use (see __getattr__), named here for type checkers
    from .pty_server import PtyServer as PtyServer
    from .server_cli import main as main


def __getattr__(name: str) -> Any:
    # The pty server and its command line need termios, fcntl and tty (POSIX only): they are
    # imported when one of their names is first asked for, so the in-process simulator imports anywhere
    # (and they stay out of __all__, so a star import works there too).
    value: Any
    if name == "PtyServer":
        from .pty_server import PtyServer as value
    elif name == "main":
        from .server_cli import main as value
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    globals()[name] = value
    return value


__all__ = [
    "DEFAULT_EEPROM_WRITE_DELAY",
    "DEFAULT_TURNAROUND",
    "FAULT_KINDS",
    "Deliverer",
    "Entry",
    "FaultConfig",
    "FaultInjector",
    "LineModel",
    "LineModelOptions",
    "MemoryDevice",
    "Mismatch",
    "ReplayDevice",
    "ServoState",
    "Transaction",
    "TransactionRecorder",
    "VirtualLine",
    "VirtualServo",
    "garble",
    "load_recording",
    "lower_timer_slack",
    "named",
    "open_url",
    "parse_ids",
    "parse_recording",
    "parse_url",
    "serving",
    "start_subprocess",
    "stop_subprocess",
    "wait_until",
]
