"""The fleet configuration: a TOML file validated by pydantic, unknown keys rejected.

Why pydantic: it gives typed, nested validation with the failing field's path for free,
so every bad config becomes one line that names the field (the README's "Config") instead
of a traceback deep inside a driver. ``load_config`` is the only way a config enters
the program; ``default_twin_config`` is the built-in 2 x 2-arm twin fleet that
``testbed trial`` runs with no ``--config``.
"""

from __future__ import annotations

import os
import re
import sys
import types
from pathlib import Path
from typing import Annotated, Any, Literal, Union, get_args, get_origin

from typing_extensions import Self

if sys.version_info >= (3, 11):
    import tomllib  # novermin (guarded: Python 3.10 reads TOML with tomli)
else:  # a robot host's Python 3.10
    import tomli as tomllib

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

NAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9_.-]*$"
Name = Annotated[str, Field(pattern=NAME_PATTERN, max_length=64)]


class ConfigError(ValueError):
    """A config or argument that cannot be used; ``str()`` is the one line to print."""


def _scalar_kind(annotation: Any) -> type | None:
    """``bool``, ``int`` or ``float`` when a field (or the items of its tuple or list)
    holds that scalar, else None; ``X | None`` and ``Annotated[X, ...]`` look through."""
    origin = get_origin(annotation)
    if origin is Annotated:
        return _scalar_kind(get_args(annotation)[0])
    if origin in (Union, types.UnionType):
        kinds = {_scalar_kind(a) for a in get_args(annotation) if a is not type(None)}
        return kinds.pop() if len(kinds) == 1 else None
    if origin in (tuple, list):
        kinds = {_scalar_kind(a) for a in get_args(annotation) if a is not Ellipsis}
        return kinds.pop() if len(kinds) == 1 else None
    return annotation if annotation in (bool, int, float) else None


_KIND_TEXT = {bool: "a TOML boolean (true or false)", int: "a TOML integer",
              float: "a TOML number"}


def _toml_typed(kind: type, value: Any) -> bool:
    """Is ``value`` (as TOML gave it) of ``kind``? No string for a boolean or a number,
    no boolean for a number (pydantic's lax mode would take ``"yes"`` as true)."""
    if kind is bool:
        return isinstance(value, bool)
    if isinstance(value, bool):
        return False
    return isinstance(value, int) if kind is int else isinstance(value, int | float)


class StrictModel(BaseModel):
    """Every config model's base: unknown keys are errors, values frozen, TOML's types
    taken strictly. ``defer_build``: a model's schema is made when it is first used, so
    a config that holds hosts (their union is every installed backend's model,
    ``testbed.core.host_config.AnyHost``) loads no backend when ``testbed`` is imported."""

    model_config = ConfigDict(extra="forbid", frozen=True, defer_build=True)

    @field_validator("*", mode="before")
    @classmethod
    def _toml_types(cls, value: Any, info: ValidationInfo) -> Any:
        """Config values take TOML's types strictly: ``mirror = "yes"`` or
        ``deadline_s = "20"`` is an error naming the field, never a guess."""
        field = cls.model_fields.get(info.field_name or "")
        kind = None if field is None else _scalar_kind(field.annotation)
        if kind is None or value is None:
            return value
        items = value if isinstance(value, list | tuple) else [value]
        if not all(_toml_typed(kind, v) for v in items):
            got = next(v for v in items if not _toml_typed(kind, v))
            what = "a string" if isinstance(got, str) else type(got).__name__
            raise ValueError(f"must be {_KIND_TEXT[kind]}, not {what}")
        return value


class FieldProblem(ValueError):
    """A model-level check that is about one field: ``field`` joins the error's location,
    so the one-line error names it (``hosts[0].key_file: ...``), not just the host."""

    def __init__(self, field: str, message: str) -> None:
        super().__init__(message)
        self.field = field


CHECK_FILES = "check_files"
"""Validation-context key: ``False`` skips the existence check of key_file/known_hosts
(for tools that load a protocol to rewrite its hosts, e.g. a rehearsal; paths are still
expanded)."""


def validation_context(check_files: bool = True) -> dict[str, Any]:
    """The pydantic ``context`` for ``model_validate`` of a fleet or a protocol."""
    return {CHECK_FILES: check_files}


