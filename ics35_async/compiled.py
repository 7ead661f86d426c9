"""Whether this install runs its engine compiled: what ``ics35 --version -v`` and ``ics35 doctor`` say.

The package's build compiles the engine's rules (the modules every transaction runs through) with mypyc where
it can (mypy and a C compiler at hand, not Windows; ``ICS35_COMPILE=0`` turns it
off; see ``setup.py``).  The same Python source runs either way: compiled, a stream on the burst path costs
5-10 % less CPU (``benchmarks/bench_burst.py``).
"""

from __future__ import annotations

import importlib.machinery

from .engine import link, machine

ENGINE_NAME = "compiled engine"
"""What ``--version -v`` and doctor call it."""


def _is_extension(path: str | None) -> bool:
    return path is not None and path.endswith(tuple(importlib.machinery.EXTENSION_SUFFIXES))


def engine_compiled() -> tuple[bool, str]:
    """Whether the engine's rules run compiled by mypyc, and what that means, in plain words (after
    :data:`ENGINE_NAME`)."""
    compiled = [_is_extension(module.__file__) for module in (machine, link)]
    if all(compiled):
        return True, "on (the engine's rules compiled by mypyc)"
    if any(compiled):  # (a build in place left one module compiled beside the other's new source)
        return False, "partly: rebuild the package (one of the engine's modules is compiled, another is not)"
    return False, (
        "off (the engine runs as plain Python: the package was built without mypy, "
        "with ICS35_COMPILE=0, or in place for development)"
    )
