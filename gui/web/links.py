"""What the web console prints so people reach it: its links' address and its lines.

Why a module of its own (issue 44): the links must name the machine as others reach it
(``public_url``: its name, a tunnel's end, a reverse proxy's address with its path
prefix), never a wildcard bind address no browser can use, and the lines printed at
start say which link is whose (each person's, the read-only overview to share, the
operator's with pause and stop), the certificate's fingerprint when the console serves
https, and that a resumed trial kept its links (docs/notes/web.md, "Reaching the
console").
"""

from __future__ import annotations

from collections.abc import Sequence

__all__ = ["link_base", "link_lines"]


def link_base(base_url: str, public_url: str | None) -> str:
    """What the printed links start with: ``public_url`` as the lab gives it (the name
    others reach this machine by, a tunnel's or a reverse proxy's address with its path
    prefix), else the server's own address with a wildcard bind (0.0.0.0, ::) replaced by
    this machine's name, which a browser elsewhere can use (the bind address cannot)."""
    if public_url:
        return public_url.rstrip("/")
    import socket
    from urllib.parse import urlsplit, urlunsplit

    parts = urlsplit(base_url)
    if parts.hostname in ("0.0.0.0", "::"):
        port = f":{parts.port}" if parts.port else ""
        return urlunsplit((parts.scheme, f"{socket.getfqdn()}{port}", "", "", ""))
    return base_url


def link_lines(labels: Sequence[str], urls: Sequence[str], overview_url: str,
               operator_url: str, fingerprint: str | None, self_signed: bool,
               resumed_at: int | None) -> list[str]:
    """The lines printed once at start: each person's link by their label, the overview
    to share, the operator's, the certificate (self-signed: to compare with what the
    browser shows), and the resume."""
    lines = [f"web console: {label}: {u}" for label, u in zip(labels, urls, strict=True)]
    lines.append(f"web console: fleet overview (to watch; share it): {overview_url}")
    lines.append(f"web console: operator (pause and stop; keep it to yourself): "
                 f"{operator_url}")
    if fingerprint is not None:
        kind = ("self-signed: compare it with what the browser shows before accepting it"
                if self_signed else "the lab's")
        lines.append(f"web console: https, certificate SHA-256 {fingerprint} ({kind})")
    if resumed_at is not None:
        lines.append(f"web console: resumed at step {resumed_at}: the links are the ones "
                     f"given at the trial's start")
    return lines