def checking_files(info: ValidationInfo) -> bool:
    ctx = info.context
    return not (isinstance(ctx, dict) and ctx.get(CHECK_FILES) is False)


_VAR = re.compile(r"\$(?:\{(?P<braced>[A-Za-z_][A-Za-z0-9_]*)\}|(?P<plain>[A-Za-z_][A-Za-z0-9_]*))")


def expand_path(text: str, field: str) -> str:
    """``~`` and ``$VAR``/``${VAR}`` expanded as a shell would; an unset variable is an
    error naming it (``os.path.expandvars`` would leave ``$VAR`` in the path silently)."""

    def value(m: re.Match[str]) -> str:
        name = m.group("braced") or m.group("plain")
        if name not in os.environ:
            raise FieldProblem(field, f"${name} is not set (in {text!r}); set it or write "
                               "the path out")
        return os.environ[name]

    return _VAR.sub(value, os.path.expanduser(text))


from testbed.core.backend_registry import host_models  # noqa: E402


class _Hosts:
    """``testbed.core.host_config.AnyHost``, looked up when the schema is made: that
    module subclasses the base classes above, so it cannot be imported before them."""

    @classmethod
    def __get_pydantic_core_schema__(cls, source: Any, handler: Any) -> Any:
        from testbed.core.host_config import AnyHost

        return handler.generate_schema(AnyHost)


def _default_hosts() -> list[Any]:
    from testbed.core.host_config import default_hosts

    return default_hosts()

TOKEN_PATTERN = re.compile(r"[A-Za-z0-9_-]{16,}")
"""A web console token: at least 16 characters, URL-safe (it travels in the link)."""

_HOSTNAME = re.compile(r"[A-Za-z0-9]([A-Za-z0-9.-]*[A-Za-z0-9])?")


class WebConsoleConfig(StrictModel):
    """The browser console (``humans.kind = "web"``, TOML ``[humans.web]``).

    Humans on their own devices come and go: ``grace_s`` and ``away_timeout_s`` bound
    what an away human costs the fleet (``testbed.core.humans.Presence``). The server binds
    to loopback unless ``host`` says otherwise: exposing it is a decision the config
    must state, never a default. Without ``tokens`` each human gets a random token at
    start (printed as their link). Tokens are credentials: a run's config.toml is
    written without them (``RunDir.write_config``), so a resumed run makes new ones
    unless its operator gives the config that has them.
    """

    host: str = "127.0.0.1"
    """Bind address (an IP address or a host name); anything but loopback only when set."""
    port: int = Field(8765, ge=0, le=65535)
    """TCP port; 0 picks a free one at start."""
    tokens: list[str] = Field(default_factory=list)
    """One secret per human (``humans.count`` of them, unique, each >= 16 characters of
    A-Z a-z 0-9 _ -); empty: a random one per human, made at start."""
    certfile: str | None = None
    """TLS certificate (PEM) for https; with ``keyfile``. Expands ``~`` and ``$VARS``."""
    keyfile: str | None = None
    """TLS private key (PEM) for https; with ``certfile``. Expands ``~`` and ``$VARS``."""
    grace_s: float = Field(10.0, ge=0, allow_inf_nan=False)
    """How long an away human's held intervention goes on before it is released."""
    away_timeout_s: float = Field(5.0, gt=0, allow_inf_nan=False)
    """The longest the fleet waits on an away human's teleop answer in a step."""
    teleop_timeout_s: float | None = Field(None, gt=0, allow_inf_nan=False)
    """The longest it waits on a present human's answer (None: as long as it takes)."""

    @field_validator("host")
    @classmethod
    def _host(cls, v: str) -> str:
        import ipaddress

        v = v.strip()
        try:
            ipaddress.ip_address(v)
        except ValueError:
            if not _HOSTNAME.fullmatch(v) or len(v) > 253:
                raise ValueError("give an IP address or a host name to bind to, e.g. "
                                 "127.0.0.1 (this machine only) or 0.0.0.0 (every "
                                 "interface)") from None
        return v

    @model_validator(mode="after")
    def _tokens_and_tls(self, info: ValidationInfo) -> Self:
        for i, token in enumerate(self.tokens):
            if not TOKEN_PATTERN.fullmatch(token):
                # the token itself is a secret: named by its position, never echoed
                raise FieldProblem(f"tokens[{i}]", f"a token of {len(token)} characters; "
                                   "each needs >= 16 characters of A-Z a-z 0-9 _ - (e.g. "
                                   "python -c 'import secrets; print(secrets."
                                   "token_urlsafe(24))')")
        if len(set(self.tokens)) != len(self.tokens):
            raise FieldProblem("tokens", "two humans have the same token; give each "
                               "human their own")
        if (self.certfile is None) != (self.keyfile is None):
            given, missing = (("certfile", "keyfile") if self.keyfile is None
                              else ("keyfile", "certfile"))
            raise FieldProblem(missing, f"{given} is set but {missing} is not; https "
                               "needs both (or neither, for plain http)")
        for name in ("certfile", "keyfile"):
            raw = getattr(self, name)
            if raw is None:
                continue
            path = expand_path(raw, name)
            if checking_files(info) and not Path(path).is_file():
                shown = repr(path) if path == raw else f"{path!r} (from {raw!r})"
                raise FieldProblem(name, f"no such file {shown}; fix the path or create it")
            object.__setattr__(self, name, path)  # frozen: only while validating
        return self


