"""RAPID data on the twin: symbols (``RAPID/<task>/<module>/<name>``), their values as
RAPID text, and the records the motion answers need (tooldata, wobjdata).

Why it exists: RWS reads and writes RAPID variables as text (``[TRUE,[[0,0,0],[1,0,0,0]],
...]``), the ABB clients set persistent variables that way, and the position a controller
reports for a named tool is the flange plus that tool's ``tframe``. The twin keeps typed
symbols, checks a new value parses as its type (a real controller refuses a malformed one),
and stores it re-printed the way RAPID prints values (``10``, ``0.5``, ``9E+09``).

Every motion task has the built-in ``tool0``, ``wobj0`` and ``load0`` (module ``BASE``).
A symbol's URL may omit the module (``RAPID/T_ROB_L/reg1``) when the name is unique in
the task, as the ABB client does; ``CONST`` symbols cannot be set.

What RAPID does to data, so that the twin fails where a controller would (issue 29):
a module is a PROGRAM module or a SYSTEM module (``MODULE X(SYSMODULE)``, and ``BASE``);
"PP to Main" sets every ``VAR`` of the task back to its declared value
(:meth:`SymbolTable.reset_vars`: a zone identity kept in a VAR reads ``[0]`` again,
while PERS, TASK PERS and CONST keep theirs); "Reset RAPID" removes every program module
and keeps the system modules (:meth:`SymbolTable.drop_program_modules`), their
routines (:class:`Routine`, a Python stand-in for a RAPID routine the twin plays, e.g.
an event routine) included.
"""

from __future__ import annotations

import math
import re
import threading
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any

from sim_twin.rws.errors import GENERIC, NO_SUCH_SYMBOL, RwsError, refused

Value = float | bool | str | list["Value"]
_TOKEN = re.compile(r'\s*(?:(?P<open>\[)|(?P<close>\])|(?P<comma>,)|"(?P<str>(?:[^"\\]|\\.|"")*)"'
                    r'|(?P<bool>TRUE|FALSE)\b|(?P<num>[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?))',
                    re.IGNORECASE)

_POS, _ORIENT = ["n"] * 3, ["n"] * 4
_POSE = [_POS, _ORIENT]
_LOAD = ["n", _POS, _ORIENT, "n", "n", "n"]
SHAPES: dict[str, Any] = {
    "num": "n", "dnum": "n", "bool": "b", "string": "s", "pos": _POS, "orient": _ORIENT,
    "pose": _POSE, "loaddata": _LOAD, "tooldata": ["b", _POSE, _LOAD],
    "wobjdata": ["b", "b", "s", _POSE, _POSE], "confdata": ["n"] * 4,
    "extjoint": ["n"] * 6, "robjoint": ["n"] * 6,
    "robtarget": [_POS, _ORIENT, ["n"] * 4, ["n"] * 6],
    "jointtarget": [["n"] * 6, ["n"] * 6], "speeddata": ["n"] * 4,
    "zonedata": ["b"] + ["n"] * 6,
}
"""The record shapes the twin checks: ``n`` number, ``b`` bool, ``s`` string; a list is
a record of those. Other types are accepted if they parse as a RAPID literal."""
TOOL0 = "[TRUE,[[0,0,0],[1,0,0,0]],[0.001,[0,0,0.001],[1,0,0,0],0,0,0]]"
WOBJ0 = '[FALSE,TRUE,"",[[0,0,0],[1,0,0,0]],[[0,0,0],[1,0,0,0]]]'
LOAD0 = "[0,[0,0,0],[1,0,0,0],0,0,0]"


def parse_value(text: str) -> Value:
    """A RAPID literal (number, TRUE/FALSE, "string", or ``[...]`` of them) as Python
    values; ``ValueError`` if it is not one."""
    pos, stack = 0, [[]]  # type: ignore[var-annotated]
    expect_item = True
    while pos < len(text):
        if text[pos:].strip() == "":
            break
        m = _TOKEN.match(text, pos)
        if m is None:
            raise ValueError(f"not a RAPID value at {text[pos:pos + 20]!r}")
        pos = m.end()
        if m.group("open"):
            stack.append([])
            expect_item = True
        elif m.group("close"):
            if len(stack) < 2:
                raise ValueError("unbalanced ']'")
            done = stack.pop()
            stack[-1].append(done)
            expect_item = False
        elif m.group("comma"):
            if expect_item or len(stack) < 2:
                raise ValueError("misplaced ','")
            expect_item = True
        else:
            if not expect_item:
                raise ValueError("missing ',' between values")
            if m.group("str") is not None:
                stack[-1].append(m.group("str").replace('""', '"'))
            elif m.group("bool"):
                stack[-1].append(m.group("bool").upper() == "TRUE")
            else:
                stack[-1].append(float(m.group("num")))
            expect_item = False
    if len(stack) != 1 or len(stack[0]) != 1:
        raise ValueError("not exactly one RAPID value")
    return stack[0][0]  # type: ignore[no-any-return]


