"""The wire model of a simulated line: host bytes and their time in, what the host receives and when out.

:class:`LineModel` is sans-IO: :meth:`LineModel.feed` takes the host's bytes
and the time they were written, frames them with the library's codec, lets
the devices answer (:mod:`.devices`), injects faults (:mod:`.faults`), logs
and records each transaction, and returns the chunks the host receives
(echo, replies, noise) with the earliest time each may be delivered.  The
drivers on top, :class:`~.virtual_line.VirtualLine` (in process) and the pty server,
only deliver those chunks.

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

import heapq
import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Iterable
from typing import Any, TypedDict, Unpack

from ..eeprom import BaudRate
from ..errors import InvalidArgument
from ..protocol import BITS_PER_BYTE, WriteEeprom
from ..transports.usb_timing import Chunks, FtdiAdapter
from ..units import finite_number, said, shown, unknown_options
from .devices import NO_ANSWER, DeviceTable, MemorySpec, build_devices
from .faults import FaultConfig, FaultInjector
from .framing import CommandFramer
from .record import TransactionRecorder
from .transaction import Transaction
from .virtual_servo import VirtualServo

DEFAULT_TURNAROUND = 100e-6
"""Seconds a servo waits after a command before answering.  An assumption:
the reference gives no figure; 100 us is a round value in the range hobby
servo firmware achieves, and is easy to change (``turnaround=``)."""
DEFAULT_EEPROM_WRITE_DELAY = 20e-3
"""Extra seconds before the EEPROM-write reply ("noticeably longer" in the
reference; 20 ms is an assumption that keeps real-time tests quick)."""
DEFAULT_LOG_SIZE = 10_000
DEFAULT_FRAME_TIMEOUT = 10e-3
DEFAULT_NOISE_GAP = 1e-3
DEFAULT_TAIL_BYTES = 4
DEFAULT_TAIL_DELAY = 40e-3
"""The held-tail fault's defaults: what ser2net with Nagle's algorithm did to a
68-byte EEPROM answer (64 bytes, then 4 about 40 ms later: a delayed ACK)."""
LONGEST_DELAY = threading.TIMEOUT_MAX
"""The longest a simulated delay may be, in seconds: what a timer thread can wait (an unplugged port's replug, a
reply's delivery; about 292 years on Linux, 49 days on Windows).  Longer, or ``inf``, that thread would die with an
``OverflowError`` as it started waiting."""


def check_delay(what: str, value: object) -> float:
    """``value`` as a simulated delay in seconds: a finite number, not negative, at most :data:`LONGEST_DELAY`.

    Raises:
        InvalidArgument: it is not, naming ``what``.
    """
    number = finite_number(value)
    if number is None:
        raise InvalidArgument(f"{what} must be a finite number of seconds, not {said(value)}")
    if number < 0:
        raise InvalidArgument(f"{what} must not be negative")
    if number > LONGEST_DELAY:
        raise InvalidArgument(
            f"{what} must be at most {LONGEST_DELAY:g} seconds (what a timer can wait), got {shown(number)}"
        )
    return number


class LineModelOptions(TypedDict, total=False):
    """The options of a simulated line's wire and devices, every one optional:
    [`LineModel`][ics35_async.sim.LineModel] and [`VirtualLine`][ics35_async.sim.VirtualLine] take them
    as keyword arguments after ``servos``."""

    baudrate: int
    """The line's rate in bit/s (default 115200; a driver may change it to the host's) and the EEPROM
    rate of servos built from IDs."""
    memory: MemorySpec | None
    """Generic memory devices: ``{id: initial bytes}`` or [`MemoryDevice`][ics35_async.sim.MemoryDevice]
    objects (default none)."""
    realtime: bool
    """The clock is ``time.perf_counter()`` (default ``False``: simulated, advancing only with wire time
    and [`advance`][ics35_async.sim.LineModel.advance])."""
    echo: bool
    """The line loops the host's bytes back, as Kondo's adapters do (default ``True``)."""
    turnaround: float
    """Seconds a servo waits after a command before answering (default
    [`DEFAULT_TURNAROUND`][ics35_async.sim.DEFAULT_TURNAROUND])."""
    eeprom_write_delay: float
    """Extra seconds before the EEPROM-write reply (default
    [`DEFAULT_EEPROM_WRITE_DELAY`][ics35_async.sim.DEFAULT_EEPROM_WRITE_DELAY])."""
    faults: FaultConfig | str | None
    """A [`FaultConfig`][ics35_async.sim.FaultConfig] or a spec string such as ``"drop:0.01,late@3:0.1"``
    (default none; see ``ics35_async.sim.faults``)."""
    seed: int | None
    """The seed of the faults' ``random.Random`` (default 0; ``None``: a fresh one each run)."""
    late_delay: float | None
    """Seconds a ``late`` reply comes after its due time (default ``None``: after the echo of the next command)."""
    tail_bytes: int
    """Bytes the held-tail fault holds back (default 4)."""
    tail_delay: float
    """Seconds the held tail comes after the rest of the reply (default 0.040)."""
    noise_gap: float
    """In real time, the most seconds between a reply and the noise fault's bytes (default 0.001)."""
    log_size: int | None
    """The most transactions kept in the log (default 10 000; ``None``: unbounded, 0: no log;
    ``transactions`` counts regardless)."""
    frame_timeout: float
    """A half-received command is forgotten after this pause in seconds (default 0.010)."""
    record: Any
    """A file path or text stream to record the session to (default none; see ``ics35_async.sim.record``)."""
    adapter: FtdiAdapter | None
    """A USB adapter model between line and host (default ``None``: a bare UART; see
    ``ics35_async.sim.adapter``)."""
    ics36: Iterable[int]
    """The IDs of servos built from IDs that speak ICS 3.6 (default none: all ICS 3.5; an ID no servo is built from
    is refused)."""
    noisy: Iterable[int]
    """The IDs of servos built from IDs whose reported position jumps at each reply, no two readings in a row
    agreeing (a broken potentiometer; default none; an ID no servo is built from is refused)."""


