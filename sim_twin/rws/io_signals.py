"""The controller's I/O signals as RWS shows them (``rw/iosystem/signals/<net>/<dev>/<name>``).

Why it exists: ``abb_motion_program_exec`` steers its RAPID module through signals
(``motion_program_preempt`` and friends, analog outputs; ``motion_program_log_motion``
and ``motion_program_stop_egm``, digital outputs), read and written with the ABB client's
``get/set_digital_io`` and ``get/set_analog_io`` on the default path ``Local/DRV_1``. The
twin keeps those signals (and any others configured) with their values, so the later
RAPID-semantics work reads what the client set.

A signal answers on its full path and on its bare name (``rw/iosystem/signals/<name>``).
Outputs can be set; an input only when simulated (``lstate=simulated`` in the same
request, as RWS's form allows). Modes ``value`` (default), ``invert`` and ``toggle``.
"""

from __future__ import annotations

import threading
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from sim_twin.rws.errors import GENERIC, refused
from sim_twin.rws.rapid_data import format_number

TYPES = ("DI", "DO", "AI", "AO", "GI", "GO")


@dataclass
class Signal:
    name: str
    type: str
    network: str = "Local"
    device: str = "DRV_1"
    category: str = ""
    lvalue: float = 0.0
    simulated: bool = False

    @property
    def title(self) -> str:
        return f"{self.network}/{self.device}/{self.name}"

    def text(self) -> str:
        return format_number(self.lvalue)

    def item(self, list_item: bool = False) -> dict[str, Any]:
        base = {"_type": "ios-signal-li" if list_item else "ios-signal", "_title": self.title,
                "name": self.name, "type": self.type, "category": self.category,
                "lvalue": self.text(),
                "lstate": "simulated" if self.simulated else "not simulated"}
        if not list_item:
            base.update({"unitnm": self.device, "phstate": "valid", "pvalue": self.text(),
                         "quality": "1"})
        return base


def default_signals() -> list[Signal]:
    """The signals ``abb_motion_program_exec``'s robot setup defines, on Local/DRV_1."""
    ao = ["motion_program_preempt", "motion_program_preempt_cmd_num",
          "motion_program_preempt_current", "motion_program_current_cmd_num",
          "motion_program_queued_cmd_num", "motion_program_seqno"]
    do = ["motion_program_stop_egm", "motion_program_log_motion"]
    return [Signal(n, "AO") for n in ao] + [Signal(n, "DO") for n in do]


class SignalTable:
    """Thread-safe signal values."""

    def __init__(self, signals: Iterable[Signal] | None = None) -> None:
        self._lock = threading.Lock()
        self._signals: dict[str, Signal] = {}
        for s in default_signals() if signals is None else signals:
            if s.type not in TYPES:
                raise ValueError(f"signal {s.name}: type must be one of {TYPES}")
            self._signals[s.name.upper()] = s

    def find(self, parts: Sequence[str]) -> Signal:
        with self._lock:
            s = self._signals.get(parts[-1].upper()) if parts else None
        if s is None or (len(parts) == 3 and [parts[0].upper(), parts[1].upper()]
                         != [s.network.upper(), s.device.upper()]) or len(parts) not in (1, 3):
            raise refused(404, GENERIC, f"no signal {'/'.join(parts)!r}")
        return s

    def listing(self) -> list[dict[str, Any]]:
        with self._lock:
            return [s.item(list_item=True) for s in self._signals.values()]

    def set(self, parts: Sequence[str], form: Mapping[str, str]) -> Signal:
        """Apply RWS's ``action=set`` form (``lvalue``, ``mode``, ``lstate``)."""
        s = self.find(parts)
        with self._lock:
            if "lstate" in form:
                if form["lstate"] not in ("simulated", "not simulated"):
                    raise refused(400, GENERIC, f"lstate={form['lstate']!r}")
                s.simulated = form["lstate"] == "simulated"
            if "lvalue" not in form and form.get("mode", "value") == "value":
                if "lstate" in form:
                    return s
                raise refused(400, GENERIC, "action=set needs lvalue")
            if s.type in ("DI", "AI", "GI") and not s.simulated:
                raise refused(400, GENERIC, f"{s.title} is an input (not simulated)")
            s.lvalue = self._new_value(s, form)
        return s

    @staticmethod
    def _new_value(s: Signal, form: Mapping[str, str]) -> float:
        mode = form.get("mode", "value")
        digital = s.type in ("DI", "DO")
        if mode in ("invert", "toggle"):
            if not digital:
                raise refused(400, GENERIC, f"mode={mode} is for digital signals")
            return 0.0 if s.lvalue else 1.0
        if mode != "value":
            raise refused(400, GENERIC, f"mode={mode!r} is not modelled by the twin")
        try:
            v = float(form["lvalue"])
        except ValueError:
            raise refused(400, GENERIC, f"lvalue={form['lvalue']!r} is not a number") from None
        if digital and v not in (0.0, 1.0):
            raise refused(400, GENERIC, f"{s.title}: a digital value is 0 or 1")
        if s.type in ("GI", "GO") and (v < 0 or v != int(v)):
            raise refused(400, GENERIC, f"{s.title}: a group value is a whole number >= 0")
        return v

    def value(self, name: str) -> float:
        """A signal's value (the twin's Python side: the RAPID work reads these)."""
        return self.find([name]).lvalue

    def write(self, name: str, value: float) -> None:
        """Set a signal from the controller's side (RAPID's SetDO/SetAO), any type."""
        s = self.find([name])
        with self._lock:
            s.lvalue = float(value)
