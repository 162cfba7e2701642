"""HTTP digest authentication (RFC 7616 / 2617, MD5, qop=auth) and RobotWare 6's sessions.

Why it exists: a real IRC5 answers every RWS request without credentials with ``401`` and
a digest challenge, and after the first authenticated request hands out a session (the
``-http-session-`` and ``ABBCX`` cookies). It holds at most 70 sessions at a time (RW6's
default); a client that never logs out leaks one per connection object, and the 71st is
refused with ``503``. The twin does the same, with the limit a parameter, so a leak shows
up in a test with three sessions instead of on day one with seventy.

The flow (what ``requests.auth.HTTPDigestAuth`` and ``curl --digest`` do):

1. A request with a live session cookie is the session's; ``Authorization`` is ignored.
2. Otherwise a valid ``Authorization: Digest ...`` opens a new session (or ``503`` when
   ``max_sessions`` are open) and the answer sets both cookies.
3. Otherwise: ``401`` with ``WWW-Authenticate: Digest realm=..., qop="auth", nonce=...``
   (``stale=true`` when the nonce was ours but expired).

Nonces stay valid for ``nonce_lifetime_s``; a literal replay (same nonce, nc and cnonce)
is refused. ``GET /logout`` ends the caller's session (the handler calls ``close``).
Sessions idle longer than ``idle_timeout_s`` (``None``: never) are dropped, as a real
controller drops them after its own idle time (the real value: see docs/rws-checklist.md).
"""

from __future__ import annotations

import hashlib
import hmac
import secrets
import threading
import time
import urllib.request
from collections import OrderedDict
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

REALM = "validusers@robapi.abb"
"""The realm RobotWare 6 announces (check yours: docs/rws-checklist.md)."""
DEFAULT_USERS = {"Default User": "robotics"}
SESSION_COOKIE = "-http-session-"
ABBCX_COOKIE = "ABBCX"
MAX_NONCES = 4096


def _md5(text: str) -> str:
    return hashlib.md5(text.encode("utf-8")).hexdigest()


def parse_digest(header: str) -> dict[str, str] | None:
    """The parameters of an ``Authorization: Digest ...`` header (quotes removed), or
    ``None`` when it is not a digest header."""
    scheme, _, rest = header.strip().partition(" ")
    if scheme.lower() != "digest" or not rest.strip():
        return None
    try:
        items = urllib.request.parse_http_list(rest)
        return {k.lower(): v for k, v in urllib.request.parse_keqv_list(items).items()}
    except ValueError:
        return None


@dataclass
class _Nonce:
    issued: float
    seen: set[tuple[str, str]] = field(default_factory=set)


