"""The line's rules as a pure state machine, and what it queues.

Nothing here does I/O or reads a clock: drivers (:mod:`ics35_async.drivers`)
move bytes and time between a :class:`LineEngine` and the world.

The rules, each in one place:

* one transaction at a time: write, consume the echo (when the line echoes),
  read exactly the reply length of that command, validate it;
* the allowance counts from the write (``LineEngine.written``: the program
  may hold the driver up between the engine's answer and its write);
* outcome: a reply that does not arrive by the deadline is a timeout, a
  partial reply, or an echo mismatch, by what did arrive; a wrong echo
  (judged first: bytes ahead of it are a late reply), extra bytes, a byte
  with a parity error or a reply the codec rejects fail it too;
* resync: after any fault, wait until the line has been quiet for
  ``quiet_time`` (at most ``max_resync``; less after a probe's or the
  stream's short wait), so the late bytes of a failed
  transaction are never taken for the next reply;
* guard read: after a timeout, a command with the same command byte does not
  go next (the late reply would fit it); a harmless read of another shape
  goes first.  A transaction that fails on what came before its deadline
  (another's late bytes, noise) may still get its own reply: it gets the
  resync and the guard read a timeout would have;
* priorities, and the stream's share: at most ``max_requests_between``
  requests between two stream transactions; after a request's reply beside
  a stream (above ``LOW`` priority) the line waits for the driver's next
  turn (a deadline of now), so that the caller's next request, made in that
  turn, goes before the stream's next transaction;
* retries of idempotent commands; cancellation (a cancelled request's reply
  is still consumed and dropped);
* offline for a reopen: at once when idle; asked while BUSY or QUIET, once
  that transaction or resync ends, no queued request going meanwhile
  (``describe()["going_offline"]`` says it is pending);
* a slow link: late bytes raise every allowance (see :mod:`.link`);
* probes: a ``Timing.PROBE`` read waits as long as this link's answers have
  taken, not the adapter's worst case, and its silence resyncs as briefly
  (see :mod:`.probe`); a ``Timing.SILENT`` command (to a servo already found
  silent) waits as a probe, and briefly even before anything has answered,
  with no guard read or hold before it; so does a stream's probe of a servo it
  found silent once the stream has left (``LineEngine.detach_source``);
* the stream's wait: its transactions wait what this link's answers take
  too; after such a short wait fails, its servo is held back (the stream
  skips it, a request to it waits) until the reply could no longer come,
  and the first command after that hold is not one that reply could pass
  for: the stream skips that servo once more while it has another to send,
  and otherwise (or for a request to it) the guard read a timeout's resync
  would have given goes first (``LineEngine._skip_held``); while a cut-short
  reply's tail could still come a reply arriving in pieces is taken only
  once nothing more follows (``LineEngine._hold``);
* reads in a paced stream's slack: a read (a command that changes nothing)
  below ``URGENT``, whose silence is no answer, beside a stream with a rate
  waits as the stream's transactions do, and, once its echo is in, no later
  than the slot it was fitted before (``LineEngine._slack_left``: its reply is
  overdue by then); timed out with its echo and nothing
  more, after the stream's short resync its first byte (command and ID) is
  held back as a stream transaction's servo is, whether or not it waited less
  than its full allowance (a retry or another command starting so waits, the
  stream and other commands go on), and the first command after that hold
  gets the guard read a timeout's resync would have given; any other failure
  of it resyncs as after its full wait (``LineEngine._in_slack``,
  ``LineEngine._hold``).  Beside no stream or an unpaced one, and for
  anything else, the rules above stand.
"""

from .counters import LineCounters
from .machine import FlushInput, LineEngine, Output
from .requests import GuardRequest, Priority, Request, RequestHandle, RequestQueue
from .source import BackgroundSource
from .state import State
from .timing import BusTiming, TimingOverrides

__all__ = [
    "BackgroundSource",
    "BusTiming",
    "FlushInput",
    "TimingOverrides",
    "GuardRequest",
    "LineCounters",
    "LineEngine",
    "Output",
    "Priority",
    "Request",
    "RequestHandle",
    "RequestQueue",
    "State",
]