class LineModel:
    """The devices of one line and the timing of everything on its wire.

    Its keyword options (the wire's and the devices') are those of
    [`LineModelOptions`][ics35_async.sim.LineModelOptions], each described there.

    Args:
        servos: [`VirtualServo`][ics35_async.sim.VirtualServo] objects or IDs (factory servos at
            ``baudrate``); ``None`` means IDs 0..31.

    Raises:
        InvalidArgument: an unknown option, a delay that is negative, not finite or longer than a timer can
            wait (``check_delay``), a bad baud rate, ID or fault spec.
    """

    def __init__(self, servos: Iterable[VirtualServo | int] | None = None, **options: Unpack[LineModelOptions]) -> None:
        unknown = set(options) - LineModelOptions.__optional_keys__
        if unknown:
            raise InvalidArgument(unknown_options("simulated line", unknown, LineModelOptions.__optional_keys__))
        line_baud = BaudRate.parse(options.get("baudrate", BaudRate.B115200))
        turnaround = options.get("turnaround", DEFAULT_TURNAROUND)
        eeprom_write_delay = options.get("eeprom_write_delay", DEFAULT_EEPROM_WRITE_DELAY)
        tail_delay = options.get("tail_delay", DEFAULT_TAIL_DELAY)
        tail_bytes = options.get("tail_bytes", DEFAULT_TAIL_BYTES)
        turnaround = check_delay("turnaround", turnaround)
        eeprom_write_delay = check_delay("eeprom_write_delay", eeprom_write_delay)
        tail_delay = check_delay("tail_delay", tail_delay)
        late_delay = options.get("late_delay")
        if late_delay is not None:
            late_delay = check_delay("late_delay", late_delay)
        if isinstance(tail_bytes, bool) or not isinstance(tail_bytes, int) or tail_bytes < 1:
            raise InvalidArgument(f"tail_bytes must be a whole number of bytes >= 1, got {tail_bytes!r}")
        memory, ics36 = options.get("memory"), options.get("ics36", ())
        self.table = DeviceTable(build_devices(servos, memory, line_baud, ics36, options.get("noisy", ())))
        self.baudrate: int = int(line_baud)
        self.realtime = options.get("realtime", False)
        self.echo = options.get("echo", True)
        self.turnaround = turnaround
        self.eeprom_write_delay = eeprom_write_delay
        self.late_delay = late_delay
        self.tail_bytes = tail_bytes
        self.tail_delay = tail_delay
        self.noise_gap = options.get("noise_gap", DEFAULT_NOISE_GAP)
        self.adapter = options.get("adapter")
        faults = options.get("faults")
        config = faults if isinstance(faults, FaultConfig) else FaultConfig.parse(faults)
        self.faults = FaultInjector(config, options.get("seed", 0))
        log_size = options.get("log_size", DEFAULT_LOG_SIZE)
        if log_size is not None and (isinstance(log_size, bool) or not isinstance(log_size, int) or log_size < 0):
            # (the deque's own refusal, "maxlen must be non-negative", named neither the option nor what it takes)
            raise InvalidArgument(
                f"log_size must be a whole number of transactions >= 0 (0: no log; None: every one), got {log_size!r}"
            )
        self.log: deque[Transaction] = deque(maxlen=log_size)
        self._log_enabled = log_size != 0
        self.transactions = 0
        self.fault_counts: Counter[str] = Counter()

        self._lock = threading.RLock()
        self.epoch = time.perf_counter()
        self._clock = 0.0
        self._line_free = 0.0
        self._framer = CommandFramer(options.get("frame_timeout", DEFAULT_FRAME_TIMEOUT))
        self._held: list[bytes] = []
        self._deferred: list[tuple[float, int, bytes]] = []
        self._deferred_order = 0
        # The held tail (see :mod:`.faults`).  Real time: nothing reaches the host before
        # _hold_until.  Fast mode: tails wait in _tails for the host's next write; once
        # delivered they are _carried into that transaction's record.
        self._hold_until = 0.0
        self._tails: list[tuple[float, bytes]] = []
        self._carried = bytearray()
        self._unplug_requested = False
        self._recorder: TransactionRecorder | None = None
        self._taps: list[Callable[[bytes], None]] = []
        if options.get("record") is not None:
            self.record_to(options["record"])

    # ------------------------------------------------------------------ the log

    def log_since(self, seq: int = 0) -> list[Transaction]:
        """A copy of the logged transactions with ``seq >= seq`` (safe while the line runs)."""
        with self._lock:
            return [t for t in self.log if t.seq >= seq]

    # ------------------------------------------------------------------ time

    def now(self) -> float:
        """The line's clock: simulated seconds (fast) or seconds since creation (real-time)."""
        if self.realtime:
            return time.perf_counter() - self.epoch
        return self._clock

    @property
    def line_free(self) -> float:
        """When (line clock) the wire is idle again after what has been fed so far."""
        return self._line_free

    def advance(self, seconds: float) -> None:
        """Let ``seconds`` of idle time pass (fast mode; in real-time mode just syncs).

        Raises:
            InvalidArgument: ``seconds`` is negative.
        """
        if seconds < 0:
            raise InvalidArgument("cannot go back in time")
        with self._lock:
            if not self.realtime:
                self._clock += seconds
            self.table.update(self.now())

    def sync(self) -> None:
        """Bring every device's state up to the line's current time."""
        with self._lock:
            self.table.update(self.now())

    def byte_time(self, baudrate: int | None = None) -> float:
        """Seconds one byte occupies the wire at ``baudrate`` (default: the line's)."""
        return BITS_PER_BYTE / (baudrate or self.baudrate)

    # ------------------------------------------------------------------ the core

    def feed(self, data: bytes, now: float) -> Chunks:
        """Host bytes ``data`` written at ``now``: the chunks the host receives and when.

        Chunks come in delivery order; each time is the earliest moment the
        whole chunk may be delivered (line clock).  In fast mode a reply
        delayed by ``late_delay`` is kept inside and released by the first
        later call whose time has passed it, and a held tail by the next call.
        Behind an ``adapter`` the bytes reach the wire, and the host, when it lets them.
        """
        with self._lock:
            adapter = self.adapter
            out = self._feed(bytes(data), now if adapter is None else adapter.outbound(now))
            return out if adapter is None or not out else adapter.inbound(out, self.byte_time())

    def _feed(self, data: bytes, now: float) -> Chunks:
        out: Chunks = []
        t = max(now, self._line_free)
        for when, tail in self._tails:
            out.append((when, tail))
            self._carried += tail
        self._tails.clear()
        while self._deferred and self._deferred[0][0] <= t:
            when, _, chunk = heapq.heappop(self._deferred)
            self._emit(out, when, chunk)
        baud = self.baudrate
        frames, in_flight = self._framer.feed(data, now, baud)
        for command, frame, fresh in frames:
            t = self._transact(command, frame, fresh, t, out)
        if in_flight:
            # The start of a command still in flight: its bytes echo as they go.
            t += len(in_flight) * BITS_PER_BYTE / baud
            self._hear(in_flight)
            if self.echo:
                self._emit(out, t, in_flight)
            self._line_free = max(self._line_free, t)
        return out

    def _transact(self, command: Any, frame: bytes, fresh: int, t: float, out: Chunks) -> float:
        baud = self.baudrate
        byte_time = BITS_PER_BYTE / baud
        servo_id = _addressed_id(command, frame)
        draw = self.faults.draw(servo_id)
        faults: list[str] = []
        rx_parts: list[bytes] = []
        extra = b""
        if self._carried:  # a held tail delivered just before this command's echo
            extra = bytes(self._carried)
            rx_parts.append(extra)
            self._carried.clear()
        t_end = t + fresh * byte_time
        echo = frame[len(frame) - fresh :] if fresh else b""
        if draw.echo and echo:
            echo = self.faults.damage_echo(echo)
            faults.append("echo")
        heard = bytearray(echo)  # what a listener on the wire hears, each byte once
        if self.echo and echo:
            self._emit(out, t_end, echo)
            rx_parts.append(echo)
        for late in self._held:
            heard += late
            t_end += len(late) * byte_time
            self._emit(out, t_end, late)
            rx_parts.append(late)
            extra += late
        self._held.clear()

        answer = NO_ANSWER
        if command is not None and not draw.echo:  # a collision garbles the command: nobody hears it
            answer = self.table.dispatch(command, t_end, baud)
        clean = answer.reply

        reply = clean
        reply_time: float | None = None
        line_free = t_end
        if clean:
            start = t_end + self.turnaround
            if isinstance(command, WriteEeprom):
                start += self.eeprom_write_delay
            kind = draw.reply
            if kind == "tail" and len(clean) <= self.tail_bytes:
                kind = None  # all of it fits in the tail: a lone small segment is not held
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
                    heard += clean
            elif kind == "tail":
                head, tail = clean[: -self.tail_bytes], clean[-self.tail_bytes :]
                heard += clean
                self._emit(out, start + len(head) * byte_time, head)
                rx_parts.append(head)
                line_free = start + len(clean) * byte_time
                reply_time = line_free + self.tail_delay
                if self.realtime:
                    self._emit(out, reply_time, tail)
                    rx_parts.append(tail)
                    self._hold_until = reply_time  # what follows queues behind it, as in a TCP stream
                else:
                    self._tails.append((reply_time, tail))
            else:
                if kind is not None:
                    reply = self.faults.damage_reply(kind, clean)
                if reply:
                    reply_time = line_free = start + len(reply) * byte_time
                    self._emit(out, reply_time, reply)
                    rx_parts.append(reply)
                    heard += reply
        if draw.noise:
            noise = self.faults.noise()
            gap = self.faults.uniform(0.0, self.noise_gap) if self.realtime else 0.0
            self._emit(out, line_free + gap + len(noise) * byte_time, noise)
            rx_parts.append(noise)
            heard += noise
            extra += noise
            faults.append("noise")
        if draw.unplug:
            self._unplug_requested = True
            faults.append("unplug")
        self._line_free = line_free
        self.fault_counts.update(faults)
        self._hear(bytes(heard))

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
                value=answer.value,
                responders=tuple(d.servo_id for d in answer.responders),
                fault="+".join(faults) or None,
                extra=extra,
                reply_time=reply_time,
            )
            if self._log_enabled:
                self.log.append(record)
            if self._recorder is not None:
                self._recorder.record(record, rx_parts, baud)
        return line_free

    def add_tap(self, listener: Callable[[bytes], None]) -> None:
        """Call ``listener(bytes)``, under the lock, with every byte on the wire once (no echo; :mod:`.tap`)."""
        with self._lock:
            self._taps.append(listener)

    def _hear(self, data: bytes) -> None:
        for listener in self._taps if data else ():
            listener(data)

    def _emit(self, out: Chunks, when: float, chunk: bytes) -> None:
        out.append((max(when, self._hold_until), chunk))

    def _defer_or_emit(self, when: float, chunk: bytes, out: Chunks) -> None:
        if self.realtime:
            self._emit(out, when, chunk)
        else:
            self._deferred_order += 1
            heapq.heappush(self._deferred, (when, self._deferred_order, chunk))

    def process(self, data: bytes) -> Chunks:
        """:meth:`feed` ``data`` at the line's own clock (fast mode: then advance it)."""
        with self._lock:
            out = self.feed(data, self.now())
            if not self.realtime:  # behind an adapter, the host has the bytes only when its packet comes
                self._clock = max(self._clock, self._line_free, out[-1][0] if self.adapter is not None and out else 0.0)
            return out

    def take_unplug_request(self) -> bool:
        """True once after a transaction drew the ``unplug`` fault."""
        with self._lock:
            requested, self._unplug_requested = self._unplug_requested, False
            return requested

    def reset_wire(self) -> None:
        """Forget everything in flight (the port went away): partial commands, held and delayed replies."""
        with self._lock:
            self._held.clear()
            self._deferred.clear()
            self._tails.clear()
            self._carried.clear()
            self._framer.reset()

    # ------------------------------------------------------------------ recording

    def record_to(self, target: Any) -> TransactionRecorder:
        """Record every following transaction to ``target`` (path, text stream or recorder)."""
        recorder = target if isinstance(target, TransactionRecorder) else TransactionRecorder(target)
        with self._lock:
            self._recorder = recorder
        return recorder

    def stop_recording(self) -> None:
        """Stop recording and close the recording (see :meth:`record_to`)."""
        with self._lock:
            recorder, self._recorder = self._recorder, None
        if recorder is not None:
            recorder.close()


def _addressed_id(command: Any, frame: bytes) -> int | None:
    if command is not None:
        return command.servo_id  # type: ignore[no-any-return]
    return frame[0] & 0x1F if frame[0] & 0x80 else None
