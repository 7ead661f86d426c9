"""A tap on the simulated line: a second pty that hears every byte on the wire once (POSIX only).

On hardware, a second adapter whose receive pin sits on a line another
controller drives hears the commands and the replies, each once (it sends
nothing, so there is no echo).  :class:`LineTap` gives a simulated line the
same listener: ``ics35 sniff --port PATH`` decodes what it hears.  Bytes pass
through as each transaction is processed, so they keep their order and the
gaps between transactions, but not the wire time inside one.  Nobody
listening: the bytes are lost, as on a wire.
"""

from __future__ import annotations

from pathlib import Path

from .model import LineModel
from .pty_port import PtyPort


class LineTap:
    """A pty at :attr:`path` (a symlink; a private temp dir unless ``link`` is given) hearing ``line``."""

    def __init__(self, line: LineModel, link: str | Path | None = None) -> None:
        self.port = PtyPort(link)
        self.port.open()
        self.dropped_bytes = 0
        line.add_tap(self.hear)

    @property
    def path(self) -> Path:
        return self.port.path

    def hear(self, data: bytes) -> None:
        port = self.port
        if port.master is None:
            return
        if not port.client_present:
            port.check_client()
        self.dropped_bytes += len(data) - port.write(data)

    def close(self) -> None:
        self.port.dispose()