class HumanProfile(StrictModel):
    """One human of the fleet (TOML ``[[humans.people]]``): a name, and for a scripted
    human how it behaves.

    The name is how the records and the report know the person (the per-human table);
    it is recorded in every run (config.toml, run.json ``humans``), so it must never be
    a secret: a web console's token is a separate field. ``skill``, ``latency`` and
    ``availability`` describe a *scripted* human (``kind = "scripted"``), so a twin
    protocol can rehearse operators who differ (``testbed.experiments.scripted_humans``);
    a person at a console is measured, not described, so they are refused there.
    """

    name: Name
    skill: float = Field(1.0, ge=0.0, le=1.0, allow_inf_nan=False)
    """How often a teleop push is the expert's; otherwise one of the other three faces."""
    latency: int = Field(0, ge=0, le=1000)
    """Timesteps from an assignment to the first action (the twin runs as fast as it
    can, so a latency in seconds would mean nothing there): a teleop's first push comes
    at its ``latency``-th step, a hard reset takes ``latency`` steps more than t_R."""
    availability: float = Field(1.0, gt=0.0, le=1.0, allow_inf_nan=False)
    """The chance, each timestep, that the human can take a new intervention (else they
    are away for that step's allocation; a held intervention goes on)."""

    @property
    def scripted_only(self) -> list[str]:
        """The profile fields set away from a perfect, instant, always-there human."""
        return [f for f, perfect in (("skill", 1.0), ("latency", 0), ("availability", 1.0))
                if getattr(self, f) != perfect]


class HumansConfig(StrictModel):
    count: int = Field(2, ge=0, le=1000)
    kind: Literal["scripted", "gui", "web"] = "scripted"
    web: WebConsoleConfig = WebConsoleConfig()
    """The browser console's settings (TOML ``[humans.web]``), read when kind is web."""
    people: list[HumanProfile] = Field(default_factory=list)
    """One entry per human, in index order (TOML ``[[humans.people]]``); empty: humans
    named ``human0``, ``human1``, ... with perfect scripted profiles. Given without
    ``count``, it sets the count."""

    @model_validator(mode="before")
    @classmethod
    def _count_from_people(cls, data: Any) -> Any:
        if isinstance(data, dict) and "count" not in data and isinstance(
                data.get("people"), list):
            return {**data, "count": len(data["people"])}
        return data

    @model_validator(mode="after")
    def _people(self) -> Self:
        if self.people and len(self.people) != self.count:
            raise FieldProblem("people", f"{len(self.people)} people for humans.count = "
                               f"{self.count}; give one [[humans.people]] per human, or "
                               "drop count")
        names = [p.name for p in self.people]
        for i, name in enumerate(names):
            if name in names[:i]:
                raise FieldProblem(f"people[{i}].name", f"{name!r} twice; each human "
                                   "needs their own name")
        if self.kind != "scripted":
            for i, p in enumerate(self.people):
                if p.scripted_only:
                    raise FieldProblem(f"people[{i}].{p.scripted_only[0]}", "describes a "
                                       f"scripted human, and humans.kind is {self.kind!r}: "
                                       "a person at a console is measured, not described")
        return self

    @property
    def names(self) -> list[str]:
        """Each human's name, by index."""
        return [p.name for p in self.people] or [f"human{i}" for i in range(self.count)]

    @property
    def profiles(self) -> list[HumanProfile]:
        """Each human's profile, by index (perfect ones when ``people`` is empty)."""
        return list(self.people) or [HumanProfile(name=n) for n in self.names]

    @model_validator(mode="after")
    def _one_token_per_human(self) -> Self:
        tokens = self.web.tokens
        if tokens and len(tokens) != self.count:
            given = f"{len(tokens)} token{'s' if len(tokens) != 1 else ''}"
            raise FieldProblem("web.tokens", f"{given} for humans.count = {self.count}; "
                               "give one per human, or none (random ones are made at "
                               "start)")
        return self


