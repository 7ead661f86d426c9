"""The bus for programs without an event loop: plain scripts, Jupyter, ROS 1 nodes.

::

    from ics35_async import blocking

    STAND = dict.fromkeys(range(12), 7500)  # where each servo stands, in counts

    with blocking.stop_on_signals(), blocking.open_bus("/dev/ttyUSB0", baudrate=1250000) as bus:
        print("temperature of 1:", bus.servo(1).read_temperature())
        stream = bus.stream(STAND, rate_hz=100, on_close="free")
        stream.set_targets(STAND)  # before the block: every servo holds from its first command
        with stream:  # Ctrl-C ends it: every servo goes free, the port is released
            for frame in stream:  # lift_holds=False: a servo back from offline stays held (see the guide)
                stream.set_targets({i: 7500 + 5 * (frame.cycle % 200) for i in STAND}, lift_holds=False)

A program whose body is a plain ``def main()`` ends with ``sys.exit(blocking.run(main))``
(:func:`~ics35_async.running.run_blocking`): the signal handling of :func:`stop_on_signals`, the exit
codes of :func:`ics35_async.run`, and a library error that ends it (a port lost or mistyped) said as one
line instead of a traceback.

The async :class:`~ics35_async.Bus` runs on an event loop in a background
thread (one per bus); every blocking call hands its work to that loop and
waits for the result: 60-100 microseconds per call on top of the wire time
when the loop is idle.  A stream runs on the loop, so a consumer pays that
per frame it takes, not per transaction.  Errors are the same typed :mod:`ics35_async.errors` classes, raised in
the calling thread.  Ctrl-C while a call waits cancels that call on the loop;
leaving the ``with`` block then closes the bus and ends the thread.

Called from a thread that already runs an event loop (a Jupyter cell, a
coroutine), it works the same way and blocks that loop for the duration of
each call; async code does better with the async API.
"""

from __future__ import annotations

from ..running import run_blocking as run
from ..running import stop_on_signals
from .blocking_bus import BlockingBus, BlockingDevice, BlockingServo, open_bus
from .blocking_robot import BlockingRobot, open_robot
from .blocking_stream import BlockingStream

__all__ = [
    "BlockingBus",
    "BlockingDevice",
    "BlockingRobot",
    "BlockingServo",
    "BlockingStream",
    "open_bus",
    "open_robot",
    "run",
    "stop_on_signals",
]
