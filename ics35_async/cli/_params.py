"""Command-line argument types (IDs, ID lists, baud lists) and the options many commands share."""

from __future__ import annotations

import difflib
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

import click

from .. import protocol
from ..eeprom import BaudRate
from ..errors import InvalidArgument
from ..protocol.wire import ALL_BAUDS as ALL_BAUDS  # (re-exported to the commands: _common)
from ..protocol.wire import ALL_IDS
from ..units import parse_id_list, plain_count
from ._numbers import Number
from ._settings import Settings

T = TypeVar("T")


def every_id(ids: Sequence[int] | None) -> bool:
    """IDS ``all`` (or 0-31): every servo there is, not 32 servos the user expects on the line (a command asks
    which answer, and those that do not are no failure)."""
    return ids is not None and set(ids) == set(ALL_IDS)


class ServoIdType(click.ParamType[int]):
    name = "ID"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> int:
        if isinstance(value, int) and not isinstance(value, bool):
            candidate: object = value
        else:
            number = plain_count(str(value).strip())
            if number is None:
                self.fail(f"{value!r} is not a servo ID (0..31)", param, ctx)
            candidate = number
        try:
            return protocol.check_id(candidate)
        except InvalidArgument:
            self.fail(f"servo ID must be 0..31, got {candidate}", param, ctx)


def parse_baud_list(text: str) -> list[int]:
    """``"115200,1250000"`` -> the rates, in order, each once; InvalidArgument for one that is not a rate."""
    bauds: list[int] = []
    for part in text.split(","):
        baud = int(BaudRate.parse(part.strip()))
        if baud not in bauds:
            bauds.append(baud)
    return bauds


class ListType(click.ParamType[list[int]]):
    """A list option: ``parse`` reads its text; an item it refuses fails the option with its error and ``hint``."""

    def __init__(self, name: str, parse: Callable[[str], list[int]], hint: str = "") -> None:
        self.name = name
        self._parse = parse
        self._hint = hint

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> list[int]:
        if isinstance(value, list):
            return value
        try:
            return self._parse(str(value))
        except InvalidArgument as exc:
            self.fail(f"{exc}{self._hint}", param, ctx)


class NegativeNumbersCommand(click.Command):
    """A command whose arguments may be written as negative numbers: values (``move 1 -30 --deg``, ``set 1 speed
    -5``), and IDs, whose own check then says what is wrong (``info -1``: "'-1' is not a servo ID (0..31)").

    Click takes ``-30`` for an option ("No such option '-1'") unless unknown options are let through, and then it
    lets a mistyped option through too: ``move --bogus`` said "'--bogus' is not a servo ID".  So only a number is
    let through: any other word that starts with a dash and is not one of the command's options (or a run of its
    one-letter flags) is refused as click refuses it elsewhere, with its near names.
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs["context_settings"] = {**(kwargs.get("context_settings") or {}), "ignore_unknown_options": True}
        super().__init__(*args, **kwargs)

    def parse_args(self, ctx: click.Context, args: list[str]) -> list[str]:
        self.check_arguments(ctx, self.arguments_given(ctx, args))  # (an unknown option refused first)
        return super().parse_args(ctx, args)

    def check_arguments(self, ctx: click.Context, arguments: list[str]) -> None:
        """A command's own look at its arguments (options and their values left out) before click parses them."""

    def arguments_given(self, ctx: click.Context, args: list[str]) -> list[str]:
        """The words of ``args`` that are arguments, not options nor their values; an unknown option is refused."""
        params = self.get_params(ctx)
        known = [name for p in params for name in (*p.opts, *p.secondary_opts)]
        # (an option that takes a value: not a flag, nor one that counts, as -v does)
        valued = {name for p in params if isinstance(p, click.Option) and not (p.is_flag or p.count) for name in p.opts}
        letters = {name[1] for name in known if len(name) == 2 and name[0] == "-" and name[1] != "-"}
        arguments: list[str] = []
        words = iter(args)
        for arg in words:
            if arg == "--":
                arguments.extend(words)  # (what follows is arguments only)
                break
            if arg in valued:
                next(words, None)  # (its value, whatever it looks like: -o -x.json)
                continue
            name = arg.partition("=")[0] if arg[:2] == "--" else arg
            if name[:1] != "-" or name == "-" or _is_number(name):
                arguments.append(arg)
                continue
            if name in known:
                continue
            if name[:2] != "--" and name[1] in letters:
                # One-letter options run together (-yq), the last may take a value: the rest of the word
                # (-b115200, -yb115200) or, if none is left, the next word (-yb 115200).
                for at, letter in enumerate(name[1:], 1):
                    if f"-{letter}" in valued:
                        if at == len(name) - 1:
                            next(words, None)
                        break
                    if letter not in letters:
                        raise click.NoSuchOption(f"-{letter}", ctx=ctx)
                continue
            raise click.NoSuchOption(name, possibilities=difflib.get_close_matches(name, known), ctx=ctx)
        return arguments


def _is_number(word: str) -> bool:
    """``-30``, ``-.5``, ``-1e2``: a number (the argument a command's own check then judges), not an option."""
    try:
        float(word)
    except ValueError:
        return False
    return True


SERVO_ID = ServoIdType()
ID_LIST = ListType("IDS", parse_id_list, " (write e.g. 3, 1-12, 0,4,7 or all)")
BAUD_LIST = ListType("BAUDS", parse_baud_list)


def _json_before_the_command(ctx: click.Context, param: click.Parameter, value: bool) -> bool:
    """``ics35 --json get 1 speed`` means ``ics35 get 1 speed --json``, as the line options do."""
    settings = ctx.find_object(Settings)
    return value or (settings is not None and settings.json_output)


def json_option(f: Callable[..., T]) -> Callable[..., T]:
    return click.option(
        "--json",
        "as_json",
        is_flag=True,
        callback=_json_before_the_command,
        help="Print machine-readable JSON on stdout.",
    )(f)


def yes_option(f: Callable[..., T]) -> Callable[..., T]:
    return click.option("--yes", "-y", is_flag=True, help="Do not ask for confirmation.")(f)


def all_ids_option(text: str) -> Callable[[Callable[..., T]], Callable[..., T]]:
    """``--ids`` for a command that looks along the whole line: every ID unless told fewer; ``text`` is the help."""
    return click.option("--ids", "ids", type=ID_LIST, default="all", show_default=True, help=text)


def choice_option(
    flag: str, choices: Sequence[str], default: str, text: str
) -> Callable[[Callable[..., T]], Callable[..., T]]:
    """``flag CHOICE``: one of the library's ``choices``, ``default`` shown; ``text`` is the help."""
    return click.option(flag, type=click.Choice(list(choices)), default=default, show_default=True, help=text)


def seconds_option(
    flag: str,
    text: str,
    *,
    low: float,
    high: float | None = None,
    default: float | None = None,
    above_low: bool = False,
) -> Callable[[Callable[..., T]], Callable[..., T]]:
    """``flag SECONDS``: a duration from ``low`` (or above it, with ``above_low``) to ``high``; ``text`` is
    the help; a default, when there is one, is shown."""
    return click.option(
        flag,
        type=Number(low, high, min_open=above_low),
        default=default,
        show_default=default is not None,
        metavar="SECONDS",
        help=text,
    )
