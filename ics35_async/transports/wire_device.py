"""What an in-process device is (the simulator, a test double), and which URL schemes name one.

No asyncio here: the package root and the bus import this, and the drivers
that need an event loop are loaded only when a line opens.  A URL scheme
maps to the function that builds a device; ``sim://`` is known from the
start but its module (the simulator) is imported the first time a ``sim://``
line opens, so importing the library loads no simulator.
"""

from __future__ import annotations

import importlib
import os
import re
import sys
from collections.abc import Callable
from typing import Literal, Protocol, cast, get_args, runtime_checkable
from urllib.parse import urlsplit

from ..errors import InvalidArgument

TransportKind = Literal["auto", "direct", "thread"]
TRANSPORT_KINDS: tuple[str, ...] = get_args(TransportKind)


class HostSide(Protocol):
    """The host end of an in-process line, as a device sees it."""

    def deliver(self, data: bytes) -> None:
        """Bytes arriving at the host (echo, replies, noise).  Thread-safe."""

    def lost(self, exc: Exception | None) -> None:
        """The line went away (``exc`` says why).  Thread-safe."""


@runtime_checkable
class WireDevice(Protocol):
    """An in-process device on the far end of the wire (e.g. the simulator).

    ``connect`` raises :class:`OSError` when the device cannot be opened
    (e.g. it is simulated as unplugged).  ``write`` is called with the host's
    bytes; the device answers by calling ``host.deliver`` now or later, from
    any thread.  ``disconnect`` detaches the host.

    A device may also offer ``discard_input()`` (drop what it has not
    delivered yet, returning how many bytes that was if it knows), called
    when the line resyncs, and ``deliver_due()`` (call ``host.deliver`` now,
    on the calling thread, with whatever is due by now and not yet
    delivered), called whenever the host looks for input; both are optional.
    """

    def connect(self, host: HostSide, baudrate: int) -> None: ...

    def write(self, data: bytes) -> None: ...

    def disconnect(self) -> None: ...


WireDeviceFactory = Callable[[str], WireDevice]
_URL_SCHEMES: dict[str, WireDeviceFactory] = {}


def register_url_scheme(scheme: str, factory: WireDeviceFactory) -> None:
    """Make ``open_port("<scheme>://...")`` (and so ``open_bus``) build its device with ``factory(url)``.

    ``scheme`` in any case: URL schemes are case-insensitive (``SIM://`` is ``sim://``)."""
    _URL_SCHEMES[scheme.lower()] = factory


_SCHEME = re.compile(r"([A-Za-z][A-Za-z0-9+.-]*)://")


def url_scheme(port: object) -> str:
    """The URL scheme ``port`` names, in lower case (``"sim"`` for ``SIM://?ids=1``; ``"socket"``,
    ``"rfc2217"``, ...); ``""`` for a device path (``/dev/ttyUSB0``, ``COM3``) or a :class:`WireDevice`.

    The one place a port's scheme is read: schemes are case-insensitive (RFC 3986), so every check of one
    ("is this the simulator?", "a network link?") goes through here rather than comparing text.
    """
    match = _SCHEME.match(port) if isinstance(port, str) else None
    return match[1].lower() if match is not None else ""


def is_url(port: object) -> bool:
    """Whether ``port`` is a URL rather than a device path (or a :class:`WireDevice`): any text with ``://``.

    The rule opening follows: pyserial takes such a name for a URL and refuses a scheme it does not know
    (``9p://x``), so it never names a device, whether or not :func:`url_scheme` can read its scheme.
    """
    return isinstance(port, str) and "://" in port


def url_name(url: str) -> str | None:
    """What a URL names between its ``scheme://`` and its options, the slashes stripped (``sim://arm?ids=1-6``:
    ``"arm"``, the simulated line's name); None when it names nothing (``sim://``, ``sim:///?ids=5``)."""
    parts = urlsplit(url)
    return (parts.netloc + parts.path).strip("/") or None


