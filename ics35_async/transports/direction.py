"""Direction control for DIY half-duplex interfaces: RTS switches an RS-485 / tri-state driver on while sending.

An ICS adapter switches the line's direction itself.  A home-made interface
(a UART, a MAX485-style transceiver or a tri-state buffer, its driver-enable
pin on RTS) needs RTS raised while the host sends and dropped at once after
the last stop bit, or the servo's reply meets our own driver.  pyserial's
RS-485 settings (:class:`serial.rs485.RS485Settings`) ask the OS driver to
do that toggling: Linux's TIOCSRS485 (UARTs whose driver supports it),
Windows' RTS_CONTROL_TOGGLE (RTS high while sending only).  A driver that
cannot gives :class:`~ics35_async.errors.DirectionControlNotSupported`.

With the receiver disabled while sending (RE tied to DE) no echo comes
back: pass ``echo=False`` (``--no-echo``) as well.
"""

from __future__ import annotations

import errno

import serial
import serial.rs485

from ..errors import DirectionControlNotSupported, InvalidArgument
from .wire_device import is_url

# "none": the interface switches direction itself (ICS adapters, auto-direction transceivers).
# "rts": RTS high while sending, low while receiving.  "rts-inverted": the other way round.
DIRECTIONS = ("none", "rts", "rts-inverted")


def check_direction(direction: str | None, port: object) -> str:
    """``direction`` as one of :data:`DIRECTIONS`; refused for ports that are not local serial ports."""
    if direction is None:
        return "none"
    if direction not in DIRECTIONS:
        raise InvalidArgument(f"direction must be one of {', '.join(DIRECTIONS)}, not {direction!r}")
    if direction != "none" and (not isinstance(port, str) or is_url(port)):
        raise InvalidArgument(
            f"direction={direction!r} drives a local serial port's RTS pin; {port!r} is not one "
            "(set direction control on the far end of a link)"
        )
    return direction


def rs485_settings(direction: str) -> serial.rs485.RS485Settings | None:
    """pyserial's RS-485 settings for ``direction`` (None: leave RTS alone)."""
    if direction == "none":
        return None
    high_while_sending = direction == "rts"
    return serial.rs485.RS485Settings(rts_level_for_tx=high_while_sending, rts_level_for_rx=not high_while_sending)


def refused(port: str, direction: str, exc: Exception) -> DirectionControlNotSupported:
    """The error for a driver that refused RS-485 mode (pyserial says so with ValueError or NotImplementedError)."""
    return DirectionControlNotSupported(
        errno.ENOTTY,
        f"the driver of {port!r} refused direction control ({direction}: RTS toggled by the driver): {exc}. "
        "Use an interface that switches direction itself, or a UART whose driver supports RS-485 mode "
        "(Linux: TIOCSRS485; Windows: RTS high while sending only)",
    )


def is_rs485_refusal(exc: Exception) -> bool:
    """Whether pyserial's ``exc`` (raised while opening) is the driver refusing RS-485 mode."""
    text = str(exc)
    return isinstance(exc, NotImplementedError) or "RS485" in text or "rs485" in text.lower()
