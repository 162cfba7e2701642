"""One RWS request in, one answer out: authentication, sessions, logout, the lab side
channel and the resources, independent of any HTTP server.

Why it exists apart from the server: the answers are the controller's, whichever HTTP
server carries them; the twin's RWS server (``sim_twin.rws.rws_server``, also the one
``sim_twin.yumi_server`` runs beside its camera) hands each request to
:meth:`RwsService.handle` and writes the :class:`HttpReply` back.

Order of a request: ``/lab/*`` (no authentication: the twin's side, never a
controller's); else the session cookie or a digest login (``401`` / ``503``, see
``sim_twin.rws.digest_auth``); ``/logout`` ends the session (``204``); a ``POST``'s body
must be a form (``application/x-www-form-urlencoded``, else ``415``, as RWS answers);
the user's UAS grants must cover the request (else ``403``, ``SYS_CTRL_E_UAS_REJECT``, and
nothing changes: ``sim_twin.rws.uas``); then the resource (``sim_twin.rws.resources``),
rendered as JSON when ``json=1``.

The lab side channel:

- ``GET /lab/controller`` -> ``{"state": {...}, "sessions": [...], "max_sessions": n,
  "refused_logins": n, "options": [...], "rapid": {"loaded", "version", "zones"} | null}``
- ``POST /lab/controller`` with any of ``{"opmode": "AUTO"|"MANR"|..., "ctrlstate":
  "motoron"|"motoroff"|"guardstop"|..., "speedratio": 0..100, "execution":
  "running"|"stopped", "options": [name, ...], "remove_option": "608-1", "rapid":
  "testbed"|"none", "rapid_version": n, "event_routines": true|false,
  "omit_motiontask": true|false, "task_error": {"task", "code", "title", "desc"?,
  "causes"?, "actions"?, "args"?, "msgtype"?}}``, applied in that order ->
  the new state; ``400`` on a bad value (nothing changed when a value is malformed).
  ``options`` replaces what ``rw/system/options`` lists, ``remove_option`` drops one
  (by name or its number: ``608-1``); ``rapid`` loads or unloads our RAPID modules
  (their symbols, and what a start runs; only with RAPID stopped) and ``rapid_version``
  sets the ``TB_RAPID_VERSION`` they report, ``event_routines`` configures (true) or
  removes (false) ``tb_zones`` as each task's POWER_ON event routine (only on a twin
  that plays our RAPID: ``sim_twin.rws.testbed_install``); ``omit_motiontask`` makes
  ``GET rw/rapid/tasks`` leave the ``motiontask`` field out (``Irc5Controller``).
- ``GET /lab/health`` -> ``{"ok": true}``.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol
from urllib.parse import parse_qsl, unquote, urlsplit

from sim_twin.rws.digest_auth import (
    ABBCX_COOKIE,
    REALM,
    SESSION_COOKIE,
    DigestAuthority,
    Session,
    SessionLimitReached,
    SessionTable,
)
from sim_twin.rws.errors import GENERIC, RwsError, refused
from sim_twin.rws.irc5 import Irc5Controller
from sim_twin.rws.resources import Reply, Request, dispatch
from sim_twin.rws.shapes import render, render_error
from sim_twin.rws.uas import demand, grants_of_users

FORM_TYPE = "application/x-www-form-urlencoded"
LAB_KEYS = ("opmode", "ctrlstate", "speedratio", "execution", "options", "remove_option",
            "rapid", "rapid_version", "event_routines", "omit_motiontask", "task_error")


class LabProgram(Protocol):
    """What the lab side channel can do to the RAPID installed on the twin
    (``sim_twin.rws.testbed_install.TestbedInstall``)."""

    def set_loaded(self, loaded: bool) -> None: ...

    def set_version(self, version: int) -> None: ...

    def set_event_routines(self, configured: bool) -> None: ...

    def lab_state(self) -> dict[str, Any]: ...


@dataclass
class HttpReply:
    status: int
    headers: list[tuple[str, str]] = field(default_factory=list)
    body: bytes = b""


def _lower_headers(headers: Mapping[str, str] | Iterable[tuple[str, str]]) -> dict[str, str]:
    items = headers.items() if isinstance(headers, Mapping) else headers
    out: dict[str, str] = {}
    for k, v in items:
        key = k.lower()
        out[key] = f"{out[key]}; {v}" if key == "cookie" and key in out else v
    return out


def parse_cookies(header: str) -> dict[str, str]:
    out = {}
    for part in header.split(";"):
        name, eq, value = part.strip().partition("=")
        if eq and name:
            out[name] = value
    return out


class RwsService:
    """The twin's RWS endpoint for one controller."""

    def __init__(self, controller: Irc5Controller, *, users: Mapping[str, str] | None = None,
                 max_sessions: int = 70, idle_timeout_s: float | None = None,
                 realm: str = REALM, program: LabProgram | None = None,
                 grants: Mapping[str, Iterable[str]] | None = None) -> None:
        self.controller = controller
        self.program = program
        self.auth = DigestAuthority(users, realm)
        self.grants = grants_of_users(self.auth.users, grants)
        """Each user's UAS grants (``sim_twin.rws.uas.grants_of_users``: unless given, the
        factory ``Default User`` every grant, any other user none)."""
        self.sessions = SessionTable(max_sessions, idle_timeout_s)

    def handle(self, method: str, target: str,
               headers: Mapping[str, str] | Iterable[tuple[str, str]], body: bytes,
               host: str) -> HttpReply:
        """Answer one request. ``target`` is the request line's path and query as sent
        (the digest ``uri``); ``host`` is ``http://name:port`` for the answers' links."""
        h = _lower_headers(headers)
        split = urlsplit(target)
        query = dict(parse_qsl(split.query, keep_blank_values=True))
        parts = [p for p in unquote(split.path).split("/") if p]
        as_json = query.get("json") == "1"
        if parts[:1] == ["lab"]:
            return self._lab(method, parts[1:], body)
        session = self.sessions.lookup(parse_cookies(h.get("cookie", "")))
        cookies: list[tuple[str, str]] = []
        if session is None:
            user, stale = self.auth.verify(method, target, h.get("authorization"))
            if user is None:
                return HttpReply(401, [("WWW-Authenticate", self.auth.challenge(stale)),
                                       ("Content-Type", "text/html")],
                                 b"<html><body>401 Unauthorized</body></html>")
            try:
                session = self.sessions.open(user)
            except SessionLimitReached as exc:
                return self._error(refused(503, GENERIC, f"too many sessions: {exc}"),
                                   host, as_json)
            cookies = _session_cookies(session)
        if parts == ["logout"]:
            self.sessions.close(session.sid)
            return HttpReply(204, _session_cookies(None))
        try:
            req = Request(method, parts, query, self._form(method, h, body), body)
            demand(session.user, self.grants.get(session.user, frozenset()), req.method,
                   req.parts, req.action, req.form)
            reply = dispatch(self.controller, req)
        except RwsError as exc:
            out = self._error(exc, host, as_json)
            out.headers += cookies
            return out
        return self._render(reply, host, as_json, cookies)

    @staticmethod
    def _form(method: str, h: Mapping[str, str], body: bytes) -> dict[str, str]:
        if method != "POST" or not body:
            return {}
        ctype = h.get("content-type", "").split(";")[0].strip().lower()
        if ctype != FORM_TYPE:
            raise refused(415, GENERIC, f"a POST's body must be {FORM_TYPE}, got {ctype!r}")
        try:
            return dict(parse_qsl(body.decode("utf-8"), keep_blank_values=True))
        except UnicodeDecodeError:
            raise refused(400, GENERIC, "the form is not UTF-8") from None

    @staticmethod
    def _error(exc: RwsError, host: str, as_json: bool) -> HttpReply:
        body, ctype = render_error(exc.code, exc.msg, host, as_json)
        return HttpReply(exc.status, [("Content-Type", ctype)], body)

    @staticmethod
    def _render(reply: Reply, host: str, as_json: bool,
                cookies: list[tuple[str, str]]) -> HttpReply:
        if reply.doc is not None:
            body, ctype = render(reply.doc, host, as_json)
            return HttpReply(reply.status, [("Content-Type", ctype), *cookies], body)
        if reply.raw is not None:
            return HttpReply(reply.status, [("Content-Type", reply.ctype), *cookies], reply.raw)
        return HttpReply(reply.status, cookies)

    # --- the lab side channel -------------------------------------------------------------
    def lab_state(self) -> dict[str, Any]:
        return {"state": self.controller.snapshot(), "sessions": self.sessions.snapshot(),
                "max_sessions": self.sessions.max_sessions,
                "refused_logins": self.sessions.refused,
                "options": list(self.controller.identity.options),
                "omit_motiontask": self.controller.omit_motiontask,
                "rapid": None if self.program is None else self.program.lab_state()}

    def _check_lab(self, body: Mapping[str, Any]) -> None:
        """Refuse a malformed ``POST /lab/controller`` body before anything changes."""
        unknown = set(body) - set(LAB_KEYS)
        if unknown:
            raise ValueError(f"unknown keys {sorted(unknown)} (known: {list(LAB_KEYS)})")
        err = body.get("task_error")
        if err is not None and (not isinstance(err, Mapping) or not {"task", "code", "title"}
                                <= set(err)):
            raise ValueError('task_error must be {"task", "code", "title", ...}')
        if "rapid" in body or "rapid_version" in body or "event_routines" in body:
            if self.program is None:
                raise ValueError("this twin plays no RAPID of ours (rapid, rapid_version, "
                                 "event_routines)")
            if body.get("rapid", "testbed") not in ("testbed", "none"):
                raise ValueError('rapid must be "testbed" (loaded) or "none" (not loaded)')
        for flag in ("event_routines", "omit_motiontask"):
            if flag in body and not isinstance(body[flag], bool):
                raise ValueError(f"{flag} must be true or false")
        opts = body.get("options")
        if opts is not None and (not isinstance(opts, list)
                                 or not all(isinstance(o, str) and o for o in opts)):
            raise ValueError("options must be a list of option names")
        gone = body.get("remove_option")
        if gone is not None and (not isinstance(gone, str) or not any(
                o == gone or o.startswith(f"{gone} ") for o in self.controller.identity.options)):
            raise ValueError(f"remove_option {gone!r}: no such option in "
                             f"{list(self.controller.identity.options)}")

    def apply_lab(self, body: Mapping[str, Any]) -> None:
        """``POST /lab/controller``'s body applied to the controller (ValueError)."""
        self._check_lab(body)
        self.controller.set_state(opmode=body.get("opmode"), ctrlstate=body.get("ctrlstate"),
                                  speedratio=body.get("speedratio"),
                                  execution=body.get("execution"))
        if "options" in body:
            self.controller.set_options(body["options"])
        if "remove_option" in body:
            self.controller.remove_option(body["remove_option"])
        if self.program is not None and "rapid" in body:
            self.program.set_loaded(body["rapid"] == "testbed")
        if self.program is not None and "rapid_version" in body:
            self.program.set_version(body["rapid_version"])
        if self.program is not None and "event_routines" in body:
            self.program.set_event_routines(body["event_routines"])
        if "omit_motiontask" in body:
            self.controller.omit_motiontask = body["omit_motiontask"]
        err = body.get("task_error")
        if err is not None:
            extra = {k: err[k] for k in ("desc", "causes", "actions", "args", "msgtype")
                     if k in err}
            try:
                self.controller.task_error(str(err["task"]), int(err["code"]), str(err["title"]),
                                           **extra)
            except RwsError as exc:
                raise ValueError(exc.msg) from None

    def _lab(self, method: str, parts: list[str], body: bytes) -> HttpReply:
        if parts == ["health"] and method == "GET":
            return _json(200, {"ok": True})
        if parts != ["controller"] or method not in ("GET", "POST"):
            return _json(404, {"error": f"no lab endpoint {method} /lab/{'/'.join(parts)}"})
        if method == "POST":
            try:
                data = json.loads(body or b"null")
                if not isinstance(data, dict):
                    raise ValueError("expected a JSON object")
                self.apply_lab(data)
            except ValueError as exc:
                return _json(400, {"error": str(exc)})
        return _json(200, {"ok": True, **self.lab_state()})


def _json(status: int, obj: Any) -> HttpReply:
    return HttpReply(status, [("Content-Type", "application/json")], json.dumps(obj).encode())


def _session_cookies(s: Session | None) -> list[tuple[str, str]]:
    """Set-Cookie headers for a new session, or (``None``) ones that delete both."""
    if s is None:
        return [("Set-Cookie", f"{name}=; Path=/; Max-Age=0")
                for name in (SESSION_COOKIE, ABBCX_COOKIE)]
    return [("Set-Cookie", f"{SESSION_COOKIE}={s.sid}; Path=/; HttpOnly"),
            ("Set-Cookie", f"{ABBCX_COOKIE}={s.abbcx}; Path=/; HttpOnly")]