QUANTILE = re.compile(r"q(0(\.\d+)?|1(\.0*)?|\.\d+)")


def quantile_of(value: object) -> float | None:
    """p of a threshold given as ``"q<p>"`` (``"q0.75"`` -> 0.75), else None."""
    if isinstance(value, str) and QUANTILE.fullmatch(value):
        return float(value[1:])
    return None


MATCH_BUDGET = re.compile(r"match:[a-z0-9][a-z0-9-]*")
"""``random_budget = "match:<algorithm>"``: Random gets the human effort of that algorithm."""


class AlgorithmConfig(StrictModel):
    """Allocation hyperparameters (the paper's 8.3, Table 1; docs/notes/core.md)."""

    name: str = "cur"
    t_T: int = Field(3, ge=1, description="minimum teleoperation time")
    t_R: int = Field(5, ge=1, description="hard reset time")
    t_I: int = Field(10, ge=0, description="C.U.R. initial period")
    u_hat: float | str = Field(
        0.05, description="uncertainty threshold in [0, 1], or 'q<p>' (e.g. 'q0.75'): that "
        "quantile of theta_0's uncertainty on its pretraining rollouts, resolved when the "
        "run starts and written into its config.toml")
    r_hat: float | str = Field(0.5, description="risk threshold, as u_hat")
    thrifty_alpha: float = Field(0.5, ge=0.0, le=1.0)
    thrifty_threshold: float = 0.0
    random_budget: float | str = Field(
        0.3, description="Random: the mean fraction of humans busy, or 'match:<algorithm>' "
        "(in a protocol: the fraction that algorithm's run of the same trial used)")

    @field_validator("u_hat", "r_hat")
    @classmethod
    def _threshold(cls, v: float | str) -> float | str:
        if isinstance(v, str):
            if quantile_of(v) is None:
                raise ValueError("a number in [0, 1] or a quantile 'q<p>' with p in [0, 1], "
                                 "e.g. 'q0.75'")
            return v
        if not 0.0 <= v <= 1.0:
            raise ValueError(f"must be in [0, 1], got {v}")
        return float(v)

    @property
    def quantile_thresholds(self) -> dict[str, float]:
        """The thresholds given as quantiles: name -> p (empty when all are numbers)."""
        out: dict[str, float] = {}
        for name in ("u_hat", "r_hat"):
            q = quantile_of(getattr(self, name))
            if q is not None:
                out[name] = q
        return out

    @field_validator("random_budget")
    @classmethod
    def _budget(cls, v: float | str) -> float | str:
        if isinstance(v, str):
            if not MATCH_BUDGET.fullmatch(v):
                raise ValueError("a number in [0, 1] or 'match:<algorithm>', e.g. 'match:cur'")
            return v
        if not 0.0 <= v <= 1.0:
            raise ValueError(f"the fraction of humans busy must be in [0, 1], got {v}")
        return float(v)

    @property
    def budget_match(self) -> str | None:
        """The algorithm Random's budget matches (``match:<algorithm>``), else None."""
        if isinstance(self.random_budget, str):
            return self.random_budget.split(":", 1)[1]
        return None