def format_number(v: float) -> str:
    """As RAPID prints a num: ``10``, ``0.5``, ``9E+09``."""
    if not math.isfinite(v):
        raise ValueError("RAPID numbers are finite")
    if v == int(v) and abs(v) < 1e7:
        return str(int(v))
    return format(v, ".9g").replace("e", "E")


def format_value(v: Value) -> str:
    if isinstance(v, bool):
        return "TRUE" if v else "FALSE"
    if isinstance(v, float | int):
        return format_number(float(v))
    if isinstance(v, str):
        return '"' + v.replace('"', '""') + '"'
    return "[" + ",".join(format_value(x) for x in v) + "]"


def _check(v: Value, shape: Any, where: str) -> None:
    if isinstance(shape, list):
        if not isinstance(v, list) or len(v) != len(shape):
            raise ValueError(f"{where}: expected a record of {len(shape)} fields")
        for i, (x, s) in enumerate(zip(v, shape, strict=True)):
            _check(x, s, f"{where}.{i + 1}")
        return
    ok = {"n": isinstance(v, float) and not isinstance(v, bool),
          "b": isinstance(v, bool), "s": isinstance(v, str)}[shape]
    if not ok:
        raise ValueError(f"{where}: expected a {dict(n='num', b='bool', s='string')[shape]}")


def check_value(type_name: str, text: str, dims: Sequence[int] = ()) -> Value:
    """Parse ``text`` as a value of ``type_name`` (an array if ``dims``); ``ValueError``."""
    v = parse_value(text)
    shape = SHAPES.get(type_name.lower())
    for d in reversed(dims):
        shape = [shape] * d if shape is not None else None
    if shape is not None:
        _check(v, shape, type_name)
    if isinstance(v, str) and type_name.lower() == "string" and len(v) > 80:
        raise ValueError("a RAPID string holds at most 80 characters")
    return v


@dataclass
class Symbol:
    task: str
    module: str
    name: str
    type: str
    value: str
    storage: str = "PERS"
    dims: tuple[int, ...] = ()
    init: str = ""
    """The declared value (what PP to Main gives a VAR back); "" = ``value``."""

    @property
    def path(self) -> str:
        return f"RAPID/{self.task}/{self.module}/{self.name}"


RoutineBody = Callable[[str], None]
"""What the twin does for a RAPID routine, called with the task's name."""


@dataclass(frozen=True)
class Routine:
    """A routine of a loaded module (the twin plays its effect in Python)."""

    task: str
    module: str
    name: str
    body: RoutineBody


