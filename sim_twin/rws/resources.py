"""The RWS 1.0 resources the twin serves: a path and method to an answer of the model.

Why it exists: this is the table docs/rws-checklist.md checks line by line. Each route
maps one request the ABB clients send (``abb_robot_client.rws``,
``abb_motion_program_exec``) to the :class:`~sim_twin.rws.irc5.Irc5Controller` and shapes
the answer as the manual (3HAC050973-001) documents it: GETs answer 200 with a document;
actions (``?action=...``) answer 204; an upload 201 (new) or 200 (replaced). Refusals
raise :class:`~sim_twin.rws.errors.RwsError`; a path the twin does not know is 404, a
known path with the wrong method 405.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from sim_twin.rws.errors import GENERIC, refused
from sim_twin.rws.irc5 import Irc5Controller
from sim_twin.rws.shapes import Doc


@dataclass
class Request:
    method: str
    parts: list[str]
    """The decoded path, split at ``/``, empty segments dropped."""
    query: dict[str, str]
    form: dict[str, str] = field(default_factory=dict)
    body: bytes = b""

    @property
    def action(self) -> str:
        return self.query.get("action", "")


@dataclass
class Reply:
    status: int
    doc: Doc | None = None
    raw: bytes | None = None
    ctype: str = "application/octet-stream"


Handler = Callable[[Irc5Controller, Request, list[str]], Reply]
NO_CONTENT = Reply(204)


def _one(title: str, base: str, item: dict[str, Any]) -> Reply:
    return Reply(200, Doc(title, base, [item]))


def _need_action(req: Request, *allowed: str) -> str:
    if req.action not in allowed:
        raise refused(400, GENERIC, f"action={req.action!r} (this resource takes "
                                    f"{', '.join(allowed)})")
    return req.action


# --- ctrl, system ----------------------------------------------------------------------------
def get_ctrl(c: Irc5Controller, req: Request, a: list[str]) -> Reply:
    name = a[0]
    if name == "identity":
        i = c.identity
        return _one("ctrl", "ctrl/", {"_type": "ctrl-identity-info", "_title": "identity",
                                       "ctrl-name": i.name, "ctrl-type": i.ctrl_type,
                                       "ctrl-id": i.ctrl_id})
    value = c.files.env_value(name) if name.startswith("$") else None
    if value is None:
        raise refused(404, GENERIC, f"no controller resource {name!r}")
    return _one("ctrl", "ctrl/", {"_type": "ctrl-env", "_title": name, "_value": value})


def restart_ctrl(c: Irc5Controller, req: Request, a: list[str]) -> Reply:
    """``POST ctrl?action=restart`` ``restart-mode=restart|pstart`` (RWS 1.0's controller
    restart; ``pstart`` is "Reset RAPID"): what a lab does after loading our system
    modules, and what must leave the world zones on (issue 29). The other modes
    (``istart``, ``xstart``, ``bstart``, ``shutdown``) are not modelled: 400."""
    _need_action(req, "restart")
    try:
        c.restart(req.form.get("restart-mode", ""))
    except ValueError as exc:
        raise refused(400, GENERIC, str(exc)) from None
    return NO_CONTENT


def _options(c: Irc5Controller) -> list[dict[str, str]]:
    return [{"_type": "sys-option-li", "_title": str(i), "option": o}
            for i, o in enumerate(c.identity.options)]


def get_system(c: Irc5Controller, req: Request, a: list[str]) -> Reply:
    i = c.identity
    if a == ["options"]:
        return Reply(200, Doc("system", "rw/system/options/", _options(c)))
    if a:
        raise refused(404, GENERIC, f"no system resource {'/'.join(a)!r}")
    v = (i.rwversion.split(".") + ["0"] * 3)[:3]
    system = {"_type": "sys-system-li", "_title": "system", "major": v[0], "minor": v[1],
              "build": v[2], "revision": "00", "sub-revision": "00", "title": "RobotWare",
              "type": "RobotWare", "description": "Controller Software", "name": i.name,
              "rwversion": i.rwversion, "sysid": i.sysid,
              "starttm": time.strftime("%Y-%m-%d T %H:%M:%S"), "rwversionname": i.rwversion}
    opts = {"_type": "sys-options-li", "_title": "options", "options": _options(c)}
    return Reply(200, Doc("system", "rw/system/", [system, opts]))


# --- panel -------------------------------------------------------------------------------------
def panel(c: Irc5Controller, req: Request, a: list[str]) -> Reply:
    what = a[0]
    if req.method == "POST":
        if what == "ctrlstate":
            _need_action(req, "setctrlstate")
            c.request_ctrlstate(req.form)
        elif what == "speedratio":
            _need_action(req, "setspeedratio")
            c.request_speedratio(req.form)
        else:
            raise refused(405, GENERIC, f"POST rw/panel/{what}")
        return NO_CONTENT
    value = {"ctrlstate": c.ctrlstate, "opmode": c.opmode,
             "speedratio": str(c.speedratio)}.get(what)
    if value is None:
        raise refused(404, GENERIC, f"no panel resource {what!r}")
    return _one("panel", f"rw/panel/{what}/", {"_type": f"pnl-{what}", "_title": what,
                                                what: value})


# --- RAPID --------------------------------------------------------------------------------------
def execution(c: Irc5Controller, req: Request, a: list[str]) -> Reply:
    if req.method == "GET":
        return _one("rapid", "rw/rapid/", c.execution_item())
    act = _need_action(req, "start", "stop", "resetpp")
    if act == "start":
        c.start(req.form)
    elif act == "stop":
        c.stop(req.form)
    else:
        c.resetpp()
    return NO_CONTENT


def tasks(c: Irc5Controller, req: Request, a: list[str]) -> Reply:
    if req.method == "POST":
        act = _need_action(req, "activate", "deactivate")
        c.set_task_active(a[0] if a else None, act == "activate")
        return NO_CONTENT
    if a:
        return _one("rapid", "rw/rapid/", c.task_item(c.task(a[0]), list_item=False))
    return Reply(200, Doc("rapid", "rw/rapid/", [c.task_item(t, list_item=True)
                                                  for t in c.tasks.values()]))


def symbol(c: Irc5Controller, req: Request, a: list[str]) -> Reply:
    if req.method == "POST":
        _need_action(req, "set")
        if "value" not in req.form:
            raise refused(400, GENERIC, "action=set needs value")
        c.set_symbol(a, req.form["value"])
        return NO_CONTENT
    s = c.symbols.find(a)
    return _one("rapid", "rw/rapid/", {"_type": "rap-data", "_title": s.path, "value": s.value})


# --- I/O, event log ---------------------------------------------------------------------------
def signals(c: Irc5Controller, req: Request, a: list[str]) -> Reply:
    if req.method == "POST":
        _need_action(req, "set")
        c.signals.set(a, req.form)
        return NO_CONTENT
    if not a:
        return Reply(200, Doc("io", "rw/iosystem/", c.signals.listing()))
    return _one("io", "rw/iosystem/", c.signals.find(a).item())


def _elog_item(e: Any, lang: bool, list_item: bool) -> dict[str, Any]:
    item: dict[str, Any] = {"_type": "elog-message-li" if list_item else "elog-message",
                            "_title": f"/rw/elog/0/{e.seqnum}", "msgtype": str(e.msgtype),
                            "code": str(e.code), "src-name": e.src_name, "tstamp": e.tstamp,
                            "argc": str(len(e.args)),
                            "argv": [{"type": "string", "value": v} for v in e.args]}
    if lang:
        item.update({"title": e.title, "desc": e.desc, "conseqs": e.conseqs,
                     "causes": e.causes, "actions": e.actions})
    return item


def elog(c: Irc5Controller, req: Request, a: list[str]) -> Reply:
    if req.method == "POST":
        if not a:
            _need_action(req, "clearall")
            c.elog.clear()
        else:
            _need_action(req, "clear")
            c.elog.clear(_domain(a[0]))
        return NO_CONTENT
    if not a:
        raise refused(405, GENERIC, "the twin lists one domain at a time: GET rw/elog/0")
    lang = bool(req.query.get("lang"))
    if len(a) == 2:
        e = c.elog.get(_int(a[1], "sequence number"))
        if e is None:
            raise refused(404, GENERIC, f"no elog message {a[1]}")
        return _one("Elog", "rw/elog/", _elog_item(e, lang, list_item=False))
    entries = c.elog.entries(_domain(a[0]))
    if req.query.get("order", "lifo") == "fifo":
        entries.reverse()
    if "elogseqnum" in req.query:
        start = _int(req.query["elogseqnum"], "elogseqnum")
        entries = [e for e in entries if e.seqnum >= start]
    return Reply(200, Doc("Elog", "rw/elog/", [_elog_item(e, lang, True) for e in entries]))


def _int(text: str, what: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise refused(400, GENERIC, f"{what} {text!r} is not a number") from None


def _domain(text: str) -> int:
    d = _int(text, "elog domain")
    if not 0 <= d <= 15:
        raise refused(404, GENERIC, f"no elog domain {d}")
    return d


# --- motion system ----------------------------------------------------------------------------
def mechunits(c: Irc5Controller, req: Request, a: list[str]) -> Reply:
    if not a:
        return Reply(200, Doc("motionsystem", "rw/motionsystem/",
                              [{"_type": "ms-mechunit-li", "_title": u.name}
                               for u in c.units.values()]))
    if len(a) != 2 or a[1] not in ("robtarget", "jointtarget"):
        raise refused(404, GENERIC, f"no motion system resource {'/'.join(a)!r}")
    base = f"rw/motionsystem/mechunits/{a[0]}/{a[1]}/"
    if a[1] == "jointtarget":
        return _one("motionsystem", base, c.jointtarget(a[0]))
    if "coordinate" not in req.query:
        raise refused(400, GENERIC, "robtarget needs coordinate=Base|World|Wobj")
    return _one("motionsystem", base, c.robtarget(a[0], req.query.get("tool", "tool0"),
                                                  req.query.get("wobj", "wobj0"),
                                                  req.query["coordinate"]))


# --- files ----------------------------------------------------------------------------------------
def fileservice(c: Irc5Controller, req: Request, a: list[str]) -> Reply:
    path = "/".join(a)
    fs = c.files
    if req.method == "PUT":
        return Reply(201 if fs.put(path, req.body) else 200)
    if req.method == "DELETE":
        fs.delete(path)
        return NO_CONTENT
    if req.method == "POST":
        if req.form.get("fs-action") != "create" or not req.form.get("fs-newname"):
            raise refused(400, GENERIC, "the twin's folders take fs-action=create&fs-newname=")
        fs.mkdir(path, req.form["fs-newname"])
        return Reply(201)
    if fs.is_dir(path):
        return Reply(200, Doc("File Service", f"fileservice/{path}/" if path else
                              "fileservice/", fs.listdir(path)))
    return Reply(200, raw=fs.read(path))


ROUTES: list[tuple[tuple[str, ...], tuple[str, ...], Handler]] = [
    (("ctrl", "{}"), ("GET",), get_ctrl),
    (("ctrl",), ("POST",), restart_ctrl),
    (("rw", "system", "**"), ("GET",), get_system),
    (("rw", "panel", "{}"), ("GET", "POST"), panel),
    (("rw", "rapid", "execution"), ("GET", "POST"), execution),
    (("rw", "rapid", "tasks", "**"), ("GET", "POST"), tasks),
    (("rw", "rapid", "symbol", "data", "RAPID", "**"), ("GET", "POST"), symbol),
    (("rw", "iosystem", "signals", "**"), ("GET", "POST"), signals),
    (("rw", "elog", "**"), ("GET", "POST"), elog),
    (("rw", "motionsystem", "mechunits", "**"), ("GET",), mechunits),
    (("fileservice", "**"), ("GET", "PUT", "DELETE", "POST"), fileservice),
]
"""(pattern, methods, handler): ``{}`` is one segment, ``**`` the rest (maybe none)."""


def _match(pattern: tuple[str, ...], parts: list[str]) -> list[str] | None:
    args: list[str] = []
    for i, p in enumerate(pattern):
        if p == "**":
            return args + parts[i:]
        if i >= len(parts) or (p != "{}" and p != parts[i]):
            return None
        if p == "{}":
            args.append(parts[i])
    return args if len(parts) == len(pattern) else None


def dispatch(c: Irc5Controller, req: Request) -> Reply:
    """The answer to ``req``; raises :class:`RwsError` for a refusal."""
    for pattern, methods, handler in ROUTES:
        args = _match(pattern, req.parts)
        if args is None:
            continue
        if req.method not in methods:
            raise refused(405, GENERIC, f"{req.method} is not allowed on "
                                        f"/{'/'.join(req.parts)}")
        return handler(c, req, args)
    raise refused(404, GENERIC, f"the twin has no resource /{'/'.join(req.parts)}")
