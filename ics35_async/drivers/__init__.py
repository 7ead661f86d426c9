"""Drivers: what moves bytes and time between a :class:`~ics35_async.engine.LineEngine` and the world.

:mod:`.core` acts on the engine's answers in one place (the port lost and reopened, idle waiters, the drain
on close); each driver adds only its way of waiting: :mod:`.asyncio_driver` (the event loop's I/O
callbacks), :mod:`.thread_driver` (an I/O thread blocking on the port) and :mod:`.anyio_driver` (one bus
task; trio).  :mod:`.choice` picks one for a line, :mod:`.burst` runs a stream's transactions on the
compiled executor (``_burst``), :mod:`.clock` is the time they feed the engine and :mod:`.settings` what
they know of a line beyond the engine's settings.

Nothing is imported here: a driver loads when a line opens, so importing the library stays cheap.
"""
