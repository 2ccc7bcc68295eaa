"""Free loopback ports and unique robot names for tests (and benchmarks) that start Zenoh parts.

Imported by name (tests/ is not a package; pytest's prepend mode puts this folder on ``sys.path``).
Random ports collided: ``randint(20000, 60000)`` overlaps the kernel's ephemeral range, so another
test's outgoing connection or a second run could hold the port. The kernel's own pick of a free port
cannot be taken at that moment; it is released at once for the Zenoh listener that will bind it.
"""

from __future__ import annotations

import socket
import uuid


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing holds now (the kernel picks it; the socket is closed)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def free_endpoint() -> str:
    """A Zenoh endpoint on a free loopback port: one listener (a hub, a router) may bind it once."""
    return f"tcp/127.0.0.1:{free_port()}"


def unique_name(prefix: str) -> str:
    """A robot name no other test or run uses: its Zenoh keys (``adaptiveh/<name>/…``) are private."""
    return f"{prefix}{uuid.uuid4().hex[:12]}"
