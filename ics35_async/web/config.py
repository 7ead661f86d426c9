"""How the configurator opens its line."""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass

from ..bus import MISSING_AS_IT_OPENS
from ..eeprom import FACTORY_BAUD
from ..errors import error_text
from ..protocol import ADAPTER_LATENCY, TOOL_RETRIES
from ..transports.wire_device import opens_anew, url_scheme


@dataclass(frozen=True)
class LineConfig:
    """How to open the line (the CLI's line options)."""

    port: str = "sim://"
    baud: int = FACTORY_BAUD
    echo: bool = True
    adapter_latency: float = ADAPTER_LATENCY
    retries: int = TOOL_RETRIES
    transport: str = "auto"
    direction: str = "none"

    @property
    def is_sim(self) -> bool:
        return url_scheme(self.port) == "sim"

    @property
    def url(self) -> str:
        """An unnamed ``sim://`` gets a name, so every reopening (scan at each rate) finds the same servos;
        one of its own for each set of options (``sim://?ids=5`` is not the ``sim://`` opened before it)."""
        if not opens_anew(self.port):
            return self.port
        from ..sim.url import named_url, url_options  # (the simulator loads only for a sim:// line)

        digest = hashlib.sha1(url_options(self.port).encode(), usedforsecurity=False).hexdigest()[:8]
        return named_url(self.port, f"ics35-web-{os.getpid()}-{digest}")


def said_on_the_page(exc: BaseException, missing: str) -> str:
    """``exc``'s words, a port missing as the configurator opens it told with ``missing`` instead of the library's
    words for it: the configurator opens with ``reconnect=True`` (its docs say the line comes back by itself), so
    a person expects a wait for an adapter not plugged in yet too, and "open it again" is a button here."""
    return error_text(exc).replace(MISSING_AS_IT_OPENS, missing)
