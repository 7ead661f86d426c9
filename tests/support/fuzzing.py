"""Fuzzed transactions: byte streams turned into a command and the (mostly broken) bytes answering it.

:func:`fuzz_case` builds a case from a hypothesis-drawn blob,
:func:`fuzz_parsers` runs every reply parser on it, :class:`FuzzDevice` is a
WireDevice double that answers with the scripted bytes, and
:class:`FuzzRig` runs buses on such doubles side by side, judging each
conclusion with the :class:`~tests.support.oracle.WirePredictor`.
"""

from __future__ import annotations

import asyncio
import functools
from collections import Counter, deque
from collections.abc import Awaitable, Sequence
from dataclasses import dataclass, field
from typing import Any

from ics35_async import (
    Bus,
    Eeprom,
    IcsError,
    ReplyError,
    open_bus,
    protocol,
)
from ics35_async.protocol import Command, Param, decode_request

from .oracle import GUARD_TXS, WirePredictor

BAUDS = (115200, 625000, 1250000)


@dataclass(frozen=True, slots=True)
class FuzzCase:
    """One fuzzed transaction: the command the host sends and the bytes the "device" answers."""

    command: Command[Any]
    echo: bytes  # what comes back in place of the echo (the real echo, damaged, or nothing)
    reply: bytes  # what follows it

    @property
    def received(self) -> bytes:
        return self.echo + self.reply


def _command_from(blob: bytes, baudrate: int) -> Command[Any]:
    kind, sid, arg = blob[0] % 10, blob[1] % 32, blob[2]
    extra = blob[5] if len(blob) > 5 else 0
    if kind == 0:
        return protocol.Position(sid, (arg << 6 | extra) % (protocol.POSITION_MAX + 1), baudrate=baudrate)
    if kind == 1:
        return protocol.Position(sid, protocol.FREE, baudrate=baudrate)
    if kind == 2:
        return protocol.ReadParam(sid, 1 + arg % 4)
    if kind == 3:
        param = Param(1 + arg % 4)
        low, high = protocol.WRITE_RANGES[param]
        return protocol.WriteParam(sid, param, low + extra % (high - low + 1))
    if kind == 4:
        return protocol.ReadEeprom(sid)
    if kind == 5:
        return protocol.WriteEeprom(sid, Eeprom.factory(sid))
    if kind == 6:
        address = arg % protocol.MEMORY_SIZE
        return protocol.ReadMemory(sid, address, 1 + extra % min(16, protocol.MEMORY_SIZE - address))
    if kind == 7:
        address = arg % (protocol.MEMORY_SIZE - 1)
        return protocol.WriteMemory(sid, address, bytes(range(1 + extra % min(8, protocol.MEMORY_SIZE - address))))
    if kind == 8:
        return protocol.ReadId(sid)
    return protocol.WriteId(sid)


def valid_value(command: Command[Any], payload: bytes) -> Any:
    p = payload + bytes(8)
    if isinstance(command, protocol.Position):
        return (p[0] << 7 | p[1]) & protocol.POSITION_MAX
    if isinstance(command, protocol.ReadParam):
        return p[0] & 0x7F
    if isinstance(command, protocol.WriteParam):
        return command.value
    if isinstance(command, protocol.ReadEeprom):
        image = Eeprom.factory(command.servo_id or 0)
        return image.replace(speed=1 + p[0] % 127, punch=p[1] % 11)
    if isinstance(command, protocol.ReadMemory):
        return (payload * command.count)[: command.count] if payload else bytes(command.count)
    if isinstance(command, (protocol.ReadId, protocol.WriteId)):
        return command.new_id if isinstance(command, protocol.WriteId) else p[0] % 32
    return None


def healthy_answer(data: bytes, baudrate: int, payload: bytes | None = None) -> bytes:
    """A healthy servo's reply to the command ``data`` (its value from ``payload``, default: the ID, then 5)."""
    framed = decode_request(data, baudrate=baudrate)
    assert framed is not None and framed[0] is not None
    command = framed[0]
    return command.encode_reply(valid_value(command, bytes([command.servo_id or 0, 5]) if payload is None else payload))


