"""Host backends as plugins: what a backend declares, and where the product finds them.

Why: a lab with a UR5e, a Franka or an OmniCore YuMi must be able to add its robot
without forking the product. A backend is one folder (or one installed package) whose
``plugin.py`` holds ONE object, a :class:`Backend` (on the agent's side a
``drivers.backends.plugin.BackendPlugin``), that declares everything the rest of the
product needs to know about it:

    name            "twin", "yumi", "ur5e": the ``backend = "..."`` of a host's config
    host_model      the pydantic model of its hosts (the fields it adds, validated)
    capabilities    what it can do: calibrate, a full camera frame, a shared cell, ...
    extra           the ``pip`` extra a robot host installs for it
    verify_imports  the modules that prove a host install can run its agent
    agent side      its flags, how to build its ``HostBackend``, its robot's lock

The core, the agent, deploy, the lock, preflight and calibration ask the registry for a
*capability*, never for a name: "can this backend calibrate?" keeps working when the
next robot arrives; "is this a YuMi?" does not.

Where plugins come from: the package entry points of group ``testbed.backends``
(``[project.entry-points."testbed.backends"]``, as pytest finds its plugins), each
naming the plugin object (``name = "package.module:OBJECT"``). The product's own twin
and YuMi are registered the same way in its ``pyproject.toml``; a checkout that is on
``sys.path`` without being installed still finds them (``BUILTIN``).

This module is the one door through which any room reaches a backend's declaration,
and only when it is asked (the first config parsed, ``testbed check``): importing
``testbed`` loads no backend. A plugin module must stay light (pydantic, the standard
library, ``testbed.core``); heavy clients are imported inside its agent-side calls.
"""

from __future__ import annotations

import functools
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib.metadata import EntryPoint, entry_points
from typing import Any, ClassVar, Final, Protocol

from pydantic import BaseModel

__all__ = ["BUILTIN", "DEFAULT_BACKEND", "ENTRY_POINT_GROUP", "Backend", "BackendError",
           "Capabilities", "HostLike", "backend", "backend_lines", "backend_of", "backends",
           "host_models"]

ENTRY_POINT_GROUP: Final = "testbed.backends"
"""The entry point group a package registers its backends in."""

DEFAULT_BACKEND: Final = "twin"
"""The backend of a host whose config names none (the built-in twin fleet's hosts)."""

BUILTIN: Final = {"twin": "drivers.backends.twin.twin_plugin:BACKEND",
                  "yumi": "drivers.yumi.yumi_plugin:BACKEND"}
"""The product's own backends, as its ``pyproject.toml`` registers them: found here too
when this checkout runs without being installed (``PYTHONPATH`` on a host)."""

_NAME = re.compile(r"[a-z][a-z0-9_-]*")


class HostLike(Protocol):
    """What the registry reads of a host's config: its name and its backend. The model
    every host's config extends is ``testbed.core.host_config.HostBase``; it is not
    imported here, since that module imports this registry for its union of backends."""

    name: str
    backend: str


class BackendError(ValueError):
    """A backend is unknown, or its plugin is broken; ``str()`` is one line to print."""


@dataclass(frozen=True)
class Capabilities:
    """What a backend can do; the product asks these, never the backend's name.

    Each flag is a promise about the backend's ``HostBackend`` and its hosts; the
    defaults are a robot that can do the five calls of the contract and nothing more.
    """

    simulated: bool = False
    """A simulation: no person at the robot, no hardware to wear. Such hosts may be fanned
    out on Ray workers, get the expert's row in a protocol's evaluation, and be
    teleoperated by scripted humans (their observations carry the expert's action)."""
    calibration: bool = False
    """``move_tcp`` and ``save_calibration``: ``testbed calibrate`` drives its arms over
    a grid and writes each arm's image-to-table homography on the host."""
    camera_frame: bool = False
    """``frame()``: the full camera frame (``testbed check`` draws crops and workspaces)."""
    shared_cell: bool = False
    """A host's arms work over one table: a person resetting one has hands near the
    other, so the loop holds the other's pushes during a reset."""
    controller: bool = False
    """A robot controller that names itself: ``describe()`` for ``testbed check``, and the
    hello's ``controller`` (serial, software, system) in run.json."""
    robot_lock: bool = False
    """The agent takes the robot's lock (``drivers/hostlock.py``) on the controller's own
    identity, so two users of one host never drive one robot."""
    stop: bool = False
    """``stop()`` stops a motion in flight (a twin's strokes last milliseconds: no)."""
    hardware_twin: bool = False
    """``testbed rehearse`` can stand a hardware twin (``sim_twin/yumi_server.py``) in its
    place behind a real sshd."""

    def names(self) -> list[str]:
        """The capabilities that are on, for ``testbed check`` and ``testbed deploy``."""
        return [k for k, v in vars(self).items() if v]


