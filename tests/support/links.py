"""Lines on another machine, on loopback: a plain TCP bridge and an RFC 2217 server in front of a serial port.

* :class:`TcpBridge` forwards a TCP connection to a serial port byte for byte
  (what ser2net's raw mode or ``socat TCP-LISTEN:... /dev/ttyUSB0`` do): the
  client's baud rate and parity stay on the client, the port runs at the
  bridge's own settings.
* :class:`Rfc2217Bridge` is pyserial's own RFC 2217 server side
  (:class:`serial.rfc2217.PortManager`, as in pyserial's ``rfc2217_server.py``
  example): the client's baud rate and parity are applied to the port.

Both serve the simulator's pty (``python -m ics35_async.sim``) in the tests,
listen on 127.0.0.1 only, serve one client at a time, and can be stopped
(connections dropped, nothing listening: refused) and started again on the
same TCP port.  ``port_settings`` records every (baud rate, parity) the far
end's port was set to, ``input_purges`` how many times its input was dropped.
"""

from __future__ import annotations

import contextlib
import errno
import socket
import threading
from collections.abc import Callable
from typing import Any

import serial
import serial.rfc2217

try:
    import termios
except ImportError:  # pragma: no cover - these bridges serve ptys, which only POSIX has
    termios = None  # type: ignore[assignment]


class FarEndPort(serial.Serial):  # type: ignore[misc]
    """The bridge's serial port; records the settings it is given and counts the purges of its input.

    Served by a pty, which keeps no parity: Linux clears PARENB and glibc's
    ``tcsetattr`` then reports EINVAL although everything else was applied,
    so that error is taken as success here (a real port would apply EVEN).
    A pty has no modem lines either: they read as off and setting them does
    nothing (pyserial's RFC 2217 server reports and sets them).
    """

    cts = dsr = ri = cd = False

    def _update_rts_state(self) -> None:
        pass

    def _update_dtr_state(self) -> None:
        pass

    def __init__(self, *args: Any, record: list[tuple[int, str]], **kwargs: Any) -> None:
        self.port_settings = record  # appended to as settings are applied
        self.input_purges = 0  # the bridge's own on each connection, and an RFC 2217 client's
        super().__init__(*args, **kwargs)

    def reset_input_buffer(self) -> None:
        self.input_purges += 1
        super().reset_input_buffer()

    def _reconfigure_port(self, force_update: bool = False) -> None:
        try:
            super()._reconfigure_port(force_update)
        except termios.error as exc:
            if exc.args[0] != errno.EINVAL:
                raise
        self.port_settings.append((int(self.baudrate), str(self.parity)))


class _Bridge:
    """A loopback TCP server for one client at a time in front of a serial port kept open throughout.

    One thread reads the port and sends to the current client (bytes with no
    client are dropped); one thread accepts a client and feeds the port what
    it sends.  Subclasses say how bytes are framed each way.
    """

    def __init__(self, device: str, *, baudrate: int = 115200, tcp_port: int = 0) -> None:
        self.device = device
        self.baudrate = baudrate
        self.tcp_port = tcp_port
        self.connections = 0
        self.port_settings: list[tuple[int, str]] = []
        self._listener: socket.socket | None = None
        self._conn: socket.socket | None = None
        self._to_client: Callable[[bytes], bytes] = bytes
        self._serial: FarEndPort | None = None
        self._threads: list[threading.Thread] = []
        self._lock = threading.Lock()

    @property
    def input_purges(self) -> int:
        return self._serial.input_purges if self._serial is not None else 0

    @property
    def host_port(self) -> str:
        return f"127.0.0.1:{self.tcp_port}"

    def start(self) -> None:
        # The port stays open across connections, as a bridge configured to hold it would.
        port = FarEndPort(self.device, self.baudrate, timeout=0.05, record=self.port_settings)
        self._serial = port
        listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        listener.bind(("127.0.0.1", self.tcp_port))
        listener.listen(1)
        self.tcp_port = listener.getsockname()[1]
        self._listener = listener
        self._threads = [
            threading.Thread(target=self._accept_loop, args=(listener, port), daemon=True, name="bridge accept"),
            threading.Thread(target=self._port_loop, args=(port,), daemon=True, name="bridge port reader"),
        ]
        for thread in self._threads:
            thread.start()

    def stop(self) -> None:
        """Drop the connection, stop listening (connections are refused) and close the port."""
        listener, self._listener = self._listener, None
        if listener is not None:
            with contextlib.suppress(OSError):
                listener.shutdown(socket.SHUT_RDWR)
            listener.close()
        self._drop()
        port, self._serial = self._serial, None
        for thread in self._threads:
            thread.join(5)
        self._threads = []
        if port is not None:
            port.close()

    def _drop(self) -> None:
        with self._lock:
            conn, self._conn = self._conn, None
        if conn is not None:
            with contextlib.suppress(OSError):
                conn.shutdown(socket.SHUT_RDWR)
            conn.close()

    def __enter__(self) -> _Bridge:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _port_loop(self, port: FarEndPort) -> None:
        """Serial -> the current client, until the bridge stops."""
        while self._serial is port:
            try:
                data = port.read(port.in_waiting or 1)
            except (OSError, serial.SerialException):
                return
            with self._lock:
                conn, frame = self._conn, self._to_client
                if data and conn is not None:
                    with contextlib.suppress(OSError):
                        conn.sendall(frame(data))

    def _accept_loop(self, listener: socket.socket, port: FarEndPort) -> None:
        while True:
            try:
                conn, _ = listener.accept()
            except OSError:
                return  # stopped
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self.connections += 1
            try:
                to_port = self._attach(conn, port)
                while True:
                    data = conn.recv(4096)
                    if not data:
                        break
                    port.write(to_port(data))
            except OSError:
                pass
            finally:
                self._drop()

    def _send(self, data: bytes) -> None:
        """To the current client, as it is (protocol replies)."""
        with self._lock:
            if self._conn is not None:
                with contextlib.suppress(OSError):
                    self._conn.sendall(data)

    def _attach(self, conn: socket.socket, port: FarEndPort) -> Callable[[bytes], bytes]:
        """Make ``conn`` the client; return how its bytes become the port's."""
        raise NotImplementedError

    @property
    def url(self) -> str:
        """The URL a client opens to reach the port through this bridge."""
        raise NotImplementedError


class TcpBridge(_Bridge):
    """A raw TCP <-> serial forwarder: the client's baud rate and parity never reach the port."""

    @property
    def url(self) -> str:
        return f"socket://{self.host_port}"

    def _attach(self, conn: socket.socket, port: FarEndPort) -> Callable[[bytes], bytes]:
        port.reset_input_buffer()
        with self._lock:
            self._conn, self._to_client = conn, bytes
        return bytes


class Rfc2217Bridge(_Bridge):
    """pyserial's RFC 2217 server side in front of the port: baud rate and parity are the client's."""

    @property
    def url(self) -> str:
        return f"rfc2217://{self.host_port}"

    def _attach(self, conn: socket.socket, port: FarEndPort) -> Callable[[bytes], bytes]:
        bridge = self

        class Link:  # what PortManager writes its telnet negotiation through
            def write(self, data: bytes) -> None:
                bridge._send(data)

        port.reset_input_buffer()
        with self._lock:
            self._conn = conn
        manager = serial.rfc2217.PortManager(port, Link())
        with self._lock:
            self._to_client = lambda data: b"".join(manager.escape(data))
        return lambda data: b"".join(manager.filter(data))
