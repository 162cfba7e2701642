"""The hardware twin's controller, as a YuMi controller client (``twin+http://HOST:PORT``).

Why it lives in drivers: to the YuMi backend it is just another controller behind the
``YumiControllerClient`` seam, as the real IRC5 behind Robot Web Services is; the
backend's logic above the seam runs unchanged against it. It speaks the twin server's
JSON API (``sim_twin.yumi_server``: ``POST /controller/execute``, ``GET
/controller/tcp``) with the standard library only and imports nothing of ``sim_twin``,
so a robot host needs nothing extra to rehearse. Every failure is a
:class:`~drivers.errors.BackendError` of one line naming the URL.
"""

from __future__ import annotations

import json
import math
import urllib.error
import urllib.request
from collections.abc import Mapping, Sequence
from typing import Any

from drivers.errors import BackendError
from drivers.yumi.yumi_controller import Waypoint

SCHEME = "twin+http://"


def twin_base_url(url: str) -> str:
    """``twin+http://HOST:PORT[/]`` -> ``http://HOST:PORT`` (the server's HTTP root)."""
    if not url.lower().startswith(SCHEME):
        raise BackendError(f"controller_url: {url!r} is not a twin URL ({SCHEME}HOST:PORT)")
    rest = url[len(SCHEME):].rstrip("/")
    if not rest or "/" in rest:
        raise BackendError(f"controller_url: {url!r} must be {SCHEME}HOST:PORT")
    return "http://" + rest


class TwinControllerClient:
    """Both arms of the hardware twin; motion programs run at once (as MultiMove)."""

    def __init__(self, url: str, arms: Sequence[str], *, http_timeout_s: float = 5.0,
                 motion_timeout_s: float = 120.0) -> None:
        self.url = url
        self._base = twin_base_url(url)
        self._arms = tuple(arms)
        self._http_timeout_s = http_timeout_s
        self._motion_timeout_s = motion_timeout_s
        self.last_sim_s: float | None = None
        """Simulated duration of the last program (the twin reports it; for logs)."""
        self._closed = False

    def _call(self, path: str, body: Any = None, timeout_s: float | None = None) -> Any:
        if self._closed:
            raise BackendError(f"twin controller {self.url}: client is closed")
        data = None if body is None else json.dumps(body).encode()
        req = urllib.request.Request(self._base + path, data=data, method="GET" if body is None
                                     else "POST", headers={"Content-Type": "application/json"})
        timeout = self._http_timeout_s if timeout_s is None else timeout_s
        try:
            with urllib.request.urlopen(req, timeout=timeout) as resp:
                return json.loads(resp.read())
        except urllib.error.HTTPError as exc:
            raw = exc.read(2000).decode("utf-8", "replace")
            try:
                msg = str(json.loads(raw)["error"])
            except (ValueError, KeyError, TypeError):
                msg = raw.strip().splitlines()[0] if raw.strip() else str(exc.reason)
            raise BackendError(f"twin controller {self.url}: {path} refused (HTTP "
                               f"{exc.code}): {msg}") from None
        except (urllib.error.URLError, OSError) as exc:  # refused, reset, timed out
            reason = getattr(exc, "reason", exc)
            raise BackendError(f"twin controller {self.url}: {path} failed: {reason}") from None
        except ValueError as exc:
            raise BackendError(f"twin controller {self.url}: {path}: reply is not JSON: "
                               f"{exc}") from None

    def execute(self, programs: Mapping[str, Sequence[Waypoint]]) -> None:
        if unknown := sorted(set(programs) - set(self._arms)):
            raise BackendError(f"twin controller {self.url}: no arm(s) {unknown}; it has "
                               f"{list(self._arms)}")
        body = {"programs": {arm: [_waypoint(w) for w in wps] for arm, wps in programs.items()
                             if arm in self._arms}}
        if not body["programs"]:
            return
        reply = self._call("/controller/execute", body, timeout_s=self._motion_timeout_s)
        if not isinstance(reply, dict) or reply.get("ok") is not True:
            raise BackendError(f"twin controller {self.url}: /controller/execute: unexpected "
                               f"reply {str(reply)[:200]}")
        sim = reply.get("sim_s")
        self.last_sim_s = float(sim) if isinstance(sim, (int, float)) else None

    def tcp_xyz(self) -> dict[str, tuple[float, float, float]]:
        reply = self._call("/controller/tcp")
        try:
            tcp = reply["tcp"]
            out = {arm: (float(tcp[arm][0]), float(tcp[arm][1]), float(tcp[arm][2]))
                   for arm in self._arms}
        except (KeyError, TypeError, IndexError, ValueError):
            raise BackendError(f"twin controller {self.url}: /controller/tcp: expected "
                               f"{{'tcp': {{arm: [x, y, z]}}}} for arms {list(self._arms)}, "
                               f"got {str(reply)[:200]}") from None
        if not all(math.isfinite(v) for xyz in out.values() for v in xyz):
            raise BackendError(f"twin controller {self.url}: non-finite TCP position {out}")
        return out

    def close(self) -> None:
        self._closed = True


def _waypoint(w: Waypoint) -> dict[str, Any]:
    return {"kind": w.kind, "xyz_mm": None if w.xyz_mm is None else [float(v) for v in w.xyz_mm],
            "speed_mm_s": float(w.speed_mm_s), "fine": bool(w.fine)}