class LearningConfig(StrictModel):
    ensemble_size: int = Field(5, ge=1, le=32)
    batch_size: int = Field(256, ge=1, le=65536)
    lr: float = Field(3e-4, gt=0, lt=1)
    augmentation_factor: int = Field(10, ge=1, le=100)
    gradient_steps: int = Field(1, ge=0, le=100, description="per timestep")
    demos: int = Field(375, ge=1, description="offline state-action pairs")
    critic_transitions: int = Field(1000, ge=0, description="BC rollouts for the critics")
    pretrain_steps: int = Field(300, ge=0)
    critic_pretrain_steps: int | None = Field(
        None, ge=0, description="critics' offline steps; None: pretrain_steps. The seed "
        "trains them 3000 steps; the goal critic needs ~600 at batch 64 (docs/notes/learning.md)")
    gamma_safe: float = Field(0.5, ge=0, le=1)
    gamma_goal: float = Field(0.999, ge=0, le=1)
    device: Literal["auto", "cpu", "cuda"] = "auto"
    compile_act: bool = Field(
        False, description="run the fleet loop's forward pass through torch.compile: "
        "1.65x faster at 100 arms on 2 CPU cores, ~20 s to compile, needs a C compiler "
        "(falls back to eager with a warning); not worth it for a few arms")

    @property
    def critic_steps(self) -> int:
        """The critics' offline gradient steps (``critic_pretrain_steps`` if set)."""
        return self.pretrain_steps if self.critic_pretrain_steps is None else (
            self.critic_pretrain_steps)


class TrialConfig(StrictModel):
    steps: int = Field(250, ge=1, le=1_000_000)
    seed: int = 0
    out: str = "runs"


class FleetConfig(StrictModel):
    name: Name = "twin"
    trial: TrialConfig = TrialConfig()
    humans: HumansConfig = HumansConfig()
    algorithm: AlgorithmConfig = AlgorithmConfig()
    learning: LearningConfig = LearningConfig()
    hosts: list[_Hosts] = Field(default_factory=_default_hosts)

    @model_validator(mode="after")
    def _unique_hosts(self) -> FleetConfig:
        names = [h.name for h in self.hosts]
        if len(set(names)) != len(names):
            raise ValueError("host names must be unique")
        if not self.hosts:
            raise ValueError("a fleet needs at least one host")
        return self

    @property
    def robot_names(self) -> list[str]:
        return [f"{h.name}/{a.name}" for h in self.hosts for a in h.arms]


def _where(loc: tuple[int | str, ...]) -> tuple[list[int | str], str | None]:
    """The error's location without the union's tag (``hosts.0.yumi.camera`` ->
    ``hosts[0].camera``), and that tag (the host's backend) if there was one."""
    parts: list[int | str] = []
    tag = None
    for k, p in enumerate(loc):
        if (p in host_models() and k >= 2 and isinstance(loc[k - 1], int)
                and loc[k - 2] == "hosts"):
            tag = str(p)
            continue
        parts.append(p)
    return parts, tag


def _one_line(err: ValidationError, source: str, prefix: tuple[str, ...] = ()) -> str:
    """The first error as ``SOURCE: FIELD.PATH: what is wrong; the fix (+N more)``."""
    first = err.errors()[0]
    parts, tag = _where(prefix + tuple(first["loc"]))
    msg = first["msg"].removeprefix("Value error, ")
    problem = first.get("ctx", {}).get("error")
    if isinstance(problem, FieldProblem):
        parts.append(problem.field)
    got = first.get("input")
    if first["type"] == "extra_forbidden":
        key = str(parts[-1])
        other = [b for b, m in host_models().items() if b != tag and key in m.model_fields]
        if tag is not None and other and len(parts) >= 2 and isinstance(parts[-2], int):
            msg = f"{key} is a {other[0]}-only field, not one of a {tag} host"
            fix = f"remove it, or set backend = \"{other[0]}\""
        else:
            msg = "unknown key"
            fix = "remove it or check its spelling (unknown keys are errors)"
    elif first["type"] == "missing":
        fix = f"add it (a {tag} host needs it)" if tag is not None else "add it"
    elif first["type"] == "unknown_backend":
        parts.append("backend")
        got = got.get("backend") if isinstance(got, dict) else got
        fix = f"got {got!r}; use {' or '.join(repr(b) for b in host_models())}"
    elif isinstance(problem, FieldProblem):
        fix = ""  # its message says what to do
    else:
        fix = f"got {got!r}" if not isinstance(got, dict | list) else "see README, section Config"
    loc = ".".join(str(p) if not isinstance(p, int) else f"[{p}]" for p in parts)
    loc = loc.replace(".[", "[") or "(top level)"
    more = len(err.errors()) - 1
    tail = f" (+{more} more)" if more else ""
    return f"{source}: {loc}: {msg}{'; ' + fix if fix else ''}{tail}"