@dataclass
class Backend:
    """A backend's declaration (subclass it in the backend's ``plugin.py``).

    The class attributes are the declaration; the methods are the calls the controller's
    rooms make of a backend and its hosts, each with a default that fits a robot with
    none of the optional capabilities.
    """

    name: ClassVar[str]
    host_model: ClassVar[type[BaseModel]]
    """Its hosts' config model, a ``testbed.core.host_config.HostBase`` subclass."""
    capabilities: ClassVar[Capabilities] = Capabilities()
    extra: ClassVar[str | None] = None
    """The ``pip`` extra a robot host installs for this backend (``"yumi"``), or None."""
    verify_imports: ClassVar[tuple[str, ...]] = ()
    """Modules a host install must import for its agent to run this backend."""
    host_requirements: ClassVar[tuple[str, ...]] = ()
    """What else a robot host installs for it (``pip`` requirements): a lab's own backend
    names its package here (``"lab-ur5e==1.2"``); the product's use ``extra``."""
    origin: str = field(default="", compare=False)
    """Where it was found, set by the registry (entry point, package and version)."""

    def scripted_teleop(self, host: HostLike) -> bool:
        """Whether scripted humans can teleoperate ``host``'s arms: its observations carry
        the expert's action. Default: a simulation can."""
        return self.capabilities.simulated

    def controller_report(self, host: HostLike, info: Mapping[str, Any]
                          ) -> tuple[list[str], list[str]]:
        """What ``testbed check`` prints of a controller's ``describe()`` ``info``: (report
        lines, FAULT lines: what to fix before a trial). Backends with the ``controller``
        capability override it."""
        return [], []

    def layout_report(self, host: HostLike, calibrations: Mapping[str, Mapping[str, Any]],
                      info: Mapping[str, Any] | None = None) -> tuple[list[str], list[str]]:
        """What ``testbed calibrate`` prints of the arms' layout after a fit: (report lines,
        FAULT lines) of ``calibrations`` (arm -> its calibration file's keys) with the
        controller's ``describe()`` ``info`` when it could be read. Backends whose arms
        have kinematics (the YuMi's reach, rest pose, clearances) override it."""
        return [], []


def _load(ep: EntryPoint, where: str) -> Backend:
    try:
        obj = ep.load()
    except Exception as exc:  # a lab's broken plugin is named, never a traceback
        raise BackendError(f"backend {ep.name!r} ({ep.value}, {where}) does not load: "
                           f"{type(exc).__name__}: {exc}") from None
    if not isinstance(obj, Backend):
        raise BackendError(f"backend {ep.name!r} ({ep.value}, {where}) is a "
                           f"{type(obj).__name__}, not a testbed.core.backend_registry.Backend")
    if obj.name != ep.name or not _NAME.fullmatch(obj.name):
        raise BackendError(f"backend {ep.name!r} ({ep.value}, {where}) declares the name "
                           f"{obj.name!r}; the entry point's name must equal it (lowercase "
                           "letters, digits, - and _)")
    field = getattr(obj, "host_model", None)
    field = None if field is None else field.model_fields.get("backend")
    if field is None or field.default != obj.name:
        raise BackendError(f"backend {ep.name!r} ({ep.value}, {where}): its host_model must "
                           f"declare backend: Literal[{obj.name!r}] = {obj.name!r}")
    obj.origin = f"{ep.value} ({where})"
    return obj


@functools.cache
def backends() -> dict[str, Backend]:
    """Every backend found, by name: the entry points of ``testbed.backends``, then the
    product's own (``BUILTIN``) that no installed package registered. Loaded once."""
    found: dict[str, Backend] = {}
    for ep in sorted(entry_points(group=ENTRY_POINT_GROUP), key=lambda e: e.name):
        dist = ep.dist
        where = (f"package {dist.metadata['Name']} {dist.version}" if dist is not None
                 else "an entry point")
        if ep.name in found:
            raise BackendError(f"backend {ep.name!r} is registered twice ({ep.value}, "
                               f"{where}; and {found[ep.name].origin}); uninstall one")
        found[ep.name] = _load(ep, where)
    for name, value in BUILTIN.items():
        if name not in found:
            found[name] = _load(EntryPoint(name, value, ENTRY_POINT_GROUP), "this checkout")
    return found


def backend(name: str) -> Backend:
    """The backend called ``name``; BackendError naming the ones installed otherwise."""
    found = backends()
    if name not in found:
        raise BackendError(f"unknown backend {name!r}; installed: {', '.join(found)} (a "
                           "lab's own robot registers an entry point in group "
                           f"{ENTRY_POINT_GROUP!r}: docs/ARCHITECTURE.md)")
    return found[name]


def backend_of(host: HostLike) -> Backend:
    """The backend that drives ``host``."""
    return backend(host.backend)


def backend_lines() -> list[str]:
    """One line per backend found: its name, where it came from, what it can do (what
    ``testbed check`` and ``testbed deploy`` print first)."""
    return [f"backend {name}: {b.origin}; capabilities: "
            f"{', '.join(b.capabilities.names()) or 'none beyond the contract'}"
            for name, b in backends().items()]


def host_models() -> dict[str, type[BaseModel]]:
    """The host config model of every backend, by name (the config's union)."""
    return {name: b.host_model for name, b in backends().items()}
