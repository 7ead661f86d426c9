"""Why a servo did not answer: the adapter, a reply too long for the link, or another baud rate.

The ``ics35`` command and the configurator both tell a person this after a
command to one servo went unanswered (:class:`~ics35_async.errors.ReplyTimeout`),
each in its own words; the checks and their order are here once:

1. not even the echo of the command came back (on a line that echoes): the
   adapter or its wiring, not the servo; nothing more is asked;
2. the EEPROM read went unanswered, but the servo answers a short read at the
   line's rate: its 66-byte reply is lost on the way (an adapter or bridge that
   drops long replies), or the device is no ICS 3.5 servo;
3. the servo answers at another rate, and its own EEPROM names that rate
   (:func:`~.scan.servo_rates`, every other rate tried): the line was opened at
   the wrong rate.

Step 3 reopens the port at each other rate, so a caller whose line others use
at the same time (a robot streaming on it, a live stream) passes
``other_rates=False``: the finding then says the other rates were not tried.
A port that cannot be opened again, or a rate the adapter cannot do, only
leaves that check out: the finding never raises for the line's sake.  It names
such rates apart (:attr:`NoReply.not_searched`), with a rate whose ask raised
(the port lost as the servo was asked there), never among the rates the servo
was asked at and did not answer (:attr:`NoReply.searched`).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from ..errors import IcsError, ReplyTimeout
from .failure_kinds import LineOpener, answers_short_read
from .scan import RateCallback, other_bauds, rates_in_words, servo_rates


class NoReplyCause(enum.Enum):
    """What :func:`why_no_reply` found."""

    NO_ECHO = "no_echo"
    """Not even the echo of the bytes sent came back: the adapter or its wiring (or it echoes nothing)."""
    LONG_REPLY_LOST = "long_reply_lost"
    """The servo answers short reads at the line's rate, but not the EEPROM read (its reply is the longest)."""
    OTHER_RATE = "other_rate"
    """The servo answers at another rate (:attr:`NoReply.rates`), which its own EEPROM names."""
    UNKNOWN = "unknown"
    """None of these: power, wiring, the ID, PWM mode; or another rate, when :attr:`NoReply.rates_tried` is False."""


@dataclass(frozen=True)
class NoReply:
    """Why ``servo_id`` did not answer at ``baud``."""

    cause: NoReplyCause
    servo_id: int | None
    baud: int
    rates: tuple[int, ...] = ()  # OTHER_RATE: the rates the servo answers at, the one to use first
    # Whether the other rates were tried.  False: an earlier check found the cause (NO_ECHO, LONG_REPLY_LOST),
    # the caller did not allow them (``other_rates=False``), or the command names no servo.
    rates_tried: bool = False
    # The other rates asked, in order, each ask run to its end (a link that ignores rates asks none).
    searched: tuple[int, ...] = ()
    # The other rates that could not be asked, in order: the port could not be opened at them, or an ask raised
    # (the port lost as the servo was asked: no answer could come back), which ended the search there.
    not_searched: tuple[int, ...] = ()

    def nothing_elsewhere(self) -> str | None:
        """When other rates were asked and the servo answered at none: that, in words to follow what did not
        answer at the line's rate (``nor at 625000 or 1250000 baud``); None otherwise."""
        if self.cause is not NoReplyCause.UNKNOWN or not self.searched:
            return None
        return f"nor at {rates_in_words(self.searched)} baud"

    def not_searched_in_words(self) -> str | None:
        """The other rates that could not be asked, in words (``625000 and 1250000 baud could not be tried``), for
        a person not to take them for rates the servo does not answer at; None when there are none."""
        if not self.not_searched:
            return None
        return f"{rates_in_words(self.not_searched, 'and')} baud could not be tried"


async def why_no_reply(
    exc: ReplyTimeout,
    open_at: LineOpener,
    baud: int,
    *,
    echo: bool = True,
    other_rates: bool = True,
    on_rate: RateCallback | None = None,
) -> NoReply:
    """Why the command of ``exc``, sent at ``baud``, went unanswered (see the module's checks, in order).

    ``open_at(baud)`` opens the line at a rate, as for :func:`~.scan.scan`; at
    ``baud`` itself it is asked for one short read, at every other rate (unless
    ``other_rates`` is False) for a stretch read and, when that is answered, the
    EEPROM.  ``echo``: whether the line loops what it sends back.  An ID command
    names no servo: nothing is asked, the cause is UNKNOWN.  ``on_rate(baud)`` is
    told each other rate as it is tried (see :func:`~.scan.servo_rates`).
    """
    servo_id = exc.servo_id
    if servo_id is None:
        return NoReply(NoReplyCause.UNKNOWN, None, baud)
    if echo and not exc.raw:
        return NoReply(NoReplyCause.NO_ECHO, servo_id, baud)
    if exc.command == "read_eeprom" and await _answers_short_read(open_at, baud, servo_id):
        return NoReply(NoReplyCause.LONG_REPLY_LOST, servo_id, baud)
    if not other_rates:
        return NoReply(NoReplyCause.UNKNOWN, servo_id, baud)
    searched: list[int] = []
    not_searched: list[int] = []
    try:
        found = await servo_rates(
            open_at, servo_id, other_bauds([baud]), on_rate=on_rate, tried=searched, not_tried=not_searched
        )
    except (IcsError, OSError):
        found = ()
    cause = NoReplyCause.OTHER_RATE if found else NoReplyCause.UNKNOWN
    return NoReply(
        cause,
        servo_id,
        baud,
        rates=found,
        rates_tried=True,
        searched=tuple(searched),
        not_searched=tuple(not_searched),
    )


async def _answers_short_read(open_at: LineOpener, baud: int, servo_id: int) -> bool:
    try:
        async with open_at(baud) as line:
            return await answers_short_read(line, servo_id)
    except (IcsError, OSError):
        return False
