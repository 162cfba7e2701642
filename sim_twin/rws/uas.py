"""The controller's User Authorization System (UAS): which grants each user holds, which
grant each RWS request needs, and the answer to a request whose grant the user lacks.

Why it exists: a real IRC5 authenticates a user AND checks, per request, that the user's
group holds the grant the request needs; the agent's user holds only what a push needs
(robot/README.md, "The user and its grants (UAS)"). A twin that checked the password alone
would let a hostile PC, logged in as the agent, write RAPID data (``tool_pusher``),
restart the controller (the zones erased), switch the motors or clear the event log, all
of which the robot refuses it. The twin refuses them the same way, at one place
(``sim_twin.rws.rws_service``, before any resource runs): nothing changes.

The refusal. RWS 1.0 (Application manual 3HAC050973-001) answers ``FORBIDDEN(403)`` where
a request needs a privilege the client lacks ("Set Reset Safety Controller": "User should
have Safety services privileges"; "Acknowledgement for Operation Mode": "Local Client
privileges"; ``setspeedratio`` lists 403 too); its status element carries a RobotWare
return code from the manual's "Robot controller return codes", here ``SYS_CTRL_E_UAS_REJECT``
(:data:`UAS_REJECT`, ``0xC0048415``: the value as client code for RobotWare spells it, the
neighbour of ``SYS_CTRL_E_MASTER_REJECT`` ``0xC004841D``; the PC SDK's
``UasRejectException``: "the current user doesn't have the required UAS grant"). That a
grant refusal is this 403 and this code on RobotWare 6 (not the 400 of the manual's
mastership example): *assumed*, docs/rws-checklist.md, "The agent's user".

The grants (ids as ABB's app SDK lists them; meanings from the FlexPendant SDK 6.5
reference, ``ABB.Robotics.Controllers.Grant`` and ``RestartMode``): see :data:`GRANTS`.

Which request needs which grant (:data:`RULES`; every GET but the file service's needs
none):

- ``rw/rapid/execution`` ``start``, ``resetpp``: Execute program (cited: ``ExecuteRapid``
  "Start/step program (stop is always allowed), Move PP to Main"); ``stop``: none (cited).
- ``rw/rapid/tasks/{task}`` ``activate``/``deactivate``: Program debug (cited:
  ``DebugRapid`` "Activate/deactivate RAPID tasks"); ``loadmod``/``unloadmod``: Load
  program (cited: ``LoadRapidProgram`` "load/delete modules and program").
- ``rw/rapid/symbol/data/...`` ``set``: Modify current value, or Perform ModPos and
  HotEdit (cited: ``ModifyRapidDataValue``; ``ModifyRapidPosition`` includes "Modify
  current value of any RAPID variable").
- ``ctrl`` / ``rw/panel`` ``restart``: a warm start (``restart``) needs Remote warm start
  AND ``UAS_RESTORE`` (the grant list names the first, ``RestartMode.WarmStart`` the
  second: the twin asks both, as robot/README.md gives the person both); ``pstart``,
  ``istart``, ``bstart`` need ``UAS_SYSTEM_ADMINISTRATION`` (cited: ``RestartMode``);
  ``xstart``, ``shutdown`` and any other mode the same (assumed).
- ``fileservice`` GET: Read access to controller disks; PUT, DELETE, POST: Write access
  (cited: ``ReadFtp``/``WriteFtp``; that RWS's file service is the "explicit disk
  access" they are for: assumed); ``UAS_SYSTEM_ADMINISTRATION`` also serves (cited:
  ``AdministrateSystem`` "gives full FTP access").
- ``rw/panel/speedratio`` ``setspeedratio``: Decrease production speed (cited
  ``DecreaseProductionSpeed`` for a decrease from 100 % in Auto; for every other change,
  an increase included, ABB names none: assumed the same, the strictest).
- ``rw/panel/ctrlstate`` ``setctrlstate`` (motors on AND off): ABB names no grant;
  assumed the strictest, ``UAS_SYSTEM_ADMINISTRATION`` (the person's, never the agent's).
- ``rw/iosystem/signals/...`` ``set``: ``WriteIO`` (cited); ``rw/elog`` ``clear``,
  ``clearall``: ``ClearEventLog`` (cited); ``rw/cfg/...`` writes: Modify configuration
  (cited: ``WriteConfiguration``).
- ``rw/mastership/...`` and ``users/rmmp`` requests: Edit RAPID code (assumed, the
  strictest: in Auto RWS takes RAPID mastership itself for what the agent does; explicit
  mastership serves editing); a ``release`` needs none (like stop).
- ``subscription`` (reads): none. Any other POST, PUT or DELETE: ``UAS_SYSTEM_ADMINISTRATION``
  (fail closed: a request this table does not know is refused to the agent).

Who holds what (:data:`ROLES`): the agent exactly robot/README.md's four grants, the
person its install grants, the factory ``Default User`` every grant the twin knows
(assumed: the RWS manual's sample calls issue each of these requests as ``Default
User``); any other user none unless given (fail closed).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass

from sim_twin.rws.digest_auth import DEFAULT_USERS
from sim_twin.rws.errors import RwsError

UAS_REJECT = -1073445867
"""``SYS_CTRL_E_UAS_REJECT`` (0xC0048415): the code of a request whose grant is missing."""
FORBIDDEN = 403

EXECUTE = "UAS_RAPID_EXECUTE"
DEBUG = "UAS_RAPID_DEBUG"
LOAD_PROGRAM = "UAS_RAPID_LOADPROGRAM"
EDIT_RAPID = "UAS_RAPID_EDIT"
CURRENT_VALUE = "UAS_RAPID_CURRVALUE"
MODPOS = "UAS_RAPID_MODPOS"
CFG_WRITE = "UAS_CFG_WRITE"
REMOTE_WARMSTART = "UAS_REMOTE_WARMSTART"
RESTORE = "UAS_RESTORE"
SYSTEM_ADMIN = "UAS_SYSTEM_ADMINISTRATION"
FTP_READ = "UAS_FTP_READ"
FTP_WRITE = "UAS_FTP_WRITE"
SPEED_DECREASE = "UAS_SPEED_DECREASE"
IO_WRITE = "UAS_IO_WRITE"
EVENTLOG_CLEAR = "UAS_EVENTLOG_CLEAR"

GRANTS: dict[str, str] = {
    EXECUTE: "Execute program",
    DEBUG: "Program debug",
    LOAD_PROGRAM: "Load program",
    EDIT_RAPID: "Edit RAPID code",
    CURRENT_VALUE: "Modify current value",
    MODPOS: "Perform ModPos and HotEdit",
    CFG_WRITE: "Modify configuration",
    REMOTE_WARMSTART: "Remote warm start",
    RESTORE: "Restore (RestartMode.WarmStart's grant)",
    SYSTEM_ADMIN: "Administration of installed systems",
    FTP_READ: "Read access to controller disks",
    FTP_WRITE: "Write access to controller disks",
    SPEED_DECREASE: "Decrease production speed",
    IO_WRITE: "Write access to I/O",
    EVENTLOG_CLEAR: "Delete event log",
}
"""Every grant the twin knows: its id -> the name RobotStudio shows (those robot/README.md
marks assumed are assumed here too)."""

AGENT_GRANTS = frozenset({EXECUTE, DEBUG, FTP_WRITE, FTP_READ})
"""robot/README.md's agent: exactly these."""
PERSON_GRANTS = frozenset({FTP_READ, LOAD_PROGRAM, EDIT_RAPID, CURRENT_VALUE, CFG_WRITE,
                           REMOTE_WARMSTART, RESTORE, SYSTEM_ADMIN})
