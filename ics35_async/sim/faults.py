"""Seeded, deterministic fault injection for the simulated line.

Faults are chosen per transaction (per host command the line frames) with a
probability that may differ per servo ID.  Every transaction draws the same
number of random numbers from one ``random.Random(seed)``, so the same seed
and the same host traffic give the same faults, whatever they turn out to be.

Kinds (names as used in fault specs and in the transaction log):

``drop``      the reply is not sent at all
``truncate``  only the first 0..n-1 bytes of the reply are sent
``corrupt``   one reply byte has some of its low 7 bits flipped
``msb``       one reply data byte (the header if there is none) gets its MSB set
``late``      the reply is held back and delivered after the echo of the host's
              *next* command (or ``late_delay`` seconds later if one is set)
``tail``      a held tail: the reply's last ``tail_bytes`` bytes reach the host
              ``tail_delay`` seconds late, and nothing sent after them
              overtakes them (a TCP bridge with Nagle's algorithm: ser2net
              splits a 68-byte EEPROM answer 64 + 4, the 4 about 40 ms later);
              a reply of ``tail_bytes`` bytes or fewer is not split.  In fast
              mode the tail comes with the host's next write, before its echo
``noise``     1..3 random bytes reach the host on the idle line after the transaction
``echo``      a collision: one echo byte comes back changed, and the garbled
              command is not heard by any device (no reply, no effect)
``unplug``    after the transaction the port disappears, and comes back after
              the line's ``replug_after`` seconds

The six reply faults exclude each other (one draw decides which, if any), so
their rates for one ID must add up to at most 1.

Spec syntax (``sim://?faults=...``, ``--faults``): comma-separated
``kind:rate`` for every ID, ``kind@ID:rate`` or ``kind@LOW-HIGH:rate`` for
some IDs (overriding the all-ID rate there), e.g.
``drop:0.01,late:0.005,corrupt@3:0.5,noise@0-7:0.02``; ``collision`` is an
alias of ``echo``, ``held_tail`` of ``tail``.  An empty spec or ``none`` means no faults.
"""

from __future__ import annotations

import random
from dataclasses import dataclass, field

from ..errors import InvalidArgument
from ..units import parse_ids

# New kinds go at the end: a draw walks this order, so the same seed keeps giving the same faults.
REPLY_FAULTS = ("drop", "truncate", "corrupt", "msb", "late", "tail")
FAULT_KINDS = (*REPLY_FAULTS, "noise", "echo", "unplug")
_ALIASES = {"collision": "echo", "held_tail": "tail"}


