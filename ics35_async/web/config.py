"""How the configurator opens its line."""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass

from ..transports.wire_device import url_scheme


@dataclass(frozen=True)
class LineConfig:
    """How to open the line (the CLI's line options)."""

    port: str = "sim://"
    baud: int = 115200
    echo: bool = True
    adapter_latency: float = 0.020
    retries: int = 1
    transport: str = "auto"
    direction: str = "none"

    @property
    def is_sim(self) -> bool:
        return url_scheme(self.port) == "sim"

    @property
    def url(self) -> str:
        """An unnamed ``sim://`` gets a name, so every reopening (scan at each rate) finds the same servos;
        one of its own for each set of options (``sim://?ids=5`` is not the ``sim://`` opened before it)."""
        options = self.port.partition("://")[2]
        if self.is_sim and (not options or options.startswith("?")):
            from ..sim.url import url_options  # (the simulator loads only for a sim:// line)

            digest = hashlib.sha1(url_options(self.port).encode(), usedforsecurity=False).hexdigest()[:8]
            return f"sim://ics35-web-{os.getpid()}-{digest}{options}"
        return self.port
