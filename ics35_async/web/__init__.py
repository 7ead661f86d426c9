"""``ics35 web``: the servo configurator in the browser (install with ``pip install 'ics35_async[web]'``).

A Starlette app served by uvicorn, with a front end of our own (plain
HTML, CSS and JavaScript in ``static/``).  Modules: :mod:`.security` (the
token, the cookie, the Origin and Host checks), :mod:`.config` (how the
line opens), :mod:`.traffic` (the last transactions), :mod:`.views`
(results as JSON), :mod:`.edits` (what a page asks a write to do),
:mod:`.live` (the plotted stream), :mod:`.session` (the line and every
action, through the library's policies), :mod:`.joints` (the Robot page,
through :class:`~ics35_async.robot.Robot`), :mod:`.api` (HTTP and WebSocket
handlers), :mod:`.server` (the app and running it).  Nothing imports this
package but ``ics35 web``.
"""

from __future__ import annotations

from .config import LineConfig
from .security import load_token, new_token
from .server import Listen, create_app, serve
from .session import LineSession

__all__ = ["LineConfig", "LineSession", "Listen", "create_app", "load_token", "new_token", "serve"]
