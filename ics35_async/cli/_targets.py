"""Where ``move`` may send a servo: a target from the command line, checked against the servo's travel.

A count outside 3500..11500 (or outside the servo's EEPROM pulse limits) runs
a real servo into its end stop, and a small number is usually degrees typed
without --deg, so both are refused unless --force.
"""

from __future__ import annotations

import math

from rich.markup import escape

from .. import protocol, units
from ..errors import InvalidArgument, MalformedEeprom, ReplyDataError
from ..servo import Servo, check_pulse_limits
from ._console import say_labelled
from ._settings import CliError, ExitCode, Settings

FORCE_HINT = "to send it anyway (the servo may run into its end stop), add --force"


def parse_target(settings: Settings, text: str, servo_id: int, *, degrees: bool, force: bool) -> int:
    """A position in counts from POS; CliError (exit code 2, nothing sent) when it is refused."""
    try:
        value = float(text)
    except ValueError:
        raise InvalidArgument(f"{text!r} is not a number") from None
    if degrees:
        return units.degrees_to_position(value)  # refuses beyond +-135 degrees
    if not math.isfinite(value) or value != int(value):
        raise InvalidArgument(f"position must be a whole number of counts, got {text} (use --deg for degrees)")
    counts = int(value)
    looks_like_degrees = abs(value) <= units.DEGREES_MAX
    if not force and not units.TRAVEL_MIN <= counts <= units.TRAVEL_MAX:
        again = settings.command_line("move", str(servo_id), text, "--deg")
        hints = [f"did you mean {text} degrees? {again}"] if looks_like_degrees else []
        raise CliError(
            ExitCode.USAGE,
            f"position {counts} is outside the servo's travel {units.TRAVEL_MIN}..{units.TRAVEL_MAX} counts "
            "(-135..+135 degrees, 7500 is neutral): nothing was sent",
            *hints,
            *([] if counts < 1 or counts > protocol.POSITION_MAX else [FORCE_HINT]),
        )
    try:
        return units.check_int("position", counts, 1, protocol.POSITION_MAX)
    except InvalidArgument:
        if looks_like_degrees:
            raise InvalidArgument(f"position must be in 1..16383, got {counts} (for degrees add --deg)") from None
        raise


async def refuse_outside_pulse_limits(servo: Servo, target: int) -> None:
    """Refuse ``target`` outside the servo's EEPROM pulse limits (read first; 3500..11500 when unreadable)."""
    try:
        image = await servo.read_eeprom()
    except (ReplyDataError, MalformedEeprom) as exc:
        say_labelled(
            "[yellow]note:[/yellow]",
            escape(f"servo {servo.id}'s EEPROM is unreadable ({exc}); its pulse limits are taken as 3500..11500"),
        )
        return
    try:
        check_pulse_limits(servo.id, target, image.pulse_limit_low, image.pulse_limit_high)
    except InvalidArgument as exc:
        raise CliError(
            ExitCode.REFUSED,
            str(exc),
            FORCE_HINT,
            "the limits are the EEPROM fields pulse_limit_low and pulse_limit_high (see: ics35 info)",
        ) from None
