"""What every host of the fleet has, whatever its backend, and the hosts' union.

Why in core: every room that reaches a host (the transports, the session, deploy,
preflight, a trial) needs where it is and how to reach it, and none of them may know
which robots exist. A backend's own fields live with the backend, in its host model
(a subclass of :class:`HostBase`, declared by its plugin: ``testbed.core.backend_registry``);
:data:`HostConfig` is the union of every installed backend's model, chosen by
``backend``, built when a config is first validated (not at import: importing
``testbed`` loads no backend).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from pydantic import Field, GetCoreSchemaHandler, ValidationInfo, model_validator
from pydantic_core import CoreSchema, core_schema
from typing_extensions import Self

from testbed.core.backend_registry import DEFAULT_BACKEND, host_models
from testbed.core.config import (
    FieldProblem,
    Name,
    StrictModel,
    checking_files,
    expand_path,
)

__all__ = ["DEFAULT_ADDRESS", "DEFAULT_SSH_CONFIG", "SSH_ALIAS_PATTERN", "AnyHost",
           "ArmConfig", "HostBase", "HostConfig", "backend_tag", "default_hosts"]

SSH_ALIAS_PATTERN = r"^[A-Za-z0-9_][A-Za-z0-9_.+-]*$"
"""A word as ``ssh ALIAS`` takes it: never an option (no leading ``-``), no spaces."""
DEFAULT_ADDRESS = "127.0.0.1"
DEFAULT_SSH_CONFIG = "~/.ssh/config"


class ArmConfig(StrictModel):
    name: Name
    crop: tuple[int, int, int, int] | None = None
    """Pixel box (x0, y0, x1, y1) of this arm's workspace in the host camera image."""
    mirror: bool = False
    """Mirror the crop left-right into the canonical frame (the right arm)."""
    calibration: str | None = None
    """Path (on the host) of the image-to-table homography file (backends with the
    ``calibration`` capability)."""

    @model_validator(mode="after")
    def _crop_is_a_box(self) -> ArmConfig:
        if self.crop is not None:
            x0, y0, x1, y1 = self.crop
            if min(self.crop) < 0 or x1 <= x0 or y1 <= y0:
                raise ValueError("crop must be (x0, y0, x1, y1) with 0 <= x0 < x1, 0 <= y0 < y1")
        return self



