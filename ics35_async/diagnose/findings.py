"""One thing a diagnosis found: the problem, in a person's words, and the fix."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Literal

Severity = Literal["error", "warning", "info"]


@dataclass(frozen=True)
class Finding:
    """``check``: which check found it; ``severity``: ``error`` (stops work), ``warning`` (slows or risks
    it), ``info``; ``fix``: what to run or do (empty when there is nothing to do)."""

    check: str
    severity: Severity
    problem: str
    fix: str = ""

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)
