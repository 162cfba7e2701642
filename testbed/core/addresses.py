"""Whether an address is this machine's own: one answer for every room that asks.

Why shared: the YuMi driver takes ABB's factory login only from a controller on loopback
(the hardware twin), and the web console serves plain http only on loopback; both must
agree on what loopback is (``localhost``, 127.0.0.0/8, ``::1``), so it is said once here.
"""

from __future__ import annotations

import ipaddress

__all__ = ["is_loopback_host"]


def is_loopback_host(host: str) -> bool:
    """Whether ``host`` (a name or an address, no port) is this machine only."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False
