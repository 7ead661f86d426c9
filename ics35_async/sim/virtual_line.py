"""The simulated line as a program sees it: :class:`VirtualLine`, a port with devices behind it.

:class:`VirtualLine` is the :class:`~.model.LineModel` (the wire timing,
faults, log) plus what makes it a line one plugs into:

* the :class:`~ics35_async.transport.WireDevice` face (``connect`` /
  ``write`` / ``disconnect``) for in-process use, answering synchronously in
  fast mode and from a :class:`~.precise_wait.Deliverer` thread at the modelled wire
  time in real-time mode (the pty server, :mod:`.pty_server`, is the other
  driver of the same model);
* the port's presence: unplug and replug, by fault, by timer or by hand;
* access to its devices (plugged in, unplugged and power-cycled while it runs), and a name by which
  ``sim://NAME`` finds it.
"""

from __future__ import annotations

import errno
import threading
from collections.abc import Callable, Iterable
from typing import NamedTuple, Unpack

from ..eeprom import BaudRate
from ..errors import PortBusy
from ..transports import HostSide
from ..units import POSITION_MAX, check_int
from .devices import VirtualDevice
from .model import LineModel, LineModelOptions, check_delay
from .precise_wait import SPIN_MARGIN, Deliverer
from .virtual_servo import MemoryDevice, VirtualServo

DEFAULT_REPLUG_AFTER = 0.2


class ServoState(NamedTuple):
    """One servo on a simulated line as [`VirtualLine.servo_states`][ics35_async.sim.VirtualLine.servo_states]
    finds it."""

    servo_id: int
    """The ID it answers to."""
    eeprom_baud: int | None
    """The baud rate its EEPROM holds (it listens at it after its next power-up); ``None``: a code the
    reference does not define."""
    baud: int
    """The baud rate it listens at now."""
    ics36: bool
    """It speaks ICS 3.6 (answers the position read)."""
    position: int
    """Where it is (host coordinates)."""
    free: bool
    """Its torque is off."""


