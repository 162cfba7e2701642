"""The config's loading: TOML read, validated by pydantic, every error one line.

Why pydantic: it gives typed, nested validation with the failing field's path for free,
so every bad config becomes one line that names the field (docs/config.md) instead
of a traceback deep inside a driver. Why only the loading here: each room keeps its own
schema (the hosts' with their backends, ``testbed/core/host_config.py`` for what every
host has; the humans' in ``testbed/people/``; the algorithm's in ``testbed/fleet/``;
learning's in ``testbed/learning/``; the whole fleet and its loaders in
``testbed/experiments/fleet_config.py``), and every one of them subclasses
:class:`StrictModel` and is parsed by :func:`parse_model`, so they all refuse the same
way and say it in the same one line.
"""

from __future__ import annotations

import os
import re
import sys
import types
from pathlib import Path
from typing import Annotated, Any, TypeVar, Union, get_args, get_origin

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
)

from testbed.core.backend_registry import host_models

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


ModelT = TypeVar("ModelT", bound=StrictModel)
"""Any config model (each room's section, the fleet, a protocol)."""


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
        fix = f"got {got!r}" if not isinstance(got, dict | list) else "see docs/config.md"
    loc = ".".join(str(p) if not isinstance(p, int) else f"[{p}]" for p in parts)
    loc = loc.replace(".[", "[") or "(top level)"
    more = len(err.errors()) - 1
    tail = f" (+{more} more)" if more else ""
    return f"{source}: {loc}: {msg}{'; ' + fix if fix else ''}{tail}"


def parse_model(model: type[ModelT], data: dict[str, Any], source: str = "config", *,
                check_files: bool = True, prefix: tuple[str, ...] = ()) -> ModelT:
    """Validate a dict into ``model``, or raise ConfigError with one line.

    ``prefix``: where the dict sits in its file (``("fleet",)`` for a protocol's fleet),
    so the error names the field as the file spells it.
    """
    try:
        return model.model_validate(data, context=validation_context(check_files))
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
