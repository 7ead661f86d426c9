"""System tools some tests drive (a TCP serial bridge): found on PATH, or the test fails naming the fix.

``make tools`` installs them (``make``'s setup does, like the browser), never a test: a test that
installs software changes the machine it is checking and makes its own time depend on a package mirror.
Never skipped either: a skipped bridge test would hide exactly the links it is there for.
"""

from __future__ import annotations

import shutil

import pytest

PACKAGES = {"socat": "socat"}  # tool -> Debian package


def require_tool(tool: str) -> str:
    """The path of ``tool``; if it is missing, the test fails and says how to install it."""
    path = shutil.which(tool)
    if path is None:
        pytest.fail(
            f"{tool} is not installed and this test needs it: run `make tools` "
            f"(as root on Debian/Ubuntu; or sudo apt-get install {PACKAGES[tool]})",
            pytrace=False,
        )
    return path
