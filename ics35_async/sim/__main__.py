"""``python -m ics35_async.sim``: serve a simulated line on a pseudo-terminal."""

import sys

from .server_cli import main

sys.exit(main())
