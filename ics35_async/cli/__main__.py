"""``python -m ics35_async.cli``: the same as the ``ics35`` command."""

from . import main

main()
