"""The humans' config: ``[humans]``, ``[[humans.people]]`` and ``[humans.web]``.

Why here: each room keeps its own schema (``testbed/core/config.py`` loads them all and
says every error in one line); the humans' is read by the consoles, the scripted humans
and the report.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, Literal, Self

from pydantic import Field, ValidationInfo, field_validator, model_validator

from testbed.core.addresses import is_loopback_host
from testbed.core.config import FieldProblem, Name, StrictModel, checking_files, expand_path
from testbed.core.humans import ON_SITE, Place, unnamed_human

__all__ = ["TOKEN_PATTERN", "HumanProfile", "HumansConfig", "WebConsoleConfig"]

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
    overview_token: str | None = None
    """The read-only overview's secret (a link to share with whoever should watch); None:
    random, made at start. Only with ``tokens``."""
    operator_token: str | None = None
    """The operator's secret: the overview with pause and stop, which no other link has;
    None: random, made at start. Only with ``tokens``."""
    public_url: str | None = None
    """What the printed links start with, as others reach this machine: its name and
    port (``https://lab-pc.example.org:8765``), or a tunnel's or a reverse proxy's
    address with its path prefix (``https://lab.example.org/fleet``); None: the server's
    own address, a wildcard bind (``0.0.0.0``) replaced by this machine's name
    (docs/notes/web.md, "Reaching the console")."""
    tls: Literal["auto", "off"] = "auto"
    """``auto``: https off loopback, with ``certfile``/``keyfile`` when given, else a
    self-signed certificate made once on this machine, its fingerprint printed with the
    links (gui/web/tls.py); plain http on loopback. ``off``: plain http anywhere (behind
    a reverse proxy that terminates TLS)."""
    certfile: str | None = None
    """TLS certificate (PEM) for https; with ``keyfile``. Expands ``~`` and ``$VARS``."""
    keyfile: str | None = None
    """TLS private key (PEM) for https; with ``certfile``. Expands ``~`` and ``$VARS``."""
    grace_s: float = Field(10.0, ge=0, allow_inf_nan=False)
    """How long an away human's held intervention goes on before it is released."""
    away_timeout_s: float = Field(5.0, gt=0, allow_inf_nan=False)
    """The longest the fleet waits on an away human's teleop answer in a step."""
    teleop_timeout_s: float | None = Field(30.0, gt=0, allow_inf_nan=False)
    """The longest a step waits on a present human's answer: then that arm's step passes
    with no push (its row's ``action`` null; a reset stays asked) and the other arms go
    on, so one colleague who looks away does not stall the fleet (issue 44). ``null``:
    as long as it takes."""

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
        for name in ("overview_token", "operator_token"):
            token = getattr(self, name)
            if token is None:
                continue
            if not self.tokens:
                raise FieldProblem(name, "given without tokens: give every human's too")
            if not TOKEN_PATTERN.fullmatch(token):
                raise FieldProblem(name, f"a token of {len(token)} characters; it needs "
                                   ">= 16 characters of A-Z a-z 0-9 _ -")
            if token in self.tokens or (name == "operator_token"
                                        and token == self.overview_token):
                raise FieldProblem(name, "the same as another token; give it its own")
        if self.public_url is not None and not re.fullmatch(
                r"https?://[^\s/?#]+(/[^\s?#]*)?", self.public_url):
            raise FieldProblem("public_url", f"{self.public_url!r} is not an http(s) URL "
                               "(e.g. https://lab-pc.example.org:8765 or "
                               "https://lab.example.org/fleet)")
        if (self.public_url is not None and self.public_url.startswith("http://")
                and self.tls == "auto" and not is_loopback_host(self.host)):
            # certainly dead: the console serves https here (gui/web/tls.py). An https
            # public_url before a plain loopback console is a proxy's or tunnel's: fine
            raise FieldProblem("public_url", 'http:// but the console serves https off '
                               'loopback (tls = "auto"); write https://..., or tls = "off" '
                               "behind a proxy that terminates TLS")
        if self.tls == "off" and self.certfile is not None:
            raise FieldProblem("tls", '"off" with a certfile: remove the certfile for plain '
                               'http, or tls = "auto" to serve https with it')
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
    """One human of the fleet (TOML ``[[humans.people]]``): a name, where they are, and
    for a scripted human how it behaves.

    The name is how the records and the report know the person (the per-human table);
    it is recorded in every run (config.toml, run.json ``humans``), so it must never be
    a secret: a web console's token is a separate field. ``skill``, ``latency`` and
    ``availability`` describe a *scripted* human (``kind = "scripted"``), so a twin
    protocol can rehearse operators who differ (``testbed.experiments.scripted_humans``);
    a person at a console is measured, not described, so they are refused there.
    ``where`` is every kind's (a scripted human's too, so the twin rehearses a lab's
    split): a hard reset is hands on the cube, so only an ``on_site`` person is given
    one (docs/notes/core.md, "Allocation rules").
    """

    name: Name
    where: Place = "on_site"
    """``on_site``: in the room with the arms, given teleops and hard resets; ``remote``:
    anywhere else, given teleops only (a remote person's teleop on an arm that violates
    ends, and the reset goes to an on-site person). Default: on site, as every human was
    before the field existed."""
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
    named ``human0``, ``human1``, ... with perfect scripted profiles, all on site. Given
    without ``count``, it sets the count. With humans, at least one must be on site
    (``where``): only a person in the room can do a hard reset."""

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
        if self.people and not any(self.on_site):
            raise FieldProblem("people", "nobody is on site, and a hard reset needs a "
                               "person in the room with the arms: set where = \"on_site\" "
                               "for at least one of [[humans.people]]")
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
        return [p.name for p in self.people] or [unnamed_human(i) for i in range(self.count)]

    @property
    def profiles(self) -> list[HumanProfile]:
        """Each human's profile, by index (perfect ones when ``people`` is empty)."""
        return list(self.people) or [HumanProfile(name=n) for n in self.names]

    @property
    def on_site(self) -> list[bool]:
        """Per human, by index: on site (may be given hard resets)? All True when
        ``people`` is empty; the allocator's mask (``Allocator(on_site=...)``)."""
        return [p.where == ON_SITE for p in self.profiles]

    @property
    def places(self) -> list[str]:
        """Each human's ``where``, by index (what the consoles are told)."""
        return [p.where for p in self.profiles]

    @model_validator(mode="after")
    def _one_token_per_human(self) -> Self:
        tokens = self.web.tokens
        if tokens and len(tokens) != self.count:
            given = f"{len(tokens)} token{'s' if len(tokens) != 1 else ''}"
            raise FieldProblem("web.tokens", f"{given} for humans.count = {self.count}; "
                               "give one per human, or none (random ones are made at "
                               "start)")
        return self