def parse_config(data: dict[str, Any], source: str = "config", *,
                 check_files: bool = True, prefix: tuple[str, ...] = ()) -> FleetConfig:
    """Validate a dict into a FleetConfig, or raise ConfigError with one line.

    ``prefix``: where the dict sits in its file (``("fleet",)`` for a protocol's fleet),
    so the error names the field as the file spells it.
    """
    try:
        return FleetConfig.model_validate(data, context=validation_context(check_files))
    except ValidationError as err:
        raise ConfigError(_one_line(err, source, prefix)) from None


def read_toml(path: str | Path, what: str = "config") -> dict[str, Any]:
    """A TOML file as a dict, or ConfigError naming the file and what is wrong with it."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read the {what} file ({exc.strerror})") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{p}: the {what} file is not UTF-8 text") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{p}: not valid TOML ({exc})") from None


PROTOCOL_KEYS = ("algorithms", "trials")


def file_kind(data: dict[str, Any]) -> Literal["fleet", "protocol"]:
    """A protocol has top-level ``algorithms``/``trials`` or a ``[fleet]`` table; anything
    else is read as a fleet config (and validated as one)."""
    if isinstance(data.get("fleet"), dict) or any(k in data for k in PROTOCOL_KEYS):
        return "protocol"
    return "fleet"


def require_protocol(data: dict[str, Any], path: str | Path) -> None:
    """Name a fleet config given where a protocol is expected, in one line."""
    if file_kind(data) == "fleet":
        raise ConfigError(
            f"{path} is a fleet config, not a protocol: run it with `testbed trial --config "
            f"{path}`, or give a protocol file (top-level algorithms and trials, its fleet "
            "in a [fleet] table)")


def load_fleet(path: str | Path | None, *, check_files: bool = True) -> FleetConfig:
    """The fleet of a fleet config or of a protocol file (its ``[fleet]`` table).

    Every verb that takes a fleet reads it here, so ``testbed check --config
    protocols/physical.toml`` checks the protocol's own hosts. ``None`` gives the
    built-in twin fleet.
    """
    if path is None:
        return default_twin_config()
    data = read_toml(path)
    if file_kind(data) == "protocol":
        fleet = data.get("fleet", {})
        if not isinstance(fleet, dict):
            raise ConfigError(f"{path}: fleet: a protocol's fleet must be a [fleet] table")
        return parse_config(fleet, str(path), check_files=check_files, prefix=("fleet",))
    return parse_config(data, str(path), check_files=check_files)


def load_config(path: str | Path | None) -> FleetConfig:
    """Read and validate a fleet config (or a protocol's fleet): ``load_fleet``."""
    return load_fleet(path)


TWIN_U_HAT = 0.17
"""The twin's uncertainty threshold: the 75th percentile of its ensemble's uncertainty
in C.U.R. runs (the paper's 0.05 made 55% of the twin's arm-steps eligible)."""


def default_twin_config() -> FleetConfig:
    """2 twin hosts x 2 arms, 2 scripted humans, local transport, 250 steps, C.U.R.

    Pretraining is sized for README command 1's 10-minute target (setup, pretraining
    and the 250-step trial at the paper's batch 256, on a 2-core machine): 60 policy +
    60 critic steps (~2 min; the trial's training steps are the rest). 120 steps
    evaluated no better within the noise of ``testbed evaluate`` (docs/notes/fleet.md,
    issue 13); the paper-scale pretraining lives in ``protocols/*.toml``. u_hat is the
    twin's 0.17: the 75th percentile of the uncertainty in C.U.R. runs, measured before
    quantile thresholds existed (the protocols now give ``"q0.75"``).
    """
    return FleetConfig(algorithm=AlgorithmConfig(u_hat=TWIN_U_HAT),
                       learning=LearningConfig(pretrain_steps=60, critic_transitions=400))
