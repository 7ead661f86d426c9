"""Bounded number types for the commands' options, refused in words a user reads at once.

Light (click only): the line options every command shares use them, and ``ics35 --version`` loads those.
"""

from __future__ import annotations

import math
from typing import Any

import click


class Number(click.FloatRange):
    """A number from ``min`` to ``max``, refused in words: click's own say "'x' is not a valid float range." and
    "9.0 is not in the range 0.001<=x<=5.0."."""

    name = "number"
    WHOLE = False  # (a whole number is asked for: "'2.5' is not a whole number")

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            number: float = value
        else:
            text = str(value).strip()
            try:
                # (Python also reads "1_0" as 10 and other scripts' digits: a mistyped "1-0" would be taken)
                if not text.isascii() or "_" in text:
                    raise ValueError(text)
                number = int(text) if self.WHOLE else float(text)
            except ValueError:
                number = math.nan
            if not math.isfinite(number):  # ("nan" compares as within every range; "inf" is no seconds or count)
                self.fail(f"{value!r} is not a {'whole ' if self.WHOLE else ''}number", param, ctx)
        low, high = self.min, self.max
        below = low is not None and (number <= low if self.min_open else number < low)
        above = high is not None and (number >= high if self.max_open else number > high)
        if below or above:
            unit = " seconds" if param is not None and getattr(param, "metavar", None) == "SECONDS" else ""
            self.fail(f"must be {self._bounds_in_words()}{unit}, not {value}", param, ctx)
        return number

    def _describe_range(self) -> str:  # (click's help shows it: "0.0<=x<=5.0" before)
        return self._bounds_in_words()

    def _bounds_in_words(self) -> str:
        low, high = self.min, self.max
        if low is not None and high is not None and not (self.min_open or self.max_open):
            return f"{low:g}..{high:g}"
        said = []
        if low is not None:
            said.append(f"{'above' if self.min_open else 'at least'} {low:g}")
        if high is not None:
            said.append(f"{'below' if self.max_open else 'at most'} {high:g}")
        return " and ".join(said)


class WholeNumber(Number):
    """A whole number from ``min`` to ``max``, refused in words (see :class:`Number`)."""

    name = "integer"  # (its metavar in the help, as click's own)
    WHOLE = True
