"""The virtual ICS line: :class:`VirtualLine`, its transaction log and its URL.

:meth:`VirtualLine.feed` is the sans-IO core: host bytes and the time they were
written go in, the chunks the host receives (echo, replies, noise) and the
earliest time each may be delivered come out.  Two drivers sit on top:

* the :class:`~ics35_async.transport.WireDevice` face of :class:`VirtualLine`
  (``connect`` / ``write`` / ``disconnect``) for in-process use, answering
  synchronously in fast mode and from a :class:`~.clock.Deliverer` thread at
  the modelled wire time in real-time mode;
* the pseudo-terminal server (:mod:`.pty_server`).

Wire model: a host byte occupies the line for 11 bit times; the echo of a
write arrives when its last byte has been sent; the addressed device starts
answering ``turnaround`` seconds after the end of the command (plus
``eeprom_write_delay`` for the EEPROM write) and its reply arrives, whole,
when its last byte has crossed the line.  Bytes the host writes while the
line is still busy (an answer in progress) are sent after it: the simulator
does not model electrical collisions except through the ``echo`` fault and
the ID command on a multi-device line.
"""

from __future__ import annotations

import errno
import functools
import heapq
import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Iterable, Mapping
from typing import Any

from ..eeprom import BaudRate
from ..errors import InvalidArgument
from ..protocol import BITS_PER_BYTE, ReadId, WriteEeprom, WriteId, decode_request
from ..transport import HostSide
from .clock import SPIN_MARGIN, Deliverer
from .faults import FaultConfig, FaultInjector
from .record import TransactionRecorder
from .servo import NO_REPLY, MemoryDevice, VirtualServo
from .transaction import Transaction

DEFAULT_TURNAROUND = 100e-6
"""Seconds a servo waits after a command before answering.  An assumption:
the reference gives no figure; 100 us is a round value in the range hobby
servo firmware achieves, and is easy to change (``turnaround=``)."""
DEFAULT_EEPROM_WRITE_DELAY = 20e-3
"""Extra seconds before the EEPROM-write reply ("noticeably longer" in the
reference; 20 ms is an assumption that keeps real-time tests quick)."""
DEFAULT_LOG_SIZE = 10_000
DEFAULT_REPLUG_AFTER = 0.2
DEFAULT_FRAME_TIMEOUT = 10e-3
DEFAULT_NOISE_GAP = 1e-3

Device = VirtualServo | MemoryDevice


def garble(replies: list[bytes]) -> bytes:
    """What the host hears when several devices answer at once.

    The line idles high and any device pulling it low wins, so the bytes
    combine as a wired-AND (a device that has finished contributes idle
    0xFF).  The devices' slightly different turnarounds smear the frames; we
    model that as one extra 0x00 byte (a glitch read as a start bit), so even
    identical replies come out visibly wrong.
    """
    length = max(len(r) for r in replies)
    anded = bytes(
        functools.reduce(lambda a, b: a & b, (r[i] if i < len(r) else 0xFF for r in replies)) for i in range(length)
    )
    return anded + b"\x00"


