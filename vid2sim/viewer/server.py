"""The viser server: binds the requested port or fails with PortInUse (viser itself would move to
the next free port, and the printed URL would then be wrong)."""

from __future__ import annotations

import errno
import socket

import viser

from vid2sim.viewer.errors import PortInUse, ViewerError

DEFAULT_PORT = 8080


def check_port_free(host: str, port: int) -> None:
    """Raise PortInUse when (host, port) cannot be bound."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as the server binds: ignores TIME_WAIT
        try:
            s.bind((host, port))
        except OSError as e:
            if e.errno in (errno.EADDRINUSE, errno.EACCES):
                raise PortInUse(f"port {port} on {host} is in use (choose another with --port N)") from None
            raise ViewerError(f"cannot listen on {host}:{port} ({e.strerror})") from None


def start_server(host: str = "127.0.0.1", port: int = DEFAULT_PORT, label: str = "vid2sim") -> viser.ViserServer:
    """A running viser server on exactly (host, port), z up."""
    check_port_free(host, port)
    server = viser.ViserServer(host=host, port=port, label=label, verbose=False)
    if server.get_port() != port:  # taken between the check and the bind
        server.stop()
        raise PortInUse(f"port {port} on {host} is in use (choose another with --port N)")
    server.scene.set_up_direction("+z")
    return server


def url(server: viser.ViserServer) -> str:
    host = server.get_host()
    return f"http://{'localhost' if host in ('0.0.0.0', '127.0.0.1') else host}:{server.get_port()}"
