"""System tools some tests drive (TCP serial bridges): found on PATH, or installed where the test suite may.

A test that needs ``socat`` calls :func:`require_tool`.  When the tool is
missing and the suite runs as root or under CI (``CI=true``) on a Debian-like
system, it is installed with apt-get, as CI does for every run; otherwise the
test fails and says how to install it.  Never skipped: a skipped bridge test
would hide exactly the links it is there for.
"""

from __future__ import annotations

import os
import shutil
import subprocess

import pytest

PACKAGES = {"socat": "socat", "ser2net": "ser2net"}  # tool -> Debian package


def _apt_install(package: str) -> str:
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    command = ["apt-get", "install", "-y", "-q", "--no-install-recommends", package]
    done = subprocess.run(command, env=env, capture_output=True, text=True, timeout=600)
    if done.returncode != 0:  # no package lists yet (a fresh container): fetch them once, try again
        subprocess.run(["apt-get", "update", "-q"], env=env, capture_output=True, timeout=600)
        done = subprocess.run(command, env=env, capture_output=True, text=True, timeout=600)
    return done.stderr[-500:] if done.returncode else ""


def require_tool(tool: str) -> str:
    """The path of ``tool``, installing its package first if the suite may; else the test fails."""
    path = shutil.which(tool)
    if path is not None:
        return path
    package = PACKAGES[tool]
    may_install = os.environ.get("CI", "").lower() == "true" or (hasattr(os, "geteuid") and os.geteuid() == 0)
    problem = f"{tool} is not installed"
    if may_install and shutil.which("apt-get"):
        problem = _apt_install(package) or problem
        path = shutil.which(tool)
        if path is not None:
            return path
    pytest.fail(f"{problem}: this test needs it (Debian/Ubuntu: sudo apt-get install {package})", pytrace=False)
