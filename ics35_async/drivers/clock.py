"""The clock every driver feeds the engine: time.monotonic.

Not the event loop's own: uvloop's ``loop.time()`` is whole milliseconds
cached per iteration, too coarse for latencies and reply timestamps; trio's
clock has its own offset.  On Linux asyncio's loop time is this same clock,
so deadlines can go to ``loop.call_at`` as they are.
"""

from __future__ import annotations

import time

now = time.monotonic