def fuzz_case(blob: bytes, baudrate: int) -> FuzzCase:
    """Turn a hypothesis-drawn blob into a command and the (mostly broken) bytes answering it.

    Byte 0: command kind; 1: ID; 2 and 5: arguments; 3: what happens to the
    echo; 4: what the reply is; the rest: bytes for values and damage.
    """
    blob = blob.ljust(6, b"\0")
    command = _command_from(blob, baudrate)
    tx = command.tx
    payload = blob[6:]
    pick = payload[0] if payload else 0
    echo_style, reply_style = blob[3] % 16, blob[4] % 10
    # The echo: usually intact, else missing, damaged, short or long.
    if echo_style < 10:
        echo = tx
    elif echo_style == 10:
        echo = b""
    elif echo_style == 11:
        i = pick % len(tx)
        echo = tx[:i] + bytes([tx[i] ^ (1 + (blob[2] % 255))]) + tx[i + 1 :]
    elif echo_style == 12:
        echo = tx[: pick % len(tx)]
    elif echo_style == 13:
        echo = tx + payload[:1]
    elif echo_style == 14:
        echo = bytes(reversed(tx))
    else:
        echo = payload[: len(tx)]
    clean = command.encode_reply(valid_value(command, payload))
    if reply_style < 3:
        reply = clean
    elif reply_style == 3:  # one byte changed
        i = pick % len(clean)
        reply = clean[:i] + bytes([clean[i] ^ (1 + blob[5] % 255)]) + clean[i + 1 :]
    elif reply_style == 4:  # cut short
        reply = clean[: pick % len(clean)]
    elif reply_style == 5:  # trailing bytes
        reply = clean + payload[: 1 + pick % 4]
    elif reply_style == 6:  # random bytes of the right length
        reply = (payload * len(clean))[: len(clean)] if payload else bytes(len(clean))
    elif reply_style == 7:  # random bytes of any length
        reply = payload
    elif reply_style == 8:  # a valid reply of another command or another ID
        other = _command_from(bytes([(blob[0] + 1 + pick % 9) % 256, (blob[1] + pick % 2) % 256, *blob[2:]]), baudrate)
        reply = other.encode_reply(valid_value(other, payload))
    else:  # an MSB set somewhere
        i = pick % len(clean)
        reply = clean[:i] + bytes([clean[i] | 0x80]) + clean[i + 1 :]
    return FuzzCase(command, echo, reply)


class FuzzDevice:
    """A WireDevice double that answers each command with the scripted (fuzzed) bytes, or cleanly.

    ``script`` holds the next answers; ``clean=True`` makes it a healthy
    device that echoes and answers every command correctly.
    """

    def __init__(self, echo: bool = True) -> None:
        self.host: Any = None
        self.echo = echo
        self.baudrate = 115200
        self.script: deque[FuzzCase] = deque()
        self.clean = False
        self.writes = 0
        self.guards = 0
        self.mismatched_writes = 0

    def connect(self, host: Any, baudrate: int) -> None:
        self.host, self.baudrate = host, baudrate

    def disconnect(self) -> None:
        self.host = None

    def write(self, data: bytes) -> None:
        self.writes += 1
        if self.clean:
            out = (data if self.echo else b"") + healthy_answer(data, self.baudrate)
        elif data in GUARD_TXS and not (self.script and self.script[0].command.tx == data):
            # The engine's guard read after a timeout (see engine.guard): a healthy answer, no script used.
            self.guards += 1
            out = (data if self.echo else b"") + healthy_answer(data, self.baudrate, b"\x05")
        elif not self.script:
            # Nothing scripted: the bus wrote a command nobody submitted.  Counted (the health
            # check reports it) and left unanswered, like a servo that is not there.
            self.mismatched_writes += 1
            out = b""
        else:
            case = self.script.popleft()
            if case.command.tx != data:
                self.mismatched_writes += 1
            out = (case.echo if self.echo else b"") + case.reply
        if out and self.host is not None:
            self.host.deliver(out)