"""robot/README.md's person who installs and measures (with ``UAS_RESTORE``: "give the
person both")."""
FACTORY_GRANTS = frozenset(GRANTS)
ROLES: dict[str, frozenset[str]] = {"agent": AGENT_GRANTS, "person": PERSON_GRANTS,
                                    "factory": FACTORY_GRANTS, "none": frozenset()}
FACTORY_USER = next(iter(DEFAULT_USERS))


@dataclass(frozen=True)
class Need:
    """What one request needs: ANY of ``alternatives``, each a set of grants ALL needed;
    ``source`` says where the mapping comes from (cited or assumed)."""

    what: str
    alternatives: tuple[frozenset[str], ...]
    source: str

    def met_by(self, grants: frozenset[str]) -> bool:
        return any(alt <= grants for alt in self.alternatives)

    def spelled(self) -> str:
        return " or ".join(" and ".join(sorted(alt)) for alt in self.alternatives)


def _need(what: str, source: str, *alternatives: Iterable[str]) -> Need:
    return Need(what, tuple(frozenset(a) for a in alternatives), source)


NeedOf = Need | Callable[[Mapping[str, str]], Need]


@dataclass(frozen=True)
class Rule:
    """A request kind: methods, a path pattern (``*`` one segment, ``**`` the rest),
    the ``action`` values it covers (``None``: any) and its :class:`Need` (``None``: no
    grant), or a function of the form for a need that depends on it."""

    methods: tuple[str, ...]
    pattern: tuple[str, ...]
    actions: tuple[str, ...] | None
    need: NeedOf | None

    def matches(self, method: str, parts: Sequence[str], action: str) -> bool:
        return (method in self.methods and _match(self.pattern, parts)
                and (self.actions is None or action in self.actions))