def opens_anew(port: object) -> bool:
    """Whether each opening of ``port`` makes a line of its own, so that two lines may share it: an unnamed
    ``sim://`` URL (``sim://``, ``sim:///?ids=5``).  A named one (``sim://arm``) is one line however often it
    is opened, as a device or any other URL is.  Here, below the robot layer and the simulator, so that both
    read one rule (the robot layer may not import the simulator)."""
    return isinstance(port, str) and url_scheme(port) == "sim" and url_name(port) is None


def asks_nothing(port: object) -> bool:
    """Whether ``port`` is the simulator with nothing asked of it: an unnamed ``sim://`` URL without options
    (``sim://``, ``sim:///``, ``SIM://``, one line however written: see :func:`opens_anew`), which a tool may
    shape its way (real time for a live command, every ID for a demo)."""
    return isinstance(port, str) and opens_anew(port) and not urlsplit(port).query


# Schemes whose device factory lives in a module loaded on first use: "module:function".
_LAZY_SCHEMES = {"sim": "ics35_async.sim.url:open_url"}
# What checks a URL of such a scheme as written, opening nothing (see check_url): "module:function".
_URL_CHECKS = {"sim": "ics35_async.sim.url:check_url"}


def _loaded(target: str) -> Callable[[str], object]:
    module, _, name = target.partition(":")
    return cast(Callable[[str], object], getattr(importlib.import_module(module), name))


# A serial port's name as each system writes it (by sys.platform; "": Linux and the BSDs), as --help writes them.
_EXAMPLE_PORTS = {"win32": "COM3", "darwin": "/dev/cu.usbserial-...", "": "/dev/ttyUSB0"}


def example_port(platform: str | None = None) -> str:
    """A serial port's name as ``platform`` (default: this one) writes it, for a hint's example: a Linux user
    offered ``COM3`` is then told that COM names are Windows' own."""
    return _EXAMPLE_PORTS.get(platform or sys.platform, _EXAMPLE_PORTS[""])


# What a program that passed no port (an unset variable, an empty argument) is told to pass instead: each system's
# name labelled (the library's words may be read on another machine; a bare "or COM3" misled a Linux user).
_PORT_ADVICE = (
    f"pass the adapter's serial port (`ics35 ports` lists them), e.g. {example_port('linux')} on Linux, "
    f"{example_port('darwin')} on macOS, {example_port('win32')} on Windows; or 'sim://' for the built-in simulator"
)


def port_argument(port: object) -> str | WireDevice:
    """``port`` as the library keeps it: a path or URL (a ``pathlib.Path`` as its string) or a :class:`WireDevice`;
    refused, saying what to pass, when it is none of those or empty.

    Raises:
        InvalidArgument: ``port`` is empty, ``None`` or of another type.
    """
    if isinstance(port, os.PathLike):
        port = os.fspath(port)
    if isinstance(port, str):
        if not port:
            raise InvalidArgument(f"port must not be empty: {_PORT_ADVICE}")
        return port
    if not isinstance(port, WireDevice):
        raise InvalidArgument(f"port must be a path, a URL or a WireDevice, not {type(port).__name__}: {_PORT_ADVICE}")
    return port


def device_factory(scheme: str) -> WireDeviceFactory | None:
    """The factory registered for ``scheme``, importing its module on first use; None if unknown."""
    scheme = scheme.lower()
    factory = _URL_SCHEMES.get(scheme)
    if factory is None and scheme in _LAZY_SCHEMES:
        factory = cast(WireDeviceFactory, _loaded(_LAZY_SCHEMES[scheme]))
        _URL_SCHEMES[scheme] = factory
    return factory


def check_url(port: str) -> None:
    """Refuse ``port`` when opening it would refuse it as written, opening nothing: a ``sim://`` URL the
    simulator refuses (an empty ID list, a misspelt option), by the simulator's own check.  Anything else passes:
    a device path, or another URL (``socket://``), is known good or bad only by opening it.  Here, below the
    robot layer and the simulator, so that a robot file's ports are checked as it is read (the robot layer may not
    import the simulator); the simulator is loaded only for a ``sim://`` port.

    Raises:
        InvalidArgument: what opening ``port`` raises for what it says.
    """
    check = _URL_CHECKS.get(url_scheme(port))
    if check is not None:
        _loaded(check)(port)
