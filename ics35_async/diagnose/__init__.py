"""Diagnosis of a first day on real hardware: the machine's side (ports, drivers, rights, the USB
adapter's latency timer) and the line's (round trips, what they say about the adapter, the cycle rate).

:mod:`.system` reads system files from a root directory (``/`` by default,
a fake tree in tests); :mod:`.line_report` measures a line through a bus;
:mod:`.udev` writes the udev rules; :mod:`.findings` is what each finds, in words.  ``ics35 doctor`` and ``ics35 udev``
print what these find.
"""

from __future__ import annotations

from .findings import Finding

__all__ = ["Finding"]
