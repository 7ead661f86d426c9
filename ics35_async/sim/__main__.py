"""``python -m ics35_async.sim``: serve a simulated line on a pseudo-terminal."""

import sys

from .pty_server import main

sys.exit(main())
