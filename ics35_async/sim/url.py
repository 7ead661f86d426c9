"""``sim://`` URLs: their syntax, and the device one names.

:func:`open_url` is what the core calls for a ``sim://`` port, :func:`check_url` what checks one without
opening it;
:func:`parse_url` splits a URL into a line name and :class:`VirtualLine`
options (:func:`named_url` gives an unnamed one a name);
:func:`parse_seconds` reads the durations both the URL and the pty server's
command line take.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any
from urllib.parse import parse_qs, urlsplit, urlunsplit

from ..eeprom import BaudRate
from ..errors import InvalidArgument
from ..transports import WireDevice
from ..transports.wire_device import url_name
from ..units import parse_ids
from .adapter import make_adapter
from .faults import FaultConfig
from .model import check_delay
from .record import ReplayDevice
from .virtual_line import VirtualLine, named


def open_url(url: str) -> WireDevice:
    """The device a ``sim://`` URL names: what the core opens for a ``sim://`` port.

    The one entry point from a URL to the simulator (registered as the
    ``sim`` URL scheme's factory); see :func:`parse_url` for the keys.

    A named line (``sim://NAME?...``) is created once and returned again by
    later calls, so a bus that reconnects finds the same servos.

    Raises:
        InvalidArgument: the URL is not a ``sim://`` URL, or a key or value is bad, or it names a
            line open already that a URL made with other options.
    """
    name, options = parse_url(url)
    query = url_options(url)
    if name is not None:
        try:
            line = named(name)
        except KeyError:
            pass
        else:
            # (a line built in Python has no URL options to compare: any URL naming it finds it)
            if query and line.url_query is not None and query != line.url_query:
                raise InvalidArgument(
                    f"sim://{name} is open already with other options ({line.url_query}); "
                    f"give the same options (or none) to reach it, or another name for another line"
                )
            return line
    replay = options.pop("replay", None)
    if replay is not None:
        return ReplayDevice(replay)
    line = VirtualLine(name=name, **options)
    line.url_query = query
    return line


def check_url(url: str) -> None:
    """Refuse ``url`` as :func:`open_url` refuses it, opening nothing: what checks a robot file's ``sim://``
    ports as the file is read (``ics35 check``), so a port the simulator refuses is told before any line opens.

    The options are checked by what opening checks them with: :func:`parse_url`, then the line built from them
    (an unnamed one, reachable by no URL, writing no recording), which checks them together (an ``ics36`` ID
    among ``ids``, ...).  What only an opening meets is left to it: a replay file missing, a recording's file
    that cannot be written, a named line open already with other options.

    Raises:
        InvalidArgument: what :func:`open_url` raises for a URL, a key or a value.
    """
    _, options = parse_url(url)
    if "replay" not in options:
        options.pop("record", None)
        VirtualLine(**options).close()


def url_options(url: str) -> str:
    """A ``sim://`` URL's options in one form (keys in order): the same options compare equal in whatever
    order they were written.  (Values are compared as written: ``ids=1-3`` is not ``ids=1,2,3``.)"""
    return "&".join(sorted(part for part in urlsplit(url).query.split("&") if part))


def named_url(url: str, name: str) -> str:
    """``url`` naming the line ``name``, its options kept: what a program that reopens an unnamed ``sim://``
    line (a scan at each rate, a read-back) opens instead, so that each opening finds the same servos."""
    return urlunsplit(urlsplit(url)._replace(netloc=name, path=""))


_TRUE = {"1", "true", "yes", "on"}
_FALSE = {"0", "false", "no", "off"}


def _flag(key: str, text: str) -> bool:
    low = text.strip().lower()
    if low in _TRUE:
        return True
    if low in _FALSE:
        return False
    raise InvalidArgument(f"sim URL: {key}={text!r} is not a boolean (1/0)")


def parse_seconds(text: str, what: str = "duration") -> float:
    """``"0.02"``, ``"20ms"``, ``"100us"``, ``"1s"`` -> seconds.

    Raises:
        InvalidArgument: not a number of seconds, or not a delay a timer can wait (negative, ``inf``, ``nan``, too
            long: see ``check_delay``), naming ``what``.
    """
    raw = text.strip().lower()
    scale = 1.0
    for suffix, factor in (("us", 1e-6), ("ms", 1e-3), ("s", 1.0)):
        if raw.endswith(suffix):
            raw, scale = raw[: -len(suffix)], factor
            break
    try:
        value = float(raw) * scale
    except ValueError:
        raise InvalidArgument(f"{what} {text!r} is not a number of seconds (e.g. 0.02, 20ms, 100us)") from None
    return check_delay(what, value)  # (float() takes "inf" and "nan": no timer waits for either)


def _int(key: str, text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise InvalidArgument(f"sim URL: {key}={text!r} is not an integer") from None


def _log_size(key: str, text: str) -> int:
    """``log=``'s number of transactions, refused here in the URL's words: the line's own refusal names its Python
    argument, log_size, which a URL's user never typed."""
    try:
        size = int(text)
    except ValueError:
        size = -1  # (not a number: refused as one below zero is, in words that name all)
    if size < 0:
        raise InvalidArgument(
            f"sim URL: {key}={text!r}: the log keeps a whole number of transactions >= 0 (0: no log; all: every one)"
        )
    return size


def parse_line_ids(text: str) -> list[int]:
    """The servo IDs a simulated line holds, as ``ids=`` and ``ics35 sim --ids`` take them: ``0-31`` /
    ``1,3,5-7``, or ``none`` for a line without servos (what a scan of an empty line meets).

    Raises:
        InvalidArgument: not IDs 0..31 nor ``none``; or no IDs at all (``ids=``, a script's unset variable):
            a line without servos is asked for in words, since every command on one times out.
    """
    if text.strip().lower() == "none":
        return []
    ids = parse_ids(text)
    if not ids:
        raise InvalidArgument("no IDs given: write IDs 0..31 (e.g. 0-31 or 1,3,5-7), or none for a line without servos")
    return ids


def _ids(key: str, text: str, parse: Callable[[str], list[int]] = parse_ids) -> list[int]:
    """``parse(text)``, the IDs given to the URL's ``key``; an error naming the key and the value as written."""
    try:
        return parse(text)
    except InvalidArgument as exc:
        raise InvalidArgument(f"sim URL: {key}={text!r}: {exc}") from None


def parse_url(url: str) -> tuple[str | None, dict[str, Any]]:
    """Split ``url``, a ``sim://[NAME][?key=value&...]`` URL, into a name and VirtualLine options.

    Keys: ``ids`` (servo IDs, ``0-31`` / ``1,3,5-7``, default 0-31; ``none``: no servos; none given: refused),
    ``baud`` (default 115200), ``realtime``, ``echo``, ``follow_baud``
    (1/0), ``seed``, ``faults`` (:mod:`.faults` syntax), ``turnaround``,
    ``eeprom_delay``, ``late_delay``, ``tail_delay``, ``unplug_after``,
    ``replug_after`` (seconds; ``20ms`` / ``100us`` suffixes allowed; each finite, at most what a timer can
    wait; ``replug_after`` defaults to 0.2 s),
    ``tail_bytes`` (how many bytes the ``tail`` fault holds back),
    ``ics36`` (IDs of servos that speak ICS 3.6 and answer its position
    read; the others are ICS 3.5; IDs among ``ids``), ``noisy`` (IDs among ``ids`` of servos whose reported
    position jumps up to 135 degrees either side of where they are at each
    reply, no two of 25 in a row agreeing: a broken potentiometer), ``memory`` (IDs of zero-filled generic
    memory devices), ``log`` (log
    size, ``all`` for unbounded), ``record`` (file to record to), ``replay``
    (a recording to serve instead of a simulated line), ``adapter`` (``ftdi``:
    the USB adapter model of :mod:`.adapter`; it implies ``realtime=1``, since
    what it models is time the host waits) with ``latency_timer`` (ms,
    1..255, default 16).

    Raises:
        InvalidArgument: not a ``sim://`` URL, an unknown key, or a value that is not what its key takes.
    """
    parts = urlsplit(url)
    if parts.scheme != "sim":
        raise InvalidArgument(f"not a sim:// URL: {url!r}")
    name = url_name(url)  # (None: an unnamed line, one of its own at each opening)
    query = parse_qs(parts.query, keep_blank_values=True, strict_parsing=False)
    options: dict[str, Any] = {}
    for key, values in query.items():
        if len(values) != 1:
            raise InvalidArgument(f"sim URL: {key} given more than once")
        value = values[0]
        if key == "ids":
            options["servos"] = _ids(key, value, parse_line_ids)
        elif key == "baud":
            options["baudrate"] = BaudRate.parse(value)
        elif key in ("realtime", "echo"):
            options[key] = _flag(key, value)
        elif key == "follow_baud":
            options["follow_host_baud"] = _flag(key, value)
        elif key == "seed":
            options["seed"] = _int(key, value)
        elif key == "faults":
            options["faults"] = FaultConfig.parse(value)
        elif key == "turnaround":
            options["turnaround"] = parse_seconds(value, key)
        elif key == "eeprom_delay":
            options["eeprom_write_delay"] = parse_seconds(value, key)
        elif key == "tail_bytes":
            options[key] = _int(key, value)
        elif key in ("late_delay", "tail_delay", "unplug_after", "replug_after"):
            options[key] = parse_seconds(value, key)
        elif key in ("ics36", "noisy"):
            options[key] = _ids(key, value)
        elif key == "memory":
            options["memory"] = {i: b"" for i in _ids(key, value)}
        elif key == "log":
            options["log_size"] = None if value == "all" else _log_size(key, value)
        elif key in ("record", "replay", "adapter"):
            options[key] = value
        elif key == "latency_timer":
            options[key] = _int(key, value.strip().lower().removesuffix("ms"))
        else:
            raise InvalidArgument(f"sim URL: unknown option {key!r}")
    if "adapter" in options or "latency_timer" in options:
        adapter = make_adapter(options.pop("adapter", None), options.pop("latency_timer", None))
        if options.get("realtime") is False:
            raise InvalidArgument("sim URL: adapter= models the time the host waits: it needs realtime=1")
        options["adapter"] = adapter
        options["realtime"] = True
    others = sorted(key for key in query if key != "replay")
    if "replay" in query and others:
        raise InvalidArgument(f"sim URL: replay= takes no other options, got {', '.join(others)}")
    return name, options