def _match(pattern: tuple[str, ...], parts: Sequence[str]) -> bool:
    for i, p in enumerate(pattern):
        if p == "**":
            return True
        if i >= len(parts) or (p != "*" and p != parts[i]):
            return False
    return len(parts) == len(pattern)


_FTP = "FlexPendant SDK ReadFtp/WriteFtp, AdministrateSystem (full FTP access); RWS's " \
       "file service as explicit disk access: assumed"
_WARM = _need("a warm restart", "FlexPendant SDK grant list (Remote warm start) and "
              "RestartMode.WarmStart (UAS_RESTORE): both asked", {REMOTE_WARMSTART, RESTORE})


def _restart(form: Mapping[str, str]) -> Need:
    mode = form.get("restart-mode", "")
    if mode == "restart":
        return _WARM
    cited = mode in ("pstart", "istart", "bstart")
    return _need(f"restart-mode={mode}", "FlexPendant SDK RestartMode" if cited else
                 "assumed: as P-start, the strictest", {SYSTEM_ADMIN})


POST = ("POST",)
WRITES = ("POST", "PUT", "DELETE")
RULES: tuple[Rule, ...] = (
    Rule(("GET",), ("fileservice", "**"), None,
         _need("reading the controller's disks", _FTP, {FTP_READ}, {SYSTEM_ADMIN})),
    Rule(WRITES, ("fileservice", "**"), None,
         _need("writing the controller's disks", _FTP, {FTP_WRITE}, {SYSTEM_ADMIN})),
    Rule(POST, ("rw", "rapid", "execution"), ("stop",), None),
    Rule(POST, ("rw", "rapid", "execution"), ("start", "resetpp"),
         _need("starting RAPID or PP to Main", "FlexPendant SDK ExecuteRapid", {EXECUTE})),
    Rule(POST, ("rw", "rapid", "tasks", "**"), ("activate", "deactivate"),
         _need("(de)activating a RAPID task", "FlexPendant SDK DebugRapid", {DEBUG})),
    Rule(POST, ("rw", "rapid", "tasks", "**"), ("loadmod", "unloadmod"),
         _need("loading or unloading a RAPID module", "FlexPendant SDK LoadRapidProgram",
               {LOAD_PROGRAM})),
    Rule(POST, ("rw", "rapid", "symbol", "data", "**"), ("set",),
         _need("setting a RAPID symbol's value", "FlexPendant SDK ModifyRapidDataValue, "
               "ModifyRapidPosition", {CURRENT_VALUE}, {MODPOS})),
    Rule(POST, ("ctrl",), ("restart",), _restart),
    Rule(POST, ("rw", "panel"), ("restart",), _restart),
    Rule(POST, ("rw", "panel", "ctrlstate"), ("setctrlstate",),
         _need("motors on or off", "assumed: ABB names no grant; the strictest",
               {SYSTEM_ADMIN})),
    Rule(POST, ("rw", "panel", "speedratio"), ("setspeedratio",),
         _need("setting the speed ratio", "FlexPendant SDK DecreaseProductionSpeed (a "
               "decrease from 100 % in Auto); any other change: assumed", {SPEED_DECREASE})),
    Rule(POST, ("rw", "iosystem", "signals", "**"), ("set",),
         _need("setting an I/O signal", "FlexPendant SDK WriteIO", {IO_WRITE})),
    Rule(POST, ("rw", "elog", "**"), ("clear", "clearall"),
         _need("clearing the event log", "FlexPendant SDK ClearEventLog", {EVENTLOG_CLEAR})),
    Rule(WRITES, ("rw", "cfg", "**"), None,
         _need("writing the configuration", "FlexPendant SDK WriteConfiguration",
               {CFG_WRITE})),
    Rule(POST, ("rw", "mastership", "**"), ("release",), None),
    Rule(POST, ("rw", "mastership", "**"), None,
         _need("requesting mastership", "assumed: the strictest", {EDIT_RAPID})),
    Rule(POST, ("users", "rmmp", "**"), None,
         _need("requesting RMMP", "assumed: the strictest", {EDIT_RAPID})),
    Rule(("POST", "DELETE"), ("subscription", "**"), None, None),
)
"""The request kinds, first match wins (the module docstring says why each)."""
UNLISTED = _need("a request the twin's UAS table does not list",
                 "assumed: fail closed", {SYSTEM_ADMIN})