@dataclass
class FuzzCounts:
    streams: int = 0
    parses: int = 0
    parse_values: int = 0
    untyped: int = 0
    fast_path_disagrees: int = 0
    decode_problems: int = 0
    bus_transactions: int = 0
    bus_values: int = 0
    bus_errors: Counter[str] = field(default_factory=Counter)
    bus_wrong: int = 0  # value where the bytes call for an error, wrong value, or another error class
    bus_untyped: int = 0
    finished: int = 0  # bus requests that have ended, either way (the soak's watchdog reads it)
    examples: list[str] = field(default_factory=list)

    def note(self, text: str) -> None:
        if len(self.examples) < 10:
            self.examples.append(text)


@functools.lru_cache(maxsize=128)
def _parsers(sid: int, baudrate: int) -> tuple[Command[Any], ...]:
    return (
        protocol.Position(sid, 7500, baudrate=baudrate),
        protocol.Position(0, protocol.FREE, baudrate=baudrate),
        protocol.ReadParam(sid, Param.STRETCH),
        protocol.ReadParam(sid, Param.TEMPERATURE),
        protocol.WriteParam(sid, Param.SPEED, 100),
        protocol.ReadEeprom(sid),
        protocol.WriteEeprom(sid, Eeprom.factory(sid)),
        protocol.ReadMemory(sid, 3, 2),
        protocol.WriteMemory(sid, 0, b"\x01"),
        protocol.ReadId(),
        protocol.WriteId(sid),
    )


def fuzz_parsers(case: FuzzCase, baudrate: int, counts: FuzzCounts) -> None:
    """Every reply parser on the fuzzed bytes: a value or a ReplyError, nothing else."""
    sid = case.command.servo_id or 0
    parsers = _parsers(sid, baudrate)
    for parser in (*parsers, case.command):
        counts.parses += 1
        try:
            parser.parse(case.reply)
            counts.parse_values += 1
        except ReplyError:
            pass
        except Exception as exc:
            counts.untyped += 1
            counts.note(f"{parser!r}.parse({case.reply.hex(' ')}) raised {exc!r}")
    if len(case.reply) == 3:
        # The stream's hot path must agree with the codec on every 3-byte reply.
        position = parsers[0]
        assert isinstance(position, protocol.Position)
        fast = protocol.position_from_reply(case.reply, 0, position.reply_header)
        try:
            slow = position.parse(case.reply)
        except ReplyError:
            slow = -1
        if fast != slow:
            counts.fast_path_disagrees += 1
            counts.note(f"position reply {case.reply.hex(' ')}: fast path {fast}, codec {slow}")
    # The device side's framing: consumes at least one byte, and a command it finds
    # re-encodes to exactly the bytes it consumed.
    for data in (case.reply, case.received):
        try:
            framed = decode_request(data, baudrate=baudrate)
        except Exception as exc:
            counts.untyped += 1
            counts.note(f"decode_request({data.hex(' ')}) raised {exc!r}")
            continue
        if framed is not None:
            command, used = framed
            if not 1 <= used <= len(data) or (command is not None and command.tx != data[:used]):
                counts.decode_problems += 1
                counts.note(f"decode_request({data.hex(' ')}) -> {command!r}, {used}")


