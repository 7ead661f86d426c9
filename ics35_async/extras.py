"""How to install an optional extra (``web``, ``plot``, ``uvloop``, ``trio``), said the way this copy was installed:
what ``ics35 web``, ``--plot`` and :func:`ics35_async.run` say when the extra they need is missing.

A clone installed with ``pip install -e .`` gets its extras from the clone, not from the
package index: ``pip install 'ics35_async[web]'`` there would fetch a second copy.  pip
records an editable install in the distribution's ``direct_url.json`` (PEP 610).
"""

from __future__ import annotations

import json
import shlex
from importlib import metadata
from pathlib import Path
from typing import Literal
from urllib.parse import unquote, urlparse
from urllib.request import url2pathname

DISTRIBUTION = "ics35_async"

Installed = tuple[Literal["editable", "package", "unknown"], Path | None]


def installed_from() -> Installed:
    """``("editable", the clone)`` for ``pip install -e``, ``("package", None)`` for a wheel or sdist, and
    ``("unknown", None)`` when no installed distribution is found (the code run from a source tree)."""
    # Installations only: a build's ics35_async.egg-info in a checkout, first on the path when the code runs from
    # there, records none (no INSTALLER): taken for one, an editable install was told as a package.
    installed = [d for d in metadata.distributions(name=DISTRIBUTION) if d.read_text("INSTALLER") is not None]
    if not installed:
        return "unknown", None
    records = [d.read_text("direct_url.json") for d in installed]
    recorded = next((r for r in records if r), None)
    try:
        direct = json.loads(recorded) if recorded else {}
    except ValueError:
        return "package", None
    url = urlparse(str(direct.get("url", "")))
    if isinstance(direct.get("dir_info"), dict) and direct["dir_info"].get("editable") and url.scheme == "file":
        return "editable", Path(url2pathname(unquote(url.path)))
    return "package", None


def install_command(extra: str, installed: Installed) -> str:
    """The pip command that adds ``extra`` to this installation."""
    how, clone = installed
    if how == "editable" and clone is not None:
        return f"pip install -e {shlex.quote(f'{clone}[{extra}]')}"
    from_index = f"pip install '{DISTRIBUTION}[{extra}]'"
    if how == "package":
        return from_index
    return f"{from_index}  (in a clone: pip install -e '.[{extra}]')"


def extra_hint(extra: str) -> str:
    """The command that installs ``extra`` here (see :func:`install_command`)."""
    return install_command(extra, installed_from())
