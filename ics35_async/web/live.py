"""The Live plots page's data: a position stream over the chosen servos, with current and temperature
read in its gaps, sampled for the page at a fixed rate (the stream never waits for the page).

Which servo is read how is the library's policy (policies.plan_position_stream):
an ICS 3.6 servo is watched with its position read, its torque left as it
was; an ICS 3.5 servo starts free (the free command is how ICS 3.5 reads a
position without moving), unless a Servo page holds it: then it is streamed
its held target, whose reply reads it too (freed, a joint of a standing robot
would go limp unasked).  They are moved only when a page with motion switched
on gives them a target.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections import deque
from collections.abc import Callable, Collection, Mapping
from typing import Any

from .. import protocol
from ..bus import Bus, Priority
from ..errors import IcsError, UnsafeOperation
from ..frames import Frame, LiveReadings
from ..policies import plan_position_stream
from ..protocol import Param
from ..stream import WATCH, Stream
from ..units import current_from_raw, temperature_text, temperature_to_celsius

# The stream's pace.  The page is sent the newest frame 25 times a second; at 100 cycles a second that
# frame is at most 10 ms old and a jog's target goes out within 10 ms.  Unpaced, a fast line (one servo
# at 1.25 Mbit/s, or the built-in simulator, which answers at once) would cycle thousands of times a
# second and take a core of the server for frames no page sees.  A line that cannot keep this pace (32
# servos at 115200: about 46 cycles a second on the wire, 15 through a USB adapter) runs at its own,
# and the other pages' requests still get the line within two of its cycles (the engine's rule).
LIVE_RATE_HZ = 100.0

# One servo's current and temperature every this many seconds: 32 servos in about 3 s,
# about 20 transactions a second taken from the stream.
TELEMETRY_PERIOD = 0.1


async def read_health(bus: Bus, servo_id: int) -> dict[str, Any]:
    """A servo's temperature and current (reads that move nothing), in the line's gaps."""
    temp = await bus.request(protocol.ReadParam(servo_id, Param.TEMPERATURE), priority=Priority.LOW)
    current = await bus.request(protocol.ReadParam(servo_id, Param.CURRENT), priority=Priority.LOW)
    return {
        "temperature": temp,
        "temperature_c": round(temperature_to_celsius(temp), 1),
        "temperature_text": temperature_text(temp),  # (the words every page and command show it in)
        "current": current_from_raw(current).magnitude,
    }


class LiveView:
    """A running stream and the latest readings of its servos."""

    def __init__(self, bus: Bus, stream: Stream) -> None:
        self.bus = bus
        self.stream = stream
        self.ids = stream.ids
        self.kept_held: list[int] = []  # ICS 3.5 servos a page held: streamed their target, not freed
        self.freed: list[int] = []  # ICS 3.5 servos it frees to read them
        self.left_out: list[int] = []  # ICS 3.5 servos not plotted: freeing them was not asked for
        # (each kept while it is the servo's own now: see LiveReadings)
        self.current: LiveReadings[int] = LiveReadings()
        self.temperature: LiveReadings[float] = LiveReadings()  # (Celsius: the plots')
        self.temperature_text: LiveReadings[str] = LiveReadings()  # (the Line page's, in its words)
        self._task: asyncio.Task[None] | None = None
        self._marks: deque[tuple[float, int]] = deque()  # (frame time, cycle) of the last second's snapshots

    @classmethod
    async def start(
        cls,
        bus: Bus,
        ids: list[int],
        *,
        rate_hz: float = LIVE_RATE_HZ,
        holding: Mapping[int, int] | None = None,
        unsure: Collection[int] = (),
        lost_touch: Callable[[list[int]], None] | None = None,
        free_ics35: bool = False,
    ) -> LiveView:
        """Stream ``ids``; an ICS 3.5 servo in ``holding`` ({ID: the target a page holds it at}) is sent that
        target, not freed; one in ``unsure`` (held before the port was lost or reopened, or it stopped answering)
        is refused: freed, a servo that kept its supply would go limp, and sent its old target, one that restarted
        would be thrown there.  A servo in ``holding`` silent as the plot starts has stopped answering: it is refused as
        well, and ``lost_touch`` is told its ID (the plan catches its timeout, so nothing else would say it).  (One
        whose protocol this line does not know is watched, which sends neither: see ``plan_position_stream``.)
        The other ICS 3.5 servos are freed to be read only with ``free_ics35`` (a standing robot's joints would go
        limp); without it they are left out (``left_out``), and a plot with nothing else to read is refused.

        Raises:
            UnsafeOperation: a servo's hold in doubt (see above), or nothing to plot without ``free_ics35``
                (nothing that moves or frees a servo sent).
        """
        plan = await plan_position_stream(bus, [protocol.check_id(i) for i in ids], free_ics35=free_ics35)
        silent_held = [sid for sid in plan.silent if sid in (holding or {})]
        if silent_held and lost_touch is not None:
            lost_touch(silent_held)
        doubtful = [sid for sid in plan.free if sid in unsure or sid in silent_held]
        if doubtful:
            who = ", ".join(map(str, doubtful))
            raise UnsafeOperation(
                f"servo {who} was held by a Servo page before the port was lost or opened again, or it stopped "
                "answering: it may still hold there, or have restarted, free and elsewhere, and the live plot reads "
                "an ICS 3.5 servo only by freeing it or by sending it a target; say which on its Servo page (Free "
                "lets it go, Hold here holds it where it stands now), then start the plot again; nothing that moves "
                "or frees a servo was sent"
            )
        # (An ICS 3.5 servo a page holds is streamed its target, freed or not: the command's reply reads it.)
        kept = {sid: target for sid, target in (holding or {}).items() if sid in plan.free or sid in plan.left_out}
        left_out = sorted(set(plan.left_out) - kept.keys())
        streamed = sorted(set(plan.streamed) | kept.keys())
        if not streamed:
            names = ", ".join(map(str, left_out))
            who, them = (f"servo {names} speaks", "it") if len(left_out) == 1 else (f"servos {names} speak", "them")
            raise UnsafeOperation(
                f'{who} ICS 3.5, which reads a position only by going free (limp): tick "free ICS 3.5 servos" to '
                f"plot {them} (turn {them} by hand), or hold one on its Servo page first (it is then plotted at its "
                "target); nothing that moves or frees a servo was sent"
            )
        stream = bus.stream(streamed, rate_hz=rate_hz, **plan.stream_options(streamed))
        if kept:
            stream.set_targets(kept)  # (before it starts: its first command to them is their target, not a free)
        await stream.start()
        view = cls(bus, stream)
        view.kept_held = sorted(kept)
        view.freed = sorted(set(plan.free) - kept.keys())
        view.left_out = left_out
        view._task = asyncio.create_task(view._read_telemetry())
        return view

    async def _read_telemetry(self) -> None:
        k = 0
        while True:
            await asyncio.sleep(TELEMETRY_PERIOD)
            sid = self.ids[k % len(self.ids)]
            k += 1
            frame = self.stream.latest
            if frame is not None:
                self._follow(frame)
            if frame is None or sid in frame.unanswered:
                continue  # a dead ID costs a full timeout per read: the stream probes it
            try:
                health = await read_health(self.bus, sid)
            except IcsError:
                # (the temperature and current are read together: one failing leaves both unread)
                for readings in self._readings:
                    readings.read_failed(sid)  # (gone at the second in a row: see LiveReadings)
                continue
            self.temperature[sid] = health["temperature_c"]
            self.temperature_text[sid] = health["temperature_text"]
            self.current[sid] = health["current"]

    @property
    def _readings(self) -> tuple[LiveReadings[Any], ...]:
        return (self.current, self.temperature, self.temperature_text)

    def _follow(self, frame: Frame) -> None:
        """Drop the readings of the servos ``frame`` has offline."""
        for readings in self._readings:
            readings.follow(frame)

    def position(self, servo_id: int) -> int:
        frame = self.stream.latest
        return -1 if frame is None else frame.positions.get(servo_id, -1)

    def snapshot(self) -> dict[str, Any] | None:
        """The newest frame for the page, or None before the first."""
        frame = self.stream.latest
        if frame is None:
            return None
        self._follow(frame)
        # The rate over the last second, from the frames themselves: Stream.stats sorts and takes the
        # deviation of its whole history, too much to do 25 times a second next to a streaming line.
        marks = self._marks
        marks.append((frame.finished, frame.cycle))
        while len(marks) > 2 and frame.finished - marks[0][0] > 1.0:
            marks.popleft()
        span = marks[-1][0] - marks[0][0]
        rate = (marks[-1][1] - marks[0][1]) / span if span > 0 else 0.0
        return {
            "cycle": frame.cycle,
            "t": frame.finished,
            "positions": {str(k): v for k, v in frame.positions.items()},
            "targets": {str(i): self.stream.target(i) for i in self.ids},
            "current": {str(k): v for k, v in self.current.items()},
            "temperature": {str(k): v for k, v in self.temperature.items()},
            "offline": sorted(frame.offline),
            # (an offline ID is watched for its answer, not known to answer ICS 3.6's read: said as offline only)
            "watched": [i for i in self.ids if self.stream.target(i) == WATCH and i not in frame.offline],
            # Sent nothing since their port came back or they answered again, and why: their servos may
            # have restarted, free and elsewhere, so the page says so rather than plot a line gone flat.
            "held": {str(k): why for k, why in self.stream.held.items()},
            "rate_hz": round(rate, 1),
        }

    async def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
        await self.stream.aclose()