class FuzzRig:
    """Buses on :class:`FuzzDevice` doubles (every ICS rate, echo on and off), run side by side."""

    def __init__(self, lines: int = 48) -> None:
        self.devices = [FuzzDevice(echo=k % 8 != 7) for k in range(lines)]
        self.bauds = [BAUDS[k % 3] for k in range(lines)]
        self.buses: list[Bus] = []
        self.predictors = [WirePredictor(b, d.echo) for b, d in zip(self.bauds, self.devices, strict=True)]
        self.counts = FuzzCounts()

    async def open(self) -> None:
        for device, baud in zip(self.devices, self.bauds, strict=True):
            bus = await open_bus(
                device,
                baudrate=baud,
                echo=device.echo,
                adapter_latency=0.0005,
                turnaround=0.0,
                quiet_time=0.0,
                eeprom_write=0.0005,
                id_command=0.0005,
                # The double answers at once, so no reply is ever late; but its fuzzed bytes often
                # look exactly like a late reply landing in front of the next echo, and the link
                # would learn a lateness that compounds (each judged "late" reply is measured from
                # an earlier deadline, so it includes the extra already waited) up to the default
                # bound, a quarter of a second added to every timeout: the soak then ran ten times
                # slower and looked hung.  Learning still runs, within a bound that suits this line.
                link_extra_max=0.002,
            )
            self.buses.append(bus)

    async def close(self) -> None:
        for bus in self.buses:
            await bus.aclose()

    async def _line(self, k: int, blobs: Sequence[bytes]) -> None:
        bus, device, predictor, counts = self.buses[k], self.devices[k], self.predictors[k], self.counts
        for blob in blobs:
            case = fuzz_case(blob, bus.baudrate)
            counts.streams += 1
            fuzz_parsers(case, bus.baudrate, counts)
            verdict = predictor.judge(case.command.tx, case.received if device.echo else case.reply)
            device.script.append(case)
            counts.bus_transactions += 1
            try:
                value = await bus.request(case.command, retries=0)
            except IcsError as exc:
                counts.finished += 1
                name = type(exc).__name__
                counts.bus_errors[name] += 1
                if verdict.ok or verdict.error != name:
                    counts.bus_wrong += 1
                    counts.note(
                        f"{case.command!r} got {case.received.hex(' ')}: bus {name}, bytes call for "
                        f"{verdict.value if verdict.ok else verdict.error}"
                    )
            except Exception as exc:
                counts.finished += 1
                counts.bus_untyped += 1
                counts.note(f"{case.command!r} got {case.received.hex(' ')}: bus raised {exc!r}")
            else:
                counts.finished += 1
                counts.bus_values += 1
                if not verdict.ok or verdict.value != value:
                    counts.bus_wrong += 1
                    counts.note(
                        f"{case.command!r} got {case.received.hex(' ')}: bus value {value!r}, bytes call "
                        f"for {verdict.value if verdict.ok else verdict.error}"
                    )

    async def run(self, blobs: Sequence[bytes]) -> None:
        n = len(self.buses)
        await asyncio.gather(*(self._line(k, blobs[k::n]) for k in range(n)))

    async def health_check(self) -> list[str]:
        """Clean devices now: every bus must answer every command right, with consistent counters."""
        problems = []
        for k, (bus, device) in enumerate(zip(self.buses, self.devices, strict=True)):
            device.clean = True
            if device.script:
                problems.append(f"line {k}: {len(device.script)} scripted answers never asked for")
                device.script.clear()
            for sid in (0, 7, 31):
                expect_image = valid_value(protocol.ReadEeprom(sid), bytes([sid, 5]))
                checks: list[tuple[Awaitable[Any], Any]] = [
                    (bus.servo(sid).read_stretch(), sid & 0x7F),
                    (bus.servo(sid).set_position(9000), (sid << 7 | 5) & protocol.POSITION_MAX),
                    (bus.servo(sid).read_eeprom(), expect_image),
                    (bus.device(sid).read_memory(0, 2), bytes([sid, 5])),
                ]
                for call, want in checks:
                    try:
                        got = await call
                    except IcsError as exc:
                        problems.append(f"line {k} ID {sid}: {exc!r}")
                        continue
                    if got != want:
                        problems.append(f"line {k} ID {sid}: {got!r}, expected {want!r}")
            stats = bus.stats
            if stats.total.transactions != device.writes:
                problems.append(f"line {k}: bus counted {stats.total.transactions}, device saw {device.writes}")
            if stats.total.ok + stats.total.errors != stats.total.transactions or stats.queued:
                problems.append(f"line {k}: counters inconsistent {stats.total} queued {stats.queued}")
            if device.mismatched_writes:
                problems.append(f"line {k}: {device.mismatched_writes} writes were not the command submitted")
        return problems