class VirtualLine:
    """A simulated ICS 3.5 line with up to 32 servos and optional memory devices.

    ``servos``: :class:`VirtualServo` objects or IDs (factory servos at
    ``baudrate``); ``None`` means IDs 0..31.  ``memory``: generic devices,
    ``{id: initial bytes}`` or :class:`MemoryDevice` objects.  ``baudrate``
    is the line's rate until a host connects (then the host's rate is used
    when ``follow_host_baud``), and the EEPROM rate of servos built from IDs.
    ``realtime`` delivers at the modelled wire times; otherwise the line's
    clock is simulated and advances only with wire time and :meth:`advance`.
    ``faults`` is a :class:`FaultConfig` or a spec string (:mod:`.faults`),
    drawn from ``random.Random(seed)``.  ``log_size`` bounds the
    transaction log (``None``: unbounded, 0: no log; :attr:`transactions`
    counts regardless).  ``name`` registers the line so ``sim://NAME``
    reaches this object.  ``record`` is a file path or text stream to record
    the session to (:mod:`.record`).
    """

    def __init__(
        self,
        servos: Iterable[VirtualServo | int] | None = None,
        *,
        baudrate: int = BaudRate.B115200,
        memory: Mapping[int, bytes | bytearray | MemoryDevice] | Iterable[MemoryDevice] | None = None,
        realtime: bool = False,
        echo: bool = True,
        turnaround: float = DEFAULT_TURNAROUND,
        eeprom_write_delay: float = DEFAULT_EEPROM_WRITE_DELAY,
        faults: FaultConfig | str | None = None,
        seed: int | None = 0,
        late_delay: float | None = None,
        noise_gap: float = DEFAULT_NOISE_GAP,
        log_size: int | None = DEFAULT_LOG_SIZE,
        follow_host_baud: bool = True,
        unplug_after: float | None = None,
        replug_after: float = DEFAULT_REPLUG_AFTER,
        frame_timeout: float = DEFAULT_FRAME_TIMEOUT,
        spin_margin: float = SPIN_MARGIN,
        name: str | None = None,
        record: Any = None,
    ) -> None:
        line_baud = BaudRate.parse(baudrate)
        built: list[Device] = []
        for item in range(32) if servos is None else servos:
            if isinstance(item, VirtualServo):
                built.append(item)
            else:
                built.append(VirtualServo(item, baud_rate=line_baud))
        if memory is not None:
            if isinstance(memory, Mapping):
                for device_id, content in memory.items():
                    built.append(
                        content if isinstance(content, MemoryDevice) else MemoryDevice(device_id, bytes(content))
                    )
            else:
                built.extend(memory)
        for value, what in ((turnaround, "turnaround"), (eeprom_write_delay, "eeprom_write_delay")):
            if value < 0:
                raise InvalidArgument(f"{what} must not be negative")
        self.devices: list[Device] = built
        self.baudrate: int = int(line_baud)
        self.realtime = realtime
        self.echo = echo
        self.turnaround = turnaround
        self.eeprom_write_delay = eeprom_write_delay
        self.late_delay = late_delay
        self.noise_gap = noise_gap
        self.follow_host_baud = follow_host_baud
        self.unplug_after = unplug_after
        self.replug_after = replug_after
        self.frame_timeout = frame_timeout
        self.spin_margin = spin_margin
        config = faults if isinstance(faults, FaultConfig) else FaultConfig.parse(faults)
        self.faults = FaultInjector(config, seed)
        self.log: deque[Transaction] = deque(maxlen=log_size)
        self._log_enabled = log_size != 0
        self.transactions = 0
        self.fault_counts: Counter[str] = Counter()
        self.unplug_count = 0
        self.plugged = True
        self.name = name

        self._lock = threading.RLock()
        self.epoch = time.perf_counter()
        self._clock = 0.0
        self._line_free = 0.0
        self._rx = bytearray()
        self._rx_echoed = 0
        self._rx_time = 0.0
        self._held: list[bytes] = []
        self._deferred: list[tuple[float, int, bytes]] = []
        self._deferred_order = 0
        self._unplug_requested = False
        self._host: HostSide | None = None
        self._deliverer: Deliverer | None = None
        self._timers: list[threading.Timer] = []
        self._unplug_scheduled = False
        self._listeners: list[Callable[[bool], None]] = []
        self._recorder: TransactionRecorder | None = None
        self._reindex()
        if record is not None:
            self.record_to(record)
        if name is not None:
            _NAMED[name] = self

    # ------------------------------------------------------------------ devices

    def _reindex(self) -> None:
        index: dict[int, list[Device]] = {}
        for device in self.devices:
            index.setdefault(device.servo_id, []).append(device)
        self._by_id = index

    @property
    def servos(self) -> list[VirtualServo]:
        return [d for d in self.devices if isinstance(d, VirtualServo)]

    def servo(self, servo_id: int) -> VirtualServo:
        """The (first) servo whose current ID is ``servo_id``."""
        for device in self._by_id.get(servo_id, ()):
            if isinstance(device, VirtualServo):
                return device
        raise KeyError(f"no servo with ID {servo_id} on the simulated line")

    def memory_device(self, device_id: int) -> MemoryDevice:
        for device in self._by_id.get(device_id, ()):
            if isinstance(device, MemoryDevice):
                return device
        raise KeyError(f"no memory device with ID {device_id} on the simulated line")

    def log_since(self, seq: int = 0) -> list[Transaction]:
        """A copy of the logged transactions with ``seq >= seq`` (safe while the line runs)."""
        with self._lock:
            return [t for t in self.log if t.seq >= seq]

    def power_cycle(self) -> None:
        """Power-cycle every servo on the line (RAM reloads from EEPROM)."""
        with self._lock:
            self._update_devices(self.now())
            for servo in self.servos:
                servo.power_cycle()

    # ------------------------------------------------------------------ time

    def now(self) -> float:
        """The line's clock: simulated seconds (fast) or seconds since creation (real-time)."""
        if self.realtime:
            return time.perf_counter() - self.epoch
        return self._clock

    def advance(self, seconds: float) -> None:
        """Let ``seconds`` of idle time pass (fast mode; in real-time mode just syncs)."""
        if seconds < 0:
            raise InvalidArgument("cannot go back in time")
        with self._lock:
            if not self.realtime:
                self._clock += seconds
            self._update_devices(self.now())

    def sync(self) -> None:
        """Bring every device's state up to the line's current time."""
        with self._lock:
            self._update_devices(self.now())

    def byte_time(self, baudrate: int | None = None) -> float:
        return BITS_PER_BYTE / (baudrate or self.baudrate)

    def _update_devices(self, now: float) -> None:
        for device in self.devices:
            device.update(now)

    # ------------------------------------------------------------------ the core

    def feed(self, data: bytes, now: float) -> list[tuple[float, bytes]]:
        """Host bytes written at ``now``: the chunks the host receives and when.

        Chunks come in delivery order; each time is the earliest moment the
        whole chunk may be delivered (line clock).  In fast mode a reply
        delayed by ``late_delay`` is kept inside and released by the first
        later call whose time has passed it.
        """
        with self._lock:
            return self._feed(bytes(data), now)

    def _feed(self, data: bytes, now: float) -> list[tuple[float, bytes]]:
        out: list[tuple[float, bytes]] = []
        t = max(now, self._line_free)
        while self._deferred and self._deferred[0][0] <= t:
            when, _, chunk = heapq.heappop(self._deferred)
            out.append((when, chunk))
        if self._rx and now - self._rx_time > self.frame_timeout:
            # A servo forgets a half-received command after a pause.
            self._rx.clear()
            self._rx_echoed = 0
        self._rx_time = now
        self._rx += data
        baud = self.baudrate
        ics_baud = baud in _ICS_BAUDS
        junk = bytearray()
        junk_fresh = 0
        rx = self._rx
        while rx:
            if ics_baud:
                framed = decode_request(rx, baudrate=baud)
                if framed is None:
                    break
                command, used = framed
            else:
                command, used = None, len(rx)  # no ICS device can make sense of this rate
            frame = bytes(rx[:used])
            fresh = max(0, used - self._rx_echoed)
            del rx[:used]
            self._rx_echoed = max(0, self._rx_echoed - used)
            if command is None:
                junk += frame
                junk_fresh += fresh
                continue
            if junk:
                t = self._transact(None, bytes(junk), junk_fresh, t, out)
                junk.clear()
                junk_fresh = 0
            t = self._transact(command, frame, fresh, t, out)
        if junk:
            t = self._transact(None, bytes(junk), junk_fresh, t, out)
        fresh = len(rx) - self._rx_echoed
        if fresh > 0:
            # The start of a command still in flight: its bytes echo as they go.
            t += fresh * BITS_PER_BYTE / baud
            if self.echo:
                out.append((t, bytes(rx[-fresh:])))
            self._rx_echoed = len(rx)
            self._line_free = max(self._line_free, t)
        return out

    def _transact(self, command: Any, frame: bytes, fresh: int, t: float, out: list[tuple[float, bytes]]) -> float:
        baud = self.baudrate
        byte_time = BITS_PER_BYTE / baud
        servo_id = _addressed_id(command, frame)
        draw = self.faults.draw(servo_id)
        faults: list[str] = []
        rx_parts: list[bytes] = []
        t_end = t + fresh * byte_time
        echo = frame[len(frame) - fresh :] if fresh else b""
        if draw.echo and echo:
            echo = self.faults.damage_echo(echo)
            faults.append("echo")
        if self.echo and echo:
            out.append((t_end, echo))
            rx_parts.append(echo)
        extra = b""
        for late in self._held:
            t_end += len(late) * byte_time
            out.append((t_end, late))
            rx_parts.append(late)
            extra += late
        self._held.clear()

        responders: list[Device] = []
        values: list[Any] = []
        if command is not None and not draw.echo:
            if isinstance(command, (ReadId, WriteId)):
                candidates: Iterable[Device] = self.servos
            else:
                candidates = self._by_id.get(command.servo_id, ())
            for device in candidates:
                # Devices advance lazily: only the ones a command reaches (and
                # all of them on advance() / sync()), which keeps a transaction cheap.
                device.update(t_end)
                if device.answers(baud):
                    value = device.handle(command)
                    if value is not NO_REPLY:
                        responders.append(device)
                        values.append(value)
            if isinstance(command, (WriteId, WriteEeprom)) and responders:
                self._reindex()
        replies = [command.encode_reply(v) for v in values]
        clean = b"" if not replies else replies[0] if len(replies) == 1 else garble(replies)
        value_answered = values[0] if len(values) == 1 else None

        reply = clean
        reply_time: float | None = None
        line_free = t_end
        if clean:
            start = t_end + self.turnaround
            if isinstance(command, WriteEeprom):
                start += self.eeprom_write_delay
            kind = draw.reply
            if kind is not None:
                faults.append(kind)
            if kind == "drop":
                reply = b""
            elif kind == "late":
                if self.late_delay is None:
                    self._held.append(clean)  # lands after the echo of the next command
                else:
                    reply_time = start + len(clean) * byte_time + self.late_delay
                    self._defer_or_emit(reply_time, clean, out)
            else:
                if kind is not None:
                    reply = self.faults.damage_reply(kind, clean)
                if reply:
                    reply_time = line_free = start + len(reply) * byte_time
                    out.append((reply_time, reply))
                    rx_parts.append(reply)
        if draw.noise:
            noise = self.faults.noise()
            gap = self.faults.uniform(0.0, self.noise_gap) if self.realtime else 0.0
            out.append((line_free + gap + len(noise) * byte_time, noise))
            rx_parts.append(noise)
            extra += noise
            faults.append("noise")
        if draw.unplug:
            self._unplug_requested = True
            faults.append("unplug")
        self._line_free = line_free
        self.fault_counts.update(faults)

        seq = self.transactions
        self.transactions = seq + 1
        if self._log_enabled or self._recorder is not None:
            record = Transaction(
                seq=seq,
                time=t_end,
                servo_id=servo_id,
                command="unknown" if command is None else command.name,
                tx=frame,
                echo=echo if self.echo else b"",
                reply=reply,
                clean_reply=clean,
                value=value_answered,
                responders=tuple(d.servo_id for d in responders),
                fault="+".join(faults) or None,
                extra=extra,
                reply_time=reply_time,
            )
            if self._log_enabled:
                self.log.append(record)
            if self._recorder is not None:
                self._recorder.record(record, rx_parts, baud)
        return line_free

    def _defer_or_emit(self, when: float, chunk: bytes, out: list[tuple[float, bytes]]) -> None:
        if self.realtime:
            out.append((when, chunk))
        else:
            self._deferred_order += 1
            heapq.heappush(self._deferred, (when, self._deferred_order, chunk))

    def process(self, data: bytes) -> list[tuple[float, bytes]]:
        """:meth:`feed` at the line's own clock (fast mode: then advance it)."""
        with self._lock:
            out = self._feed(bytes(data), self.now())
            if not self.realtime:
                self._clock = max(self._clock, self._line_free)
            return out

    def take_unplug_request(self) -> bool:
        """True once after a transaction drew the ``unplug`` fault."""
        with self._lock:
            requested, self._unplug_requested = self._unplug_requested, False
            return requested

    # ------------------------------------------------------------------ the WireDevice face

    def connect(self, host: HostSide, baudrate: int) -> None:
        with self._lock:
            if not self.plugged:
                raise OSError(errno.ENOENT, "the simulated port is unplugged")
            if self._host is not None:
                raise OSError(errno.EBUSY, "the simulated port is already open")
            self._host = host
            if self.follow_host_baud:
                self.baudrate = int(baudrate)
            if self.realtime and self._deliverer is None:
                self._deliverer = Deliverer(self.spin_margin)
            if self.unplug_after is not None and not self._unplug_scheduled:
                self._unplug_scheduled = True
                self.schedule_unplug(self.unplug_after, self.replug_after)

    def write(self, data: bytes) -> None:
        host = self._host
        if host is None:
            raise OSError(errno.EIO, "the simulated port is not open" if self.plugged else "the simulated port is gone")
        chunks = self.process(data)
        if self.realtime:
            deliverer = self._deliverer
            if deliverer is None:
                return  # unplugged or disconnected meanwhile: the bytes are lost
            for when, chunk in chunks:
                deliverer.schedule(self.epoch + when, chunk, host.deliver)
            if self.take_unplug_request():
                when = self.epoch + self._line_free
                deliverer.schedule(when, b"", lambda _: self.unplug(replug_after=self.replug_after))
        else:
            if chunks:
                host.deliver(b"".join(chunk for _, chunk in chunks))
            if self.take_unplug_request():
                self.unplug(replug_after=self.replug_after)

    def disconnect(self) -> None:
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

        With ``replug_after`` (wall-clock seconds) the port comes back by itself.
        """
        with self._lock:
            if not self.plugged:
                return
            self.plugged = False
            self.unplug_count += 1
            host, self._host = self._host, None
            self._held.clear()
            self._deferred.clear()
            self._rx.clear()
            self._rx_echoed = 0
        self._stop_deliverer()
        if replug_after is not None:
            self._start_timer(replug_after, self.replug)
        if host is not None:
            host.lost(exc or OSError(errno.ENODEV, "the simulated port was unplugged"))
        for callback in list(self._listeners):
            callback(False)

    def replug(self) -> None:
        with self._lock:
            if self.plugged:
                return
            self.plugged = True
        for callback in list(self._listeners):
            callback(True)

    def schedule_unplug(self, after: float, replug_after: float | None = None) -> None:
        """Unplug ``after`` wall-clock seconds from now, replug ``replug_after`` later."""

        def fire() -> None:
            self.unplug()
            if replug_after is not None:
                self._start_timer(replug_after, self.replug)

        self._start_timer(after, fire)

    def _start_timer(self, delay: float, action: Callable[[], None]) -> None:
        timer = threading.Timer(delay, action)
        timer.daemon = True
        with self._lock:
            self._timers = [t for t in self._timers if t.is_alive()]
            self._timers.append(timer)
        timer.start()

    # ------------------------------------------------------------------ recording, lifetime

    def record_to(self, target: Any) -> TransactionRecorder:
        """Record every following transaction to ``target`` (path or text stream)."""
        recorder = target if isinstance(target, TransactionRecorder) else TransactionRecorder(target)
        with self._lock:
            self._recorder = recorder
        return recorder

    def stop_recording(self) -> None:
        with self._lock:
            recorder, self._recorder = self._recorder, None
        if recorder is not None:
            recorder.close()

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
        return f"<VirtualLine {len(self.devices)} devices @{self.baudrate} {mode} txns={self.transactions}>"


def _addressed_id(command: Any, frame: bytes) -> int | None:
    if command is not None:
        return command.servo_id  # type: ignore[no-any-return]
    return frame[0] & 0x1F if frame[0] & 0x80 else None


_ICS_BAUDS = frozenset(int(b) for b in BaudRate)
_NAMED: dict[str, VirtualLine] = {}


def named(name: str) -> VirtualLine:
    """The line registered under ``name`` (``VirtualLine(name=...)`` or ``sim://NAME``)."""
    return _NAMED[name]
