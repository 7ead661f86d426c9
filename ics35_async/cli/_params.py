"""Command-line argument types (IDs, ID lists, baud lists) and the options many commands share."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar

import click

from .. import protocol
from ..eeprom import BaudRate
from ..errors import InvalidArgument
from ..units import parse_ids
from ._settings import Settings

T = TypeVar("T")

ALL_BAUDS: tuple[int, ...] = tuple(int(b) for b in BaudRate)


def parse_id_list(text: str) -> list[int]:
    """``"1-12"``, ``"0,3,5-7"``, ``"all"`` -> sorted unique IDs; InvalidArgument on anything else (or nothing)."""
    if text.strip().lower() in ("all", "*"):
        return list(range(32))
    ids = parse_ids(text)
    if not ids:
        raise InvalidArgument("no IDs given")
    return ids


class ServoIdType(click.ParamType[int]):
    name = "ID"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> int:
        if isinstance(value, int) and not isinstance(value, bool):
            candidate: object = value
        else:
            try:
                candidate = int(str(value), 10)
            except ValueError:
                self.fail(f"{value!r} is not a servo ID (0..31)", param, ctx)
        try:
            return protocol.check_id(candidate)
        except InvalidArgument:
            self.fail(f"servo ID must be 0..31, got {candidate}", param, ctx)


class IdListType(click.ParamType[list[int]]):
    name = "IDS"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> list[int]:
        if isinstance(value, list):
            return value
        try:
            return parse_id_list(str(value))
        except InvalidArgument as exc:
            self.fail(f"{exc} (IDs are 0..31; write e.g. 3, 1-12, 0,4,7 or all)", param, ctx)


class BaudListType(click.ParamType[list[int]]):
    name = "BAUDS"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> list[int]:
        if isinstance(value, list):
            return value
        bauds: list[int] = []
        for part in str(value).split(","):
            try:
                baud = int(BaudRate.parse(part.strip()))
            except InvalidArgument as exc:
                self.fail(str(exc), param, ctx)
            if baud not in bauds:
                bauds.append(baud)
        return bauds


SERVO_ID = ServoIdType()
ID_LIST = IdListType()
BAUD_LIST = BaudListType()


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