class SymbolTable:
    """The RAPID symbols the twin knows, thread-safe."""

    def __init__(self, motion_tasks: Iterable[str]) -> None:
        self._lock = threading.Lock()
        self._symbols: dict[tuple[str, str, str], Symbol] = {}
        self._system: set[tuple[str, str]] = set()
        self._routines: dict[tuple[str, str, str], Routine] = {}
        for t in motion_tasks:
            self.declare_module(t, "BASE", system=True)
            self.declare(t, "BASE", "tool0", "tooldata", TOOL0)
            self.declare(t, "BASE", "wobj0", "wobjdata", WOBJ0)
            self.declare(t, "BASE", "load0", "loaddata", LOAD0)

    def declare(self, task: str, module: str, name: str, type_name: str, value: str,
                storage: str = "PERS", dims: Sequence[int] = ()) -> Symbol:
        """Add (or replace) a symbol; its value must parse as its type."""
        if storage.upper() not in ("PERS", "VAR", "CONST", "TASK PERS"):
            raise ValueError(f"storage must be PERS, VAR, CONST or TASK PERS, got {storage!r}")
        text = format_value(check_value(type_name, value, dims))
        s = Symbol(task, module, name, type_name.lower(), text, storage.upper(), tuple(dims),
                   text)
        with self._lock:
            self._symbols[(task.upper(), module.upper(), name.upper())] = s
        return s

    def undeclare(self, task: str, module: str, name: str) -> bool:
        """Remove a symbol (a module unloaded); False if there was none."""
        with self._lock:
            return self._symbols.pop((task.upper(), module.upper(), name.upper()),
                                     None) is not None

    def declare_module(self, task: str, module: str, *, system: bool) -> None:
        """Record whether ``module`` of ``task`` is a system module (``SYSMODULE``); a
        module never declared counts as a program module."""
        key = (task.upper(), module.upper())
        with self._lock:
            if system:
                self._system.add(key)
            else:
                self._system.discard(key)

    def is_system(self, task: str, module: str) -> bool:
        with self._lock:
            return (task.upper(), module.upper()) in self._system

    def has_module(self, task: str, module: str) -> bool:
        """Whether any symbol or routine of ``module`` is loaded in ``task``."""
        key = (task.upper(), module.upper())
        with self._lock:
            return any(k[:2] == key for k in (*self._symbols, *self._routines))

    def declare_routine(self, task: str, module: str, name: str, body: RoutineBody) -> None:
        with self._lock:
            self._routines[(task.upper(), module.upper(), name.upper())] = Routine(
                task, module, name, body)

    def routine(self, task: str, name: str) -> Routine | None:
        """The routine ``name`` of ``task`` (any module), None if no module holds it."""
        with self._lock:
            return next((r for k, r in self._routines.items()
                         if (k[0], k[2]) == (task.upper(), name.upper())), None)

    def undeclare_routine(self, task: str, module: str, name: str) -> None:
        with self._lock:
            self._routines.pop((task.upper(), module.upper(), name.upper()), None)

    def reset_vars(self, task: str) -> list[str]:
        """PP to Main in ``task``: every VAR back to its declared value (in program and
        system modules alike: the twin's assumption, docs/rws-checklist.md asks);
        returns the paths of those that changed."""
        changed = []
        with self._lock:
            for (t, _, _), s in self._symbols.items():
                if t == task.upper() and s.storage == "VAR" and s.value != (s.init or s.value):
                    s.value = s.init
                    changed.append(s.path)
        return changed

    def drop_program_modules(self) -> list[str]:
        """Reset RAPID: remove every symbol and routine of a program module (any task);
        system modules stay. Returns the ``task/module`` names removed."""
        with self._lock:
            gone = {k[:2] for k in (*self._symbols, *self._routines)
                    if k[:2] not in self._system}
            self._symbols = {k: s for k, s in self._symbols.items() if k[:2] not in gone}
            self._routines = {k: r for k, r in self._routines.items() if k[:2] not in gone}
        return sorted(f"{t}/{m}" for t, m in gone)

    def find(self, parts: Sequence[str]) -> Symbol:
        """The symbol of a URL's ``RAPID/...`` parts: ``[task, module, name]``,
        ``[task, name]`` (unique in the task) or ``[name]`` (unique anywhere)."""
        keys = [p.upper() for p in parts]
        with self._lock:
            if len(keys) == 3:
                hits = [s for k, s in self._symbols.items() if k == tuple(keys)]
            elif len(keys) == 2:
                hits = [s for k, s in self._symbols.items() if (k[0], k[2]) == tuple(keys)]
            elif len(keys) == 1:
                hits = [s for k, s in self._symbols.items() if k[2] == keys[0]]
            else:
                hits = []
        if len(hits) != 1:
            what = "no" if not hits else "more than one"
            raise refused(400, NO_SUCH_SYMBOL, f"{what} RAPID symbol RAPID/{'/'.join(parts)}")
        return hits[0]

    def find_typed(self, task: str, name: str, type_name: str) -> Symbol | None:
        """A task's symbol of a given name and type (tool, wobj lookups)."""
        with self._lock:
            for (t, _, n), s in self._symbols.items():
                if t == task.upper() and n == name.upper() and s.type == type_name:
                    return s
        return None

    def set(self, parts: Sequence[str], text: str) -> Symbol:
        s = self.find(parts)
        if s.storage == "CONST":
            raise refused(400, GENERIC, f"{s.path} is a CONST")
        try:
            value = format_value(check_value(s.type, text, s.dims))
        except ValueError as exc:
            raise refused(400, GENERIC, f"{s.path}: {exc}") from None
        with self._lock:
            s.value = value
        return s

    def all(self) -> list[Symbol]:
        with self._lock:
            return list(self._symbols.values())


def numbers(v: Value) -> list[float]:
    """The numbers of a (nested) record, depth first."""
    if isinstance(v, list):
        return [x for item in v for x in numbers(item)]
    return [float(v)] if isinstance(v, float) and not isinstance(v, bool) else []


def tool_frame(value: str) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """``(trans, quat wxyz)`` of a tooldata's ``tframe``."""
    v = parse_value(value)
    if not isinstance(v, list) or len(v) != 3:
        raise RwsError(400, GENERIC, "not a tooldata")
    f = numbers(v[1])
    return tuple(f[:3]), tuple(f[3:7])


def wobj_frames(value: str) -> list[tuple[tuple[float, ...], tuple[float, ...]]]:
    """``[uframe, oframe]`` of a wobjdata, each ``(trans, quat wxyz)``."""
    v = parse_value(value)
    if not isinstance(v, list) or len(v) != 5:
        raise RwsError(400, GENERIC, "not a wobjdata")
    out = []
    for frame in v[3:5]:
        f = numbers(frame)
        out.append((tuple(f[:3]), tuple(f[3:7])))
    return out
