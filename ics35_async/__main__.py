"""``python -m ics35_async``: the same as the ``ics35`` command (and ``python -m ics35_async.cli``)."""

from .cli import main

main()
