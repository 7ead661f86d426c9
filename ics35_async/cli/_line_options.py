"""The line options (--port, --baud, --timeout, ...): taken before the command, and after it as well.

The group declares them with their defaults and environment variables; every
command gets a copy without a default, whose value (when given) overrides the
group's in the shared :class:`Settings`, so ``ics35 scan --port X`` and
``ics35 --port X scan`` mean the same.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, TypeVar

import click

from ..eeprom import FACTORY_BAUD
from ..protocol.wire import ADAPTER_LATENCY, ALL_BAUDS, MAX_RETRIES, TOOL_RETRIES
from ._numbers import Number, WholeNumber
from ._settings import DEFAULT_PORT, Settings, setup_logging

F = TypeVar("F", bound=Callable[..., Any])


@dataclass(frozen=True)
class LineOption:
    name: str  # the Settings attribute (and the group callback's parameter)
    decls: tuple[str, ...]
    help: str
    group_kwargs: dict[str, Any] = field(default_factory=dict)  # default, envvar, show_default
    kwargs: dict[str, Any] = field(default_factory=dict)  # type, is_flag, count: the same before and after


LINE_OPTIONS = (
    LineOption(
        "port",
        ("--port", "-p"),
        "Serial device (/dev/ttyUSB0, /dev/cu.usbserial-..., COM3; see: ics35 ports), pyserial URL "
        "(rfc2217://host:port, socket://host:port), or sim://[?ids=..] for the built-in simulator.",
        {"default": DEFAULT_PORT, "show_default": True, "envvar": "ICS35_PORT"},
    ),
    LineOption(
        "baud",
        ("--baud", "-b"),
        "Line baud rate (625000 and 1250000 need the ICS USB adapter HS).",
        {"default": str(FACTORY_BAUD), "show_default": True, "envvar": "ICS35_BAUD"},
        {"type": click.Choice([str(b) for b in ALL_BAUDS])},
    ),
    LineOption(
        "timeout",
        ("--timeout",),
        "Seconds allowed on top of the wire time for each reply (USB adapter latency).",
        {"default": ADAPTER_LATENCY, "show_default": True},
        {"type": Number(0.0, 5.0), "metavar": "SECONDS"},
    ),
    LineOption(
        "retries",
        ("--retries",),
        "Retries for reads and positions.",
        {"default": TOOL_RETRIES, "show_default": True},
        {"type": WholeNumber(0, MAX_RETRIES)},
    ),
    LineOption(
        "no_echo",
        ("--no-echo",),
        "The interface does not loop sent bytes back (no echo to skip).",
        kwargs={"is_flag": True},
    ),
    LineOption(
        "direction",
        ("--direction",),
        "DIY half-duplex interface: the serial driver raises RTS while sending (rts), or lowers it "
        "(rts-inverted). Needs a driver with RS-485 mode; ICS adapters need none.",
        {"default": "none", "show_default": True},
        {"type": click.Choice(["none", "rts", "rts-inverted"])},
    ),
    LineOption(
        "transport",
        ("--transport",),
        "How a serial port is read: on its descriptor (auto, direct: device paths) or by a thread.",
        {"default": "auto", "show_default": True},
        {"type": click.Choice(["auto", "direct", "thread"])},
    ),
    LineOption(
        "verbose",
        ("--verbose", "-v"),
        "Log bus activity to stderr (-vv: every byte).",
        kwargs={"count": True},
    ),
)


class _NamesItsVariable(click.ParamType):  # type: ignore[type-arg]  # generic from click 8.3 on
    """A line option's type that, for a bad value from the environment, names the variable it came from."""

    def __init__(self, inner: click.ParamType, envvar: str) -> None:  # type: ignore[type-arg]
        self.inner = inner
        self.envvar = envvar
        self.name = inner.name

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        try:
            return self.inner.convert(value, param, ctx)
        except click.BadParameter as exc:
            source = ctx.get_parameter_source(param.name) if ctx is not None and param is not None else None
            if source is click.core.ParameterSource.ENVIRONMENT and param is not None:
                message = f"{exc.message.rstrip('.')} (from {self.envvar}={value})"
                raise click.BadParameter(message, ctx, param) from None
            raise

    def get_metavar(self, param: click.Parameter, ctx: click.Context) -> str | None:
        return self.inner.get_metavar(param, ctx)


def group_line_options(f: F) -> F:
    """Decorate the group with the line options, defaults and environment variables included."""
    for option in reversed(LINE_OPTIONS):
        kwargs = dict(option.kwargs)
        envvar = option.group_kwargs.get("envvar")
        if envvar and isinstance(kwargs.get("type"), click.ParamType):
            kwargs["type"] = _NamesItsVariable(kwargs["type"], envvar)
        f = click.option(*option.decls, option.name, help=option.help, **option.group_kwargs, **kwargs)(f)
    return f


def settings_from(ctx: click.Context, values: dict[str, Any]) -> Settings:
    """The group's Settings from its parsed line options."""
    setup_logging(values["verbose"])
    return Settings(
        port=values["port"],
        baud=int(values["baud"]),
        timeout=values["timeout"],
        retries=values["retries"],
        echo=not values["no_echo"],
        transport=values["transport"],
        direction=values["direction"],
        verbose=values["verbose"],
        port_defaulted=ctx.get_parameter_source("port") is click.core.ParameterSource.DEFAULT,
        given=frozenset(
            option.name
            for option in LINE_OPTIONS
            if ctx.get_parameter_source(option.name)
            not in (None, click.core.ParameterSource.DEFAULT, click.core.ParameterSource.DEFAULT_MAP)
        ),
        from_environment=tuple(
            f"{option.group_kwargs['envvar']}={values[option.name]}"
            for option in LINE_OPTIONS
            if option.group_kwargs.get("envvar")
            and ctx.get_parameter_source(option.name) is click.core.ParameterSource.ENVIRONMENT
        ),
    )


def _store(name: str) -> Callable[[click.Context, click.Parameter, Any], None]:
    """The callback of a line option given after the command: override the group's value."""

    def store(ctx: click.Context, param: click.Parameter, value: Any) -> None:
        if value is None or value is False or (name == "verbose" and not value):
            return  # not given after the command: the group's value stands
        settings = ctx.find_object(Settings)
        if settings is None:
            return
        settings.given |= {name}
        if name == "port":
            settings.port = value
            settings.port_defaulted = False
            settings.from_environment = tuple(v for v in settings.from_environment if not v.startswith("ICS35_PORT="))
        elif name == "baud":
            settings.baud = int(value)
            settings.from_environment = tuple(v for v in settings.from_environment if not v.startswith("ICS35_BAUD="))
        elif name == "no_echo":
            settings.echo = False
        elif name == "verbose":
            settings.verbose = max(settings.verbose, value)
            setup_logging(settings.verbose)
        else:
            setattr(settings, name, value)

    return store


def add_line_options(command: click.Command) -> None:
    """Give ``command`` (and a group's subcommands) the line options it does not define itself.

    A command's own option of the same name wins (``scan --timeout`` is the
    reply allowance of the scan, which is what the line option means too).
    """
    taken = {opt for param in command.params for opt in (*param.opts, *param.secondary_opts)}
    for option in LINE_OPTIONS:
        if option.decls[0] in taken:
            continue
        decls = [d for d in option.decls if d not in taken]
        command.params.append(
            click.Option(
                decls,
                help=option.help,
                default=None,
                expose_value=False,
                callback=_store(option.name),
                **option.kwargs,
            )
        )
    if isinstance(command, click.Group):
        for sub in command.commands.values():
            add_line_options(sub)
