"""A virtual ICS 3.5 bus: up to 32 servos (and generic memory devices) on one line.

Two ways in:

* **In process**: :class:`SimBus` is a :class:`~ics35_async.transport.WireDevice`;
  importing this package registers the ``sim://`` URL scheme, so
  ``open_bus("sim://?ids=0-31&baud=1250000&realtime=1")`` talks to it.
  Tests build one from Python objects
  (``SimBus([VirtualServo(1), VirtualServo(2, position=9000)], faults="drop:0.1", seed=3, name="t")``)
  and reach it by name (``sim://t``).
* **On a pseudo-terminal**: ``python -m ics35_async.sim --ids 0-31 [--baud B]
  [--realtime] [--faults SPEC] [--seed N]`` prints a device path on its first
  line; any serial program can open it (see :mod:`.pty_server` for pyserial's
  parity quirk on ptys).

URL syntax: ``sim://[NAME][?key=value&...]``.  ``sim://`` alone is 32
factory servos (IDs 0..31) at 115200 bit/s in fast mode.  Keys:
``ids`` (``0-31``, ``1,3,5-7``), ``baud``, ``realtime`` (1/0), ``echo``
(1/0), ``follow_baud`` (1/0), ``seed``, ``faults`` (e.g.
``drop:0.01,late@3:0.1``, see :mod:`.faults`), ``turnaround``,
``eeprom_delay``, ``late_delay``, ``unplug_after``, ``replug_after``
(seconds, or with ``us``/``ms``/``s``), ``memory`` (IDs of generic devices),
``log`` (log size, ``all``), ``record`` (file), ``replay`` (file: serve a
recording).  With a NAME, the first URL creates the line and later ones
(reconnects) return the same object.

The line's baud rate is the host's: ``connect(host, baudrate)`` (or the
pty client's settings) sets it, and a servo whose EEPROM (power-up) baud
differs stays silent.  ``baud=`` sets the servos' EEPROM rate.

Modes and clocks.  Fast mode (default): answers are delivered at once, and
the line keeps a simulated clock that advances by the modelled wire time of
every transaction (11 bit times a byte, plus a 100 us turnaround, plus 20 ms
for the EEPROM write) and by :meth:`SimBus.advance`, so motion is
deterministic whatever the host's speed.  Real-time mode: the clock is
``time.perf_counter()`` and each chunk is delivered no earlier than its wire
time, by a delivery thread (in process) or the server's loop (pty) that
sleeps with 1 ns timer slack and spins the last 250 us.

Measured accuracy (``benchmarks/sim_timing.py``; 2-core VM, Linux 6.18,
Python 3.11; lateness = delivery time minus modelled wire time):

* in process, the delivery thread's ``host.deliver`` call: median 0.2 us,
  p99 1 us, max about 30 us (the thread must win the GIL back);
* in process, through an asyncio event loop (``call_soon_threadsafe`` to
  ``data_received``): median about 35 us, p99 about 120 us;
* over the pty, a blocking pyserial client's ``read`` returns a median of
  about 45 us (p99 about 150 us) after the modelled time: the pty's own
  latency, the same in fast mode.

so real-time mode is microsecond-exact at the device and the remaining
jitter is the host side's.
"""

from __future__ import annotations

from ..transport import WireDevice, register_url_scheme
from .clock import Deliverer, lower_timer_slack, wait_until
from .faults import FAULT_KINDS, FaultConfig, FaultInjector, parse_ids
from .line import (
    DEFAULT_EEPROM_WRITE_DELAY,
    DEFAULT_TURNAROUND,
    SimBus,
    Transaction,
    garble,
    named,
    parse_url,
)
from .pty_server import PtyServer, serving, start_subprocess, stop_subprocess
from .pty_server import main as main
from .record import Entry, Mismatch, Recorder, ReplayDevice, load_recording, parse_recording
from .servo import MemoryDevice, VirtualServo


def open_url(url: str) -> WireDevice:
    """The device a ``sim://`` URL names (the registered URL-scheme factory).

    A named line (``sim://NAME?...``) is created once and returned again by
    later calls, so a bus that reconnects finds the same servos.
    """
    name, options = parse_url(url)
    if name is not None:
        try:
            return named(name)
        except KeyError:
            pass
    replay = options.pop("replay", None)
    if replay is not None:
        if options:
            raise ValueError(f"sim URL: replay= takes no other options, got {', '.join(sorted(options))}")
        return ReplayDevice(replay)
    return SimBus(name=name, **options)


register_url_scheme("sim", open_url)

__all__ = [
    "DEFAULT_EEPROM_WRITE_DELAY",
    "DEFAULT_TURNAROUND",
    "FAULT_KINDS",
    "Deliverer",
    "Entry",
    "FaultConfig",
    "FaultInjector",
    "MemoryDevice",
    "Mismatch",
    "PtyServer",
    "Recorder",
    "ReplayDevice",
    "SimBus",
    "Transaction",
    "VirtualServo",
    "garble",
    "load_recording",
    "lower_timer_slack",
    "main",
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