class HostBase(StrictModel):
    """What every host has, whatever its backend: where it is and how to reach it.

    Paths are expanded (``~``, ``$VARS``) when the config is loaded: ``key_file``,
    ``known_hosts`` and ``ssh_config`` always (they are read on this machine, and a
    missing one is an error here, before anything starts), ``python``, ``workdir``, a
    YuMi ``camera`` path and the arms' ``calibration`` only for ``transport = "local"``.
    Over ssh those are paths on the robot host: they are passed as written and the agent
    expands them there.

    Two ways to say where an ssh host is. Explicit: ``address``, ``port``, ``user``,
    ``known_hosts`` and (optionally) ``key_file``, read from this file alone. By alias:
    ``ssh_alias`` names a ``Host`` of an OpenSSH client config (``ssh_config``, default
    ``~/.ssh/config``) and the host is reached as ``ssh ALIAS`` reaches it. With an
    alias, what the ssh config sets for it WINS (``HostName``, ``Port``, ``User``,
    ``IdentityFile``, ``ProxyJump``, ``UserKnownHostsFile``): it is the lab's one
    description of its hosts, which its people's ``ssh`` uses too, and a resolved config
    written back (a run's config.toml lists every default) must not start overriding
    it. ``port``, ``user``, ``key_file`` and ``known_hosts`` here fill in what the ssh
    config leaves unsaid (then OpenSSH's defaults: port 22, the local user,
    ``~/.ssh/known_hosts``); ``address`` is not used, so it may not be given. No key
    named anywhere: the running ssh-agent's keys (``SSH_AUTH_SOCK``).
    """

    name: Name
    if TYPE_CHECKING:  # each backend's model declares it, ``Literal["its name"]``, as
        backend: str  # its first own field (a resolved config lists it there)
    transport: Literal["local", "ssh"] = "local"
    address: str = DEFAULT_ADDRESS
    port: int = Field(22, ge=1, le=65535)
    user: str | None = None
    key_file: str | None = None
    """The private key to log in with; None: the ssh-agent's keys (or, with
    ``ssh_alias``, the ssh config's ``IdentityFile``)."""
    known_hosts: str | None = None
    ssh_alias: str | None = Field(None, pattern=SSH_ALIAS_PATTERN, max_length=253)
    """A ``Host`` alias of ``ssh_config``: reach the host as ``ssh ALIAS`` does, its
    bastions (``ProxyJump``) included (precedence: the class docstring)."""
    ssh_config: str | None = None
    """The OpenSSH client config that ``ssh_alias`` is looked up in; default (when
    ``ssh_alias`` is set) ``~/.ssh/config``. ``ProxyCommand``, ``Match exec`` and
    ``Include`` are refused when the host is reached: nothing local is ever run."""
    python: str = "python3"
    """Interpreter that runs the agent; over SSH it must be an absolute path."""
    workdir: str | None = None
    """Project checkout on the host (over SSH); the agent runs with it as PYTHONPATH."""
    deadline_s: float = Field(10.0, gt=0, le=600)
    """Per-call deadline for a push or an observation on this host."""
    heartbeat_s: float = Field(2.0, gt=0, le=600)
    """Idle time after which the controller checks the agent is alive (application
    heartbeat: SSH keepalives do not notice a dead peer)."""
    connect_timeout_s: float = Field(20.0, gt=0, le=600)
    """Budget to (re)connect: SSH handshake, agent start, backend start, hello."""
    arms: list[ArmConfig] = Field(default_factory=lambda: [ArmConfig(name="left"),
                                                          ArmConfig(name="right", mirror=True)])

    @model_validator(mode="after")
    def _transport_fields(self, info: ValidationInfo) -> Self:
        self._ssh_alias_fields()
        if self.transport == "ssh":
            missing = [f for f in ("user", "known_hosts") if getattr(self, f) is None]
            if missing and self.ssh_alias is None:
                raise ValueError(f"ssh transport needs {', '.join(missing)} (or ssh_alias: "
                                 "a Host of your ssh config)")
            if not self.python.startswith("/"):
                raise ValueError("python must be an absolute interpreter path over ssh")
        names = [a.name for a in self.arms]
        if len(set(names)) != len(names):
            raise ValueError("arm names must be unique within a host")
        if not self.arms:
            raise ValueError("a host needs at least one arm")
        self._expand_paths(checking_files(info))
        return self

    def _ssh_alias_fields(self) -> None:
        """An alias or a config file only make sense together and over ssh, and with an
        alias the ssh config says where the host is: an ``address`` as well would be
        silently ignored, so it is refused (the default, 127.0.0.1, is "not given")."""
        if self.ssh_alias is None:
            if self.ssh_config is not None:
                raise FieldProblem("ssh_alias", "ssh_config is set but ssh_alias is not; "
                                   "name the Host of that file to reach this host by")
            return
        if self.transport != "ssh":
            raise FieldProblem("ssh_alias", 'an ssh alias needs transport = "ssh"')
        if self.address != DEFAULT_ADDRESS:
            raise FieldProblem("address", f"address and ssh_alias both say where the host "
                               f"is; the HostName of {self.ssh_alias!r} in the ssh config "
                               "wins: leave address out (or drop ssh_alias)")
        if self.ssh_config is None:
            self._set("ssh_config", DEFAULT_SSH_CONFIG)

    def _set(self, field: str, value: Any) -> None:
        object.__setattr__(self, field, value)  # frozen: only while validating

    def _expand_paths(self, check_files: bool) -> None:
        for field in ("key_file", "known_hosts", "ssh_config"):
            raw = getattr(self, field)
            if raw is None:
                continue
            path = expand_path(raw, field)
            if check_files and not Path(path).is_file():
                shown = repr(path) if path == raw else f"{path!r} (from {raw!r})"
                raise FieldProblem(field, f"no such file {shown}; fix the path or create it")
            self._set(field, path)
        if self.transport != "local":
            return
        self._set("python", expand_path(self.python, "python"))  # "python3" stays as is
        if self.workdir is not None:
            self._set("workdir", expand_path(self.workdir, "workdir"))
        self._set("arms", [
            a if a.calibration is None else a.model_copy(update={
                "calibration": expand_path(a.calibration, f"arms[{i}].calibration")})
            for i, a in enumerate(self.arms)
        ])


HostConfig = HostBase
"""One host of the fleet, as the rooms that use it see it: a :class:`HostBase` (its
backend's model); read a backend's own fields only in that backend's folder."""


def backend_tag(value: Any) -> str:
    """The union's tag: ``backend``, the default backend when the key is absent."""
    backend = (value.get("backend", DEFAULT_BACKEND) if isinstance(value, dict)
               else getattr(value, "backend", DEFAULT_BACKEND))
    return backend if isinstance(backend, str) else repr(backend)


class AnyHost:
    """The type of a config's ``hosts`` entries: one of the installed backends' host
    models, chosen by ``backend`` (a tagged union, so an error names the field inside
    the chosen model). Its schema is made when a model holding it is first validated;
    those models set ``defer_build`` (``StrictModel`` does)."""

    @classmethod
    def __get_pydantic_core_schema__(cls, source: Any, handler: GetCoreSchemaHandler
                                     ) -> CoreSchema:
        return core_schema.tagged_union_schema(
            {name: handler.generate_schema(model) for name, model in host_models().items()},
            discriminator=backend_tag, custom_error_type="unknown_backend",
            custom_error_message="unknown backend")


def default_hosts() -> list[HostBase]:
    """The built-in fleet's hosts: two cells of the default backend."""
    model = host_models()[DEFAULT_BACKEND]
    return [model(name="cell0"), model(name="cell1")]