def need_of(method: str, parts: Sequence[str], action: str,
            form: Mapping[str, str]) -> Need | None:
    """The grants ``method`` on ``parts`` (``?action=``, the form) needs; ``None``: none."""
    for rule in RULES:
        if rule.matches(method, parts, action):
            return rule.need(form) if callable(rule.need) else rule.need
    return None if method == "GET" else UNLISTED


def demand(user: str, grants: frozenset[str], method: str, parts: Sequence[str],
           action: str, form: Mapping[str, str]) -> None:
    """Raise the controller's refusal (403, :data:`UAS_REJECT`) unless ``user``'s
    ``grants`` meet what the request needs; the message names the user and the grant,
    never a password."""
    need = need_of(method, parts, action, form)
    if need is None or need.met_by(grants):
        return
    raise RwsError(FORBIDDEN, UAS_REJECT,
                   f"rws twin: user {user!r} lacks the UAS grant {need.spelled()} that "
                   f"{need.what} needs (code {UAS_REJECT & 0xFFFFFFFF:#010x} "
                   f"SYS_CTRL_E_UAS_REJECT)")


def parse_grants(spec: str) -> frozenset[str]:
    """A role (``agent``, ``person``, ``factory``, ``none``) or grant ids separated by
    commas (``UAS_RAPID_EXECUTE,UAS_FTP_READ``); a one-line ``ValueError`` otherwise."""
    text = spec.strip()
    if text in ROLES:
        return ROLES[text]
    ids = [g.strip() for g in text.split(",") if g.strip()]
    unknown = [g for g in ids if g not in GRANTS]
    if not ids or unknown:
        raise ValueError(f"grants {spec!r}: expected a role ({', '.join(ROLES)}) or grant "
                         f"ids ({', '.join(GRANTS)}); unknown: {unknown or [spec]}")
    return frozenset(ids)


def grants_of_users(users: Iterable[str], given: Mapping[str, Iterable[str]] | None = None
                    ) -> dict[str, frozenset[str]]:
    """Each user's grants: those ``given``; else the factory ``Default User``'s
    (:data:`FACTORY_GRANTS`) for it, none for any other (fail closed). ``ValueError`` for
    grants given to no user or an unknown grant id."""
    names = list(users)
    given = dict(given or {})
    stray = sorted(set(given) - set(names))
    if stray:
        raise ValueError(f"grants for {stray}: no such user")
    out: dict[str, frozenset[str]] = {}
    for name in names:
        if name in given:
            grants = frozenset(given[name])
            unknown = sorted(grants - set(GRANTS))
            if unknown:
                raise ValueError(f"user {name!r}: unknown grants {unknown}")
            out[name] = grants
        else:
            out[name] = FACTORY_GRANTS if name == FACTORY_USER else frozenset()
    return out