class VirtualLine(LineModel):
    """A simulated ICS 3.5 line with up to 32 servos and optional memory devices.

    Its other keyword options (the wire's and the devices': ``baudrate``, ``realtime``, ``faults``,
    ...) are those of [`LineModelOptions`][ics35_async.sim.LineModelOptions], each described there.

    Args:
        servos: [`VirtualServo`][ics35_async.sim.VirtualServo] objects or IDs (factory servos);
            ``None`` means IDs 0..31.
        follow_host_baud: the line runs at the rate the host connects with (else at ``baudrate``).
        unplug_after: the port disappears that many wall-clock seconds after the first connect.
        replug_after: it comes back (also after an ``unplug`` fault) that many seconds later.
        spin_margin: seconds the delivery thread spins before a chunk is due (see ``ics35_async.sim.precise_wait``).
        name: registers the line so ``sim://NAME`` reaches this object.

    Raises:
        InvalidArgument: an unknown option, a delay that is negative, not finite or longer than a timer can
            wait (``check_delay``), a bad baud rate, ID or fault spec.
    """

    def __init__(
        self,
        servos: Iterable[VirtualServo | int] | None = None,
        *,
        follow_host_baud: bool = True,
        unplug_after: float | None = None,
        replug_after: float = DEFAULT_REPLUG_AFTER,
        spin_margin: float = SPIN_MARGIN,
        name: str | None = None,
        **options: Unpack[LineModelOptions],
    ) -> None:
        super().__init__(servos, **options)
        self.follow_host_baud = follow_host_baud
        self.unplug_after = None if unplug_after is None else check_delay("unplug_after", unplug_after)
        self.replug_after = check_delay("replug_after", replug_after)
        self.spin_margin = spin_margin
        self.name = name
        self.url_query: str | None = None  # the options of the sim:// URL that made it (see sim.url.open_url)
        self.plugged = True
        self.replug_pending = False  # unplugged with a replug of its own to come (not one left out until told)
        self.unplug_count = 0
        self._host: HostSide | None = None
        self._deliverer: Deliverer | None = None
        self._timers: list[threading.Timer] = []
        self._unplug_scheduled = False
        self._listeners: list[Callable[[bool], None]] = []
        if name is not None:
            _NAMED[name] = self

    # ------------------------------------------------------------------ devices

    @property
    def devices(self) -> list[VirtualDevice]:
        """Every device on the line, servos and memory devices."""
        return self.table.devices

    @property
    def servos(self) -> list[VirtualServo]:
        """The servos on the line."""
        return self.table.servos

    def servo(self, servo_id: int) -> VirtualServo:
        """The (first) servo whose current ID is ``servo_id``."""
        return self.table.servo(servo_id)

    def memory_device(self, device_id: int) -> MemoryDevice:
        """The (first) memory device whose ID is ``device_id``."""
        return self.table.memory_device(device_id)

    def servos_at(self, servo_id: int) -> list[VirtualServo]:
        """Every servo whose current ID is ``servo_id`` (several share one only by mistake), oldest first."""
        with self._lock:
            return self.table.servos_at(servo_id)

    def add_device(self, device: VirtualDevice) -> None:
        """Put one more device on the line (as if plugged in while it runs)."""
        with self._lock:
            self.table.add(device)

    def remove_device(self, device: VirtualDevice) -> None:
        """Take ``device`` off the line (as if unplugged while it runs); it keeps its EEPROM.

        Raises:
            ValueError: that object is not on the line.
        """
        with self._lock:
            self.table.update(self.now())
            self.table.remove(device)

    def remove_servo(self, servo_id: int) -> VirtualServo:
        """Unplug the servo whose current ID is ``servo_id`` and return it; of several at that ID, the one
        plugged in last.

        Raises:
            KeyError: no servo has that ID.
        """
        with self._lock:
            present = self.table.servos_at(servo_id)
            if not present:
                raise KeyError(f"no servo with ID {servo_id} on the simulated line")
            self.remove_device(present[-1])
            return present[-1]

    def power_cycle(self, servo_id: int | None = None) -> list[VirtualServo]:
        """Power-cycle every servo on the line, or those whose ID is ``servo_id``: RAM reloads from the
        EEPROM (a baud rate written there takes effect now) and each wakes up free.  Returns them.

        Raises:
            KeyError: no servo has ID ``servo_id`` (nothing is power-cycled).
        """
        with self._lock:
            servos = self.servos if servo_id is None else self.table.servos_at(servo_id)
            if servo_id is not None and not servos:
                raise KeyError(f"no servo with ID {servo_id} on the simulated line")
            now = self.now()
            for servo in servos:
                servo.update(now)
                servo.power_cycle()
            return servos

    def move_by_hand(self, servo_id: int, position: int) -> list[VirtualServo]:
        """Turn the servos whose ID is ``servo_id`` by hand to ``position`` (host coordinates), as
        [`VirtualServo.move_by_hand`][ics35_async.sim.VirtualServo.move_by_hand] does: a free one stays
        there, a holding one turns back to its target at its speed from now on.  Returns them.

        Raises:
            KeyError: no servo has ID ``servo_id`` (nothing is turned).
            InvalidArgument: ``position`` is not 1..16383 (nothing is turned).
        """
        check_int("position", position, 1, POSITION_MAX)
        with self._lock:
            servos = self.table.servos_at(servo_id)
            if not servos:
                raise KeyError(f"no servo with ID {servo_id} on the simulated line")
            now = self.now()
            for servo in servos:
                servo.update(now)  # its way so far first: the way back of a holding one starts now
                servo.move_by_hand(position)
            return servos

    def servo_states(self) -> list[ServoState]:
        """Each servo's state now (ID, EEPROM and listening baud rates, ICS version, position), in the
        order they were plugged in."""
        with self._lock:
            now = self.now()
            states = []
            for servo in self.servos:
                servo.update(now)
                eeprom_baud = servo.eeprom.baud_rate
                states.append(
                    ServoState(
                        servo.servo_id,
                        int(eeprom_baud) if isinstance(eeprom_baud, BaudRate) else None,
                        int(servo.baud_rate),
                        servo.ics36,
                        servo.position,
                        servo.free,
                    )
                )
            return states

    # ------------------------------------------------------------------ the WireDevice face

    def connect(self, host: HostSide, baudrate: int) -> None:
        """Open the port for ``host`` at ``baudrate`` (the WireDevice face; the line follows the rate
        with ``follow_host_baud``).

        Raises:
            OSError: the port is unplugged (``ENOENT``); PortBusy (an OSError, ``EBUSY``): it is already open.
        """
        with self._lock:
            if not self.plugged:
                raise OSError(errno.ENOENT, "the simulated port is unplugged")
            if self._host is not None:
                line = f"sim://{self.name}" if self.name is not None else "the simulated line"
                raise PortBusy(errno.EBUSY, f"{line} is already open: a simulated line takes one bus at a time")
            self._host = host
            if self.follow_host_baud:
                self.baudrate = int(baudrate)
            if self.realtime and self._deliverer is None:
                self._deliverer = Deliverer(self.spin_margin)
            if self.unplug_after is not None and not self._unplug_scheduled:
                self._unplug_scheduled = True
                self.schedule_unplug(self.unplug_after, self.replug_after)

    def write(self, data: bytes) -> None:
        """The host writes ``data``: the answers are delivered to it, at once (fast mode) or at their
        wire time (real time).

        Raises:
            OSError: the port is not open (``EIO``) or was unplugged (``ENODEV``).
        """
        host = self._host
        if host is None:
            if not self.plugged:  # (a write between unplug() taking the host and telling it: the same words)
                raise OSError(errno.ENODEV, "the simulated port was unplugged")
            raise OSError(errno.EIO, "the simulated port is not open")
        chunks = self.process(data)
        if self.realtime:
            deliverer = self._deliverer
            if deliverer is None:
                return  # unplugged or disconnected meanwhile: the bytes are lost
            for when, chunk in chunks:
                deliverer.schedule(self.epoch + when, chunk, host.deliver)
            if self.take_unplug_request():
                when = self.epoch + self.line_free
                # (the delivery thread's alone: the unplug stops that deliverer, which a reader must not wait on)
                deliverer.schedule(when, b"", lambda _: self.unplug(replug_after=self.replug_after), thread_only=True)
        else:
            if chunks:
                host.deliver(b"".join(chunk for _, chunk in chunks))
            if self.take_unplug_request():
                self.unplug(replug_after=self.replug_after)

    def deliver_due(self) -> None:
        """Deliver now, on the calling thread, what is due by now (real time; the WireDevice face): the host
        looks for input, and a servo's reply that came off the wire is there whatever held the delivery
        thread back."""
        deliverer = self._deliverer
        if deliverer is not None:
            deliverer.deliver_due()

    def disconnect(self) -> None:
        """Close the port for its host (what is still to be delivered is dropped)."""
        with self._lock:
            self._host = None
        self._stop_deliverer()

    def _stop_deliverer(self) -> None:
        # Outside the lock: the delivery thread may be running an unplug that needs it.
        with self._lock:
            deliverer, self._deliverer = self._deliverer, None
        if deliverer is not None:
            deliverer.close()

    # ------------------------------------------------------------------ unplug / replug

    def add_listener(self, callback: Callable[[bool], None]) -> None:
        """Call ``callback(plugged)`` after every unplug and replug (any thread)."""
        self._listeners.append(callback)

    def unplug(self, exc: Exception | None = None, *, replug_after: float | None = None) -> None:
        """The port disappears: the host loses the line, connect() fails until :meth:`replug`.

        The host's port is lost with ``exc`` (default: an ``ENODEV`` OSError).  With ``replug_after``
        (wall-clock seconds) the port comes back by itself.

        Raises:
            InvalidArgument: ``replug_after`` is not a delay a timer can wait (see ``check_delay``).
        """
        if replug_after is not None:  # here: its timer thread would die of a time it cannot wait, the port gone
            replug_after = check_delay("replug_after", replug_after)
        with self._lock:
            if not self.plugged:
                return
            self.plugged = False
            self.replug_pending = replug_after is not None
            self.unplug_count += 1
            host, self._host = self._host, None
            self.reset_wire()
            if self.adapter is not None:
                self.adapter.reset()  # a new chip's timer
        self._stop_deliverer()
        if replug_after is not None:
            self._start_timer(replug_after, self.replug)
        if host is not None:
            host.lost(exc or OSError(errno.ENODEV, "the simulated port was unplugged"))
        for callback in list(self._listeners):
            callback(False)

    def replug(self) -> None:
        """The port comes back: ``connect`` works again."""
        with self._lock:
            if self.plugged:
                return
            self.plugged = True
            self.replug_pending = False
        for callback in list(self._listeners):
            callback(True)

    def schedule_unplug(self, after: float, replug_after: float | None = None) -> None:
        """Unplug ``after`` wall-clock seconds from now, replug ``replug_after`` later.

        Raises:
            InvalidArgument: either is not a delay a timer can wait (see ``check_delay``).
        """
        after = check_delay("unplug_after", after)
        if replug_after is not None:
            replug_after = check_delay("replug_after", replug_after)

        def fire() -> None:
            self.unplug(replug_after=replug_after)

        self._start_timer(after, fire)

    def _start_timer(self, delay: float, action: Callable[[], None]) -> None:
        timer = threading.Timer(delay, action)
        timer.daemon = True
        with self._lock:
            self._timers = [t for t in self._timers if t.is_alive()]
            self._timers.append(timer)
        timer.start()

    # ------------------------------------------------------------------ lifetime

    def close(self) -> None:
        """Stop threads and timers, close a recording, forget the name."""
        for timer in self._timers:
            timer.cancel()
        self._stop_deliverer()
        self.stop_recording()
        if self.name is not None and _NAMED.get(self.name) is self:
            del _NAMED[self.name]

    def __enter__(self) -> VirtualLine:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        mode = "realtime" if self.realtime else "fast"
        behind = f" behind {self.adapter!r}" if self.adapter is not None else ""
        return f"<VirtualLine {len(self.devices)} devices @{self.baudrate} {mode}{behind} txns={self.transactions}>"


_NAMED: dict[str, VirtualLine] = {}


def named(name: str) -> VirtualLine:
    """The line registered under ``name`` (``VirtualLine(name=...)`` or ``sim://NAME``)."""
    return _NAMED[name]