def _rate(text: str, item: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise InvalidArgument(f"fault rate in {item!r} is not a number") from None
    if not 0.0 <= value <= 1.0:
        raise InvalidArgument(f"fault rate in {item!r} must be in 0..1")
    return value


@dataclass
class FaultConfig:
    """Fault rates: ``rates`` for every ID, ``per_id`` overrides for some IDs."""

    rates: dict[str, float] = field(default_factory=dict)
    per_id: dict[int, dict[str, float]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for table in (self.rates, *self.per_id.values()):
            for kind, value in table.items():
                if kind not in FAULT_KINDS:
                    raise InvalidArgument(f"unknown fault kind {kind!r} (known: {', '.join(FAULT_KINDS)})")
                if not 0.0 <= value <= 1.0:
                    raise InvalidArgument(f"fault rate {kind}={value} must be in 0..1")
        for servo_id in (None, *self.per_id):
            total = sum(self.rate(kind, servo_id) for kind in REPLY_FAULTS)
            if total > 1.0 + 1e-9:
                where = "all IDs" if servo_id is None else f"ID {servo_id}"
                raise InvalidArgument(f"reply fault rates for {where} add up to {total:g}, more than 1")

    @classmethod
    def parse(cls, spec: str | None) -> FaultConfig:
        """The configuration a ``spec`` string gives: ``kind[@ids]:rate`` items, comma-separated
        (e.g. ``"drop:0.01,late@3:0.1"``); ``None``, ``""`` or ``"none"``: no faults.

        Raises:
            InvalidArgument: an unknown kind, a missing rate, a rate outside 0..1, a bad ID list, or
                reply fault rates adding up to more than 1.
        """
        rates: dict[str, float] = {}
        per_id: dict[int, dict[str, float]] = {}
        if spec is None or spec.strip().lower() in ("", "none"):
            return cls()
        for item in spec.split(","):
            item = item.strip()
            if not item:
                continue
            head, colon, value = item.rpartition(":")
            if not colon:
                raise InvalidArgument(f"fault {item!r} needs a rate, e.g. drop:0.01")
            kind, at, ids_text = head.partition("@")
            kind = _ALIASES.get(kind.strip(), kind.strip())
            if kind not in FAULT_KINDS:
                raise InvalidArgument(f"unknown fault kind {kind!r} (known: {', '.join(FAULT_KINDS)})")
            rate = _rate(value, item)
            if at:
                for servo_id in parse_ids(ids_text):
                    per_id.setdefault(servo_id, {})[kind] = rate
            else:
                rates[kind] = rate
        return cls(rates, per_id)

    def rate(self, kind: str, servo_id: int | None) -> float:
        """The rate of fault ``kind`` for a transaction to ``servo_id`` (``None``: the ID command)."""
        if servo_id is not None:
            table = self.per_id.get(servo_id)
            if table is not None and kind in table:
                return table[kind]
        return self.rates.get(kind, 0.0)

    def __bool__(self) -> bool:
        return any(self.rates.values()) or any(any(t.values()) for t in self.per_id.values())

    def __str__(self) -> str:
        parts = [f"{kind}:{rate:g}" for kind, rate in self.rates.items()]
        parts += [
            f"{kind}@{sid}:{rate:g}" for sid, table in sorted(self.per_id.items()) for kind, rate in table.items()
        ]
        return ",".join(parts) or "none"


@dataclass(frozen=True, slots=True)
class Draw:
    """The faults chosen for one transaction."""

    echo: bool
    reply: str | None
    noise: bool
    unplug: bool

    def names(self) -> list[str]:
        out = ["echo"] if self.echo else []
        if self.reply is not None:
            out.append(self.reply)
        if self.noise:
            out.append("noise")
        if self.unplug:
            out.append("unplug")
        return out


NO_FAULTS = Draw(False, None, False, False)


class FaultInjector:
    """Draws faults for each transaction and applies them to bytes.

    Args:
        config: the fault rates (default: none).
        seed: the seed of its ``random.Random`` (``None``: a fresh one).
    """

    def __init__(self, config: FaultConfig | None = None, seed: int | None = 0) -> None:
        self.config = config or FaultConfig()
        self.seed = seed
        self.rng = random.Random(seed)
        self._enabled = bool(self.config)  # the config is not meant to change afterwards

    def draw(self, servo_id: int | None) -> Draw:
        """The faults for one transaction to ``servo_id`` (always four draws, so a seed replays the same faults)."""
        if not self._enabled:
            return NO_FAULTS
        rng, cfg = self.rng, self.config
        # Always four draws, in this order, so the stream stays aligned with the traffic.
        echo = rng.random() < cfg.rate("echo", servo_id)
        pick = rng.random()
        reply = None
        for kind in REPLY_FAULTS:
            pick -= cfg.rate(kind, servo_id)
            if pick < 0:
                reply = kind
                break
        noise = rng.random() < cfg.rate("noise", servo_id)
        unplug = rng.random() < cfg.rate("unplug", servo_id)
        return Draw(echo, reply, noise, unplug)

    def damage_reply(self, kind: str, reply: bytes) -> bytes:
        """``reply`` after a fault of ``kind``: ``"truncate"``, ``"corrupt"`` or ``"msb"``."""
        if not reply:
            return reply
        rng = self.rng
        if kind == "truncate":
            return reply[: rng.randrange(1, len(reply)) if len(reply) > 1 else 0]
        data = bytearray(reply)
        if kind == "corrupt":
            data[rng.randrange(len(data))] ^= rng.randrange(1, 0x80)
        elif kind == "msb":
            data[rng.randrange(1, len(data)) if len(data) > 1 else 0] |= 0x80
        return bytes(data)

    def damage_echo(self, echo: bytes) -> bytes:
        """``echo`` with one byte changed (the ``echo`` fault: a collision)."""
        if not echo:
            return echo
        data = bytearray(echo)
        data[self.rng.randrange(len(data))] ^= self.rng.randrange(1, 0x100)
        return bytes(data)

    def noise(self) -> bytes:
        """One to three random bytes (the ``noise`` fault)."""
        return bytes(self.rng.randrange(0x100) for _ in range(self.rng.randrange(1, 4)))

    def uniform(self, low: float, high: float) -> float:
        """A random number between ``low`` and ``high`` from the injector's own generator."""
        return self.rng.uniform(low, high)