class DigestAuthority:
    """Issues challenges and checks digest responses against the configured users."""

    def __init__(self, users: Mapping[str, str] | None = None, realm: str = REALM, *,
                 nonce_lifetime_s: float = 3600.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.users = dict(DEFAULT_USERS if users is None else users)
        self.realm = realm
        self.nonce_lifetime_s = float(nonce_lifetime_s)
        self._clock = clock
        self._lock = threading.Lock()
        self._nonces: OrderedDict[str, _Nonce] = OrderedDict()

    def challenge(self, stale: bool = False) -> str:
        """A fresh ``WWW-Authenticate`` value."""
        nonce = secrets.token_hex(16)
        with self._lock:
            self._nonces[nonce] = _Nonce(self._clock())
            while len(self._nonces) > MAX_NONCES:
                self._nonces.popitem(last=False)
        opaque = _md5(self.realm)
        return (f'Digest realm="{self.realm}", qop="auth", nonce="{nonce}", '
                f'opaque="{opaque}", algorithm=MD5, stale={"true" if stale else "false"}')

    def verify(self, method: str, uri: str, header: str | None) -> tuple[str | None, bool]:
        """``(user, stale)``: the authenticated user (``None`` when refused) and whether
        the refusal was only an expired nonce (the client should retry with a new one)."""
        p = parse_digest(header or "")
        if p is None or not all(p.get(k) for k in ("username", "nonce", "uri", "response")):
            return None, False
        user, nonce = p["username"], p["nonce"]
        if p.get("realm") != self.realm or p["uri"] != uri or user not in self.users:
            return None, False
        qop, nc, cnonce = p.get("qop", ""), p.get("nc", ""), p.get("cnonce", "")
        if qop != "auth" or not nc or not cnonce:
            return None, False
        with self._lock:
            record = self._nonces.get(nonce)
            if record is None:
                return None, False
            if self._clock() - record.issued > self.nonce_lifetime_s:
                return None, True
            if (nc, cnonce) in record.seen:
                return None, False  # a replayed request
        ha1 = _md5(f"{user}:{self.realm}:{self.users[user]}")
        if p.get("algorithm", "MD5").upper() == "MD5-SESS":
            ha1 = _md5(f"{ha1}:{nonce}:{cnonce}")
        ha2 = _md5(f"{method}:{uri}")
        expected = _md5(f"{ha1}:{nonce}:{nc}:{cnonce}:{qop}:{ha2}")
        if not hmac.compare_digest(expected, p["response"].lower()):
            return None, False
        with self._lock:
            record.seen.add((nc, cnonce))
        return user, False


@dataclass
class Session:
    """One login: what the two cookies carry, who, and since when."""

    sid: str
    abbcx: str
    user: str
    opened: float
    last_seen: float
    requests: int = 0


class SessionLimitReached(Exception):
    """Every session slot is taken (the controller answers ``503``)."""


class SessionTable:
    """The controller's open sessions, at most ``max_sessions`` of them."""

    def __init__(self, max_sessions: int = 70, idle_timeout_s: float | None = None, *,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if max_sessions < 1:
            raise ValueError("max_sessions must be >= 1")
        self.max_sessions = int(max_sessions)
        self.idle_timeout_s = idle_timeout_s
        self._clock = clock
        self._lock = threading.Lock()
        self._sessions: dict[str, Session] = {}
        self._serial = 0
        self.refused = 0
        """How many logins were refused for the limit (a leak's fingerprint)."""

    def _expire(self, now: float) -> None:
        if self.idle_timeout_s is None:
            return
        for sid in [s.sid for s in self._sessions.values()
                    if now - s.last_seen > self.idle_timeout_s]:
            del self._sessions[sid]

    def lookup(self, cookies: Mapping[str, str]) -> Session | None:
        """The live session both cookies name, touched; ``None`` if none."""
        sid = cookies.get(SESSION_COOKIE)
        with self._lock:
            now = self._clock()
            self._expire(now)
            s = self._sessions.get(sid or "")
            if s is None or cookies.get(ABBCX_COOKIE, s.abbcx) != s.abbcx:
                return None
            s.last_seen, s.requests = now, s.requests + 1
            return s

    def open(self, user: str) -> Session:
        """A new session for ``user``; ``SessionLimitReached`` when all slots are taken."""
        with self._lock:
            now = self._clock()
            self._expire(now)
            if len(self._sessions) >= self.max_sessions:
                self.refused += 1
                raise SessionLimitReached(f"{len(self._sessions)} sessions open "
                                          f"(the limit is {self.max_sessions})")
            self._serial += 1
            s = Session(sid=f"{self._serial}::http-session-::{secrets.token_hex(12)}",
                        abbcx=str(secrets.randbelow(10**9)), user=user, opened=now,
                        last_seen=now, requests=1)
            self._sessions[s.sid] = s
            return s

    def close(self, sid: str) -> bool:
        with self._lock:
            return self._sessions.pop(sid, None) is not None

    def __len__(self) -> int:
        with self._lock:
            self._expire(self._clock())
            return len(self._sessions)

    def snapshot(self) -> list[dict[str, Any]]:
        """The open sessions (user, age, requests) for the lab side channel."""
        with self._lock:
            now = self._clock()
            self._expire(now)
            return [{"user": s.user, "age_s": round(now - s.opened, 3),
                     "idle_s": round(now - s.last_seen, 3), "requests": s.requests}
                    for s in self._sessions.values()]
