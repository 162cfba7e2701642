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
    hardware_twin   how ``testbed rehearse`` stands a stand-in in a host's place
                    (:class:`HardwareTwin`: its process, the ports it writes, the
                    host's fields that reach it, calibration, its lab side channel)
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
import zlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib.metadata import EntryPoint, entry_points
from pathlib import Path
from typing import Any, ClassVar, Final, Protocol

from pydantic import BaseModel

__all__ = ["BUILTIN", "DEFAULT_BACKEND", "ENTRY_POINT_GROUP", "Backend", "BackendError",
           "Capabilities", "HardwareTwin", "HostLike", "TwinPlace", "backend", "backend_lines",
           "backend_of", "backends", "host_models"]

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

    def names(self) -> list[str]:
        """The capabilities that are on, for ``testbed check`` and ``testbed deploy``."""
        return [k for k, v in vars(self).items() if v]


@dataclass(frozen=True)
class TwinPlace:
    """Where ``testbed rehearse`` stands one host's hardware twin: what the lab gives it.

    Why: a backend's :class:`HardwareTwin` says how to start its stand-in and how to
    reach it; the lab owns the folder, the seed and the pace. Every file of one host's
    twin is named from here, so a rehearsal run again finds (and a reaper kills) the
    same ones."""

    host: str
    arms: tuple[str, ...]
    folder: Path
    """The lab's folder (absolute: an sshd's config and a stand-in's cwd differ)."""
    seed: int
    """The twin's world seed: the protocol's first seed and the host's index."""
    realtime: float = 0.0
    """Pace motion at this many times real time (0: as fast as it computes)."""
    camera_fps: float = 15.0

    def file(self, what: str) -> Path:
        """``FOLDER/HOST-WHAT``: one file of this host's twin (a login, a log)."""
        return self.folder / f"{self.host}-{what}"

    def port_file(self, port: str) -> Path:
        """``FOLDER/HOST.PORT``: where the stand-in writes the port called ``port`` once
        it serves it (the lab waits for the file, then reads one integer)."""
        return self.folder / f"{self.host}.{port}"

    @property
    def key(self) -> int:
        """A number (0..999999) stable for this folder and host and unlikely to be another
        lab's: a stand-in controller's serial, on which robot locks are keyed."""
        return zlib.crc32(f"{self.folder}/{self.host}".encode()) % 1_000_000


class HardwareTwin:
    """How ``testbed rehearse`` stands a hardware twin in one host's place (a backend's
    optional declaration, :meth:`Backend.hardware_twin`; subclass it in the plugin).

    Why: a rehearsal runs a lab's physical protocol unchanged but for where its hosts
    are, so it must know, per backend, what plays the robot (a process serving the
    robot's own API on loopback, or nothing when the backend's agent is its own
    stand-in), which fields of the host's config point the agent at it, whether the arms
    are calibrated against it, and what the lab can see and do there that the
    controller cannot (the ``/lab/*`` side channel). The lab adds the rest: one real
    ``sshd`` per host in front of the agent, the host's transport, interpreter and
    folder rewritten to reach it (``testbed.lab.hardware_twin.HardwareTwinLab``).
    """

    ports: ClassVar[tuple[str, ...]] = ()
    """The ports the stand-in process serves, each written to ``place.port_file(name)``
    when it is ready; the lab waits for every one before the host's sshd starts."""
    lab_port: ClassVar[str | None] = None
    """The port (one of ``ports``) of the lab's side channel ``/lab/*`` (truth, the lab
    hand, the true camera: ``testbed.lab.lab_client.LabClient``). With it, scripted
    humans read the table's truth, the lab hand resets a cube, and each run's truth is
    recorded and scored; None: the host's own observations carry the expert's action
    and its backend does its own resets (the ``simulated`` capability)."""
    calibrate: ClassVar[bool] = False
    """The rehearsal calibrates the host's arms against the stand-in (``testbed
    calibrate``, scored against the side channel's true camera: needs ``lab_port``)."""
    faults: ClassVar[bool] = False
    """The side channel injects and clears the lab's faults (``/lab/fault``,
    ``/lab/clear``): ``testbed rehearse --faults`` needs it on every host."""
    request_log: ClassVar[str | None] = None
    """The stand-in logs each controller request it serves, one JSON line, to
    ``place.file(request_log)``; each run keeps its share (``hosts/<host>.rws.jsonl``)."""

    def prepare(self, place: TwinPlace) -> None:
        """Write what the stand-in and the agent share before it starts (a controller's
        login file, mode 0600). Default: nothing."""
        return None

    def identity(self, place: TwinPlace) -> str | None:
        """The stand-in robot's own name for itself (a controller's serial, on which the
        agent's robot lock is keyed), derived from ``place.key`` so that each host of a
        lab, and of another lab on this machine, has its own. None: it has none."""
        return None

    def command(self, place: TwinPlace) -> list[str] | None:
        """The stand-in's argv, run from the product's folder with its output in
        ``place.file("twin.log")``, in a session of its own (the lab kills its group);
        None: no process, the agent's own backend plays the robot."""
        return None

    def host_fields(self, host: HostLike, place: TwinPlace, ports: Mapping[str, int]
                    ) -> dict[str, Any]:
        """The host's own fields that point its agent at the stand-in (``ports``: each of
        ``ports``' number), e.g. a camera URL and a controller URL. Default: none."""
        return {}


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
    nominal_push_s: ClassVar[float | None] = None
    """Seconds a fleet step of its arms nominally takes (the push and the picture after
    it; a host's arms push at once): what the time estimate before step 1
    (``testbed/experiments/pace.py``) assumes until the lab has pushes of its own on
    record. None: not declared (the estimate then says it assumed a default)."""
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

    def hardware_twin(self) -> HardwareTwin | None:
        """How ``testbed rehearse`` stands a hardware twin in this backend's hosts' place;
        None (the default): a rehearsal refuses its hosts, naming the field."""
        return None

    def default_table_box(self, arm: str, calibration: Mapping[str, Any] | None = None
                          ) -> tuple[float, float, float, float] | None:
        """The table box (x0, y0, x1, y1), mm, in the robot's world frame, that an arm
        whose ``calibration`` (its file's keys; None: no file yet) has no
        ``table_box_mm`` is driven in while it is calibrated: what ``testbed calibrate``
        uses when given no ``--box``. None (the default): the backend has none, and
        ``--box`` is required. Backends with the ``calibration`` capability whose arms
        have a shipped layout override it."""
        return None

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
            f"{', '.join(_can(b)) or 'none beyond the contract'}"
            for name, b in backends().items()]


def _can(b: Backend) -> list[str]:
    """Its capabilities' names, and ``hardware_twin`` when it declares one."""
    return b.capabilities.names() + (["hardware_twin"] if b.hardware_twin() else [])


def host_models() -> dict[str, type[BaseModel]]:
    """The host config model of every backend, by name (the config's union)."""
    return {name: b.host_model for name, b in backends().items()}
