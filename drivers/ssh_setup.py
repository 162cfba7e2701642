"""How a robot host is reached over SSH as labs reach theirs: aliases, bastions, agents.

Why this module: labs do not type addresses. A robot host half a mile away is an alias
of ``~/.ssh/config`` (``HostName``, ``User``, ``Port``, ``IdentityFile``), reached
through a bastion (``ProxyJump``), with a key that lives in ``ssh-agent`` or behind a
passphrase. The controller must reach it the way ``ssh ALIAS`` does, without starting a
local process (no ``ssh`` binary, no ``ProxyCommand``, no ``Match exec``) and without
weakening the rules of ``drivers.transport``: every hop's host key is checked against
known_hosts files only (a ``RejectPolicy``, hashed entries included), key auth only,
every error one line that names the hop.

Two halves, so the first can be checked without a network:

* :func:`resolve_route` reads the host's config, and with ``ssh_alias`` its ssh config
  (``paramiko.SSHConfig``), into a :class:`Route`: the bastions, nearest first, then
  the host. Precedence (``testbed.core.host_config.HostBase``): what the ssh config sets for
  an alias wins; the host's ``port``/``user`` (the host itself only) and
  ``key_file``/``known_hosts`` (every hop) fill in what it leaves unsaid; then OpenSSH's
  defaults. ``ProxyJump a,b`` is followed as OpenSSH does: ``a`` by its own config
  (its own ProxyJump too), ``b`` through ``a``, the host through ``b``.
* :func:`connect` walks the route: TCP to the first hop, then each next hop over a
  ``direct-tcpip`` channel of the previous hop's connection. Keys are tried in order by
  a ``paramiko.auth_strategy.AuthStrategy``: for each named key the ssh-agent's copy if
  it holds one (``paramiko.Agent``), else the file, decrypted by :data:`KEYRING` (its
  passphrase asked once per process through a prompt that tests can answer, kept in
  memory only as the decrypted key); with no key named, every key of the agent.

Over 450 lines, on purpose: it resolves a host as ``ssh ALIAS`` would (the config,
ProxyJump chains, keys, the agent, passphrases); the parts are read together when a
lab's host does not connect, and each is small.
"""

from __future__ import annotations

import base64
import contextlib
import fnmatch
import getpass
import hashlib
import os
import re
import socket
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import paramiko
from paramiko.auth_strategy import (
    AuthFailure,
    AuthSource,
    AuthStrategy,
    InMemoryPrivateKey,
    PrivateKey,
)

from drivers.errors import HostKeyError, TransportError
from testbed.core.config import ConfigError
from testbed.core.host_config import HostConfig

DEFAULT_KNOWN_HOSTS = "~/.ssh/known_hosts"
MAX_HOPS = 8
"""The longest route (bastions and the host); a longer one is taken for a ProxyJump loop."""
PASSPHRASE_TRIES = 3


class SshConfigError(TransportError, ConfigError):
    """An ssh config the driver will not follow (a local command, an ``Include``, a
    ProxyJump loop, a line it cannot parse): a setting to fix, and a host that cannot be
    reached until it is."""


class BastionError(TransportError):
    """A bastion on the way to the host is unreachable, refused us, or could not open the
    tunnel onwards: the host is faulted, the message names the bastion."""


class KeyUnavailable(TransportError):
    """A named key that cannot be used: unreadable, or its passphrase not given."""


def one_line(text: str) -> str:
    """Every message here is one line (a Fault's reason, a log line)."""
    return " ".join(str(text).split())


# -- the route ---------------------------------------------------------------------------
@dataclass(frozen=True)
class Hop:
    """One SSH server on the way: where it is and how we log in to it."""

    role: str
    """How messages name it: ``host cell0`` or ``host cell0: bastion jump``."""
    name: str
    """The alias (or address) as written."""
    hostname: str
    port: int
    user: str
    identity_files: tuple[str, ...]
    """Named keys, in order; empty: every key of the ssh-agent."""
    known_hosts: tuple[str, ...]
    bastion: bool = False

    @property
    def where(self) -> str:
        return f"{self.hostname}:{self.port}"

    def error(self, message: str) -> TransportError:
        """The error class of a failure at this hop (a bastion's says so)."""
        return (BastionError if self.bastion else TransportError)(one_line(message))


@dataclass(frozen=True)
class Route:
    hops: tuple[Hop, ...]
    """Bastions nearest first, the host last."""
    ssh_config: str | None = None

    @property
    def target(self) -> Hop:
        return self.hops[-1]


def resolve_route(host: HostConfig) -> Route:
    """The hops to ``host``, from its config (and its ssh config): no network, no process.

    Raises SshConfigError (one line naming the option and the file) for what the driver
    will not follow, TransportError for a host that cannot be described."""
    role = f"host {host.name}"
    if host.ssh_alias is None:
        if host.user is None or host.known_hosts is None:
            raise TransportError(f"{role}: ssh needs user and known_hosts (or ssh_alias)")
        keys = (host.key_file,) if host.key_file else ()
        return Route((Hop(role, host.address, host.address, host.port, host.user, keys,
                          (host.known_hosts,)),))
    path = host.ssh_config or os.path.expanduser("~/.ssh/config")
    resolver = _Resolver(host, path, load_ssh_config(path, role))
    resolver.check_named(host.ssh_alias)
    return Route(tuple(resolver.route(host.ssh_alias, role, target=True)), path)


_MATCH_EXEC = re.compile(r"(^|\s)!?exec(\s|$)", re.IGNORECASE)


def load_ssh_config(path: str, who: str) -> paramiko.SSHConfig:
    """``paramiko.SSHConfig`` of ``path``, after refusing what would run or hide things.

    Why a scan before paramiko: ``Match exec`` runs its command at every lookup (through
    ``invoke``), whatever the host, so it must be refused before any lookup; paramiko
    ignores ``Include``, so the hosts of an included file would silently not exist."""
    try:
        text = Path(path).read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise SshConfigError(f"{who}: cannot read ssh config {path}: {exc.strerror}") from None
    for number, raw in enumerate(text.splitlines(), 1):
        m = paramiko.SSHConfig.SETTINGS_REGEX.match(raw.strip())
        if m is None or raw.strip().startswith("#"):
            continue
        key, value = m.group(1).lower(), m.group(2)
        if key == "match" and _MATCH_EXEC.search(value):
            raise SshConfigError(f"{who}: Match exec in {path} (line {number}) is refused: "
                                 "it runs a local command; match on host names instead")
        if key == "include":
            raise SshConfigError(f"{who}: Include in {path} (line {number}) is refused: "
                                 "it is not followed; copy the included Host blocks in")
    try:
        return paramiko.SSHConfig.from_text(text)
    except Exception as exc:  # ConfigParseError, and anything paramiko trips on
        raise SshConfigError(one_line(f"{who}: ssh config {path}: {exc}")) from None


def parse_jump(spec: str) -> tuple[str | None, str, int | None]:
    """``[user@]host[:port]`` or ``ssh://[user@]host[:port]`` (a ProxyJump entry)."""
    spec = spec.strip().removeprefix("ssh://")
    user, _, rest = spec.rpartition("@")
    m = re.fullmatch(r"\[([^\]]+)\](?::(\d+))?|([^:\[\]]+)(?::(\d+))?", rest)
    if not rest or m is None:
        raise ValueError(f"not [user@]host[:port]: {spec!r}")
    name, port = (m.group(1), m.group(2)) if m.group(1) else (m.group(3), m.group(4))
    return user or None, name, int(port) if port else None


@dataclass
class _Resolver:
    """Hops of one host's ssh config (OpenSSH's rules, through ``SSHConfig.lookup``)."""

    host: HostConfig
    path: str
    cfg: paramiko.SSHConfig

    def check_named(self, alias: str) -> None:
        """The host's alias must be a ``Host`` of the file (a pattern other than ``*``)
        or get a ``HostName`` there: a typo is then one line naming the file, not a
        failed DNS lookup of the typo."""
        patterns = [p for p in self.cfg.get_hostnames() if p != "*" and not p.startswith("!")]
        if any(fnmatch.fnmatch(alias, p) for p in patterns):
            return
        if self._lookup(alias, f"host {self.host.name}")["hostname"] != alias:
            return  # a Match block names it
        raise SshConfigError(f"host {self.host.name}: ssh_alias {alias!r} is not a Host of "
                             f"{self.path}; fix the alias or add a Host block for it")

    def _lookup(self, alias: str, who: str) -> paramiko.SSHConfigDict:
        try:
            opts = self.cfg.lookup(alias)
        except Exception as exc:  # a Match paramiko cannot evaluate, a bad token
            raise SshConfigError(one_line(f"{who}: ssh config {self.path}, Host {alias}: "
                                          f"{exc}")) from None
        if opts.get("proxycommand"):
            raise SshConfigError(f"{who}: ProxyCommand in {self.path} (for {alias}) is "
                                 "refused: it runs a local command; use ProxyJump")
        return opts

    def hop(self, alias: str, role: str, *, target: bool, user: str | None = None,
            port: int | None = None) -> tuple[Hop, str | None]:
        """The hop ``alias`` and its ProxyJump value (``user``/``port``: a jump spec's)."""
        h = self.host
        opts = self._lookup(alias, role)
        try:
            port = port or int(opts.get("port") or (h.port if target else 22))
        except ValueError:
            port = 0
        if not 0 < port < 65536:
            raise SshConfigError(f"{role}: Port {opts.get('port')!r} of {alias} in "
                                 f"{self.path} is not a port number") from None
        user = user or opts.get("user") or (h.user if target else None) or getpass.getuser()
        named = [k for k in opts.get("identityfile") or [] if k.lower() != "none"]
        keys = tuple(named) or ((h.key_file,) if h.key_file else ())
        if "userknownhostsfile" in opts:
            known = tuple(os.path.expanduser(f) for f in opts["userknownhostsfile"].split()
                          if f.lower() != "none")
        else:
            known = (h.known_hosts or os.path.expanduser(DEFAULT_KNOWN_HOSTS),)
        return Hop(role, alias, opts["hostname"], port, user, keys, known,
                   bastion=not target), opts.get("proxyjump")

    def route(self, alias: str, role: str, *, target: bool, user: str | None = None,
              port: int | None = None, depth: int = 0) -> list[Hop]:
        if depth >= MAX_HOPS:
            raise SshConfigError(f"host {self.host.name}: ProxyJump in {self.path} goes "
                                 f"more than {MAX_HOPS} hops deep at {alias} (a loop?)")
        hop, jump = self.hop(alias, role, target=target, user=user, port=port)
        if not jump or jump.strip().lower() == "none":
            return [hop]
        try:
            specs = [parse_jump(s) for s in jump.split(",")]
        except ValueError as exc:
            raise SshConfigError(f"{role}: ProxyJump of {alias} in {self.path}: "
                                 f"{exc}") from None
        bastion = f"host {self.host.name}: bastion"
        (u, name, p), rest = specs[0], specs[1:]
        chain = self.route(name, f"{bastion} {name}", target=False, user=u, port=p,
                           depth=depth + 1)
        for u, name, p in rest:  # reached through the previous jump: its ProxyJump unused
            chain.append(self.hop(name, f"{bastion} {name}", target=False, user=u,
                                  port=p)[0])
        if len(chain) >= MAX_HOPS:
            raise SshConfigError(f"host {self.host.name}: ProxyJump in {self.path} makes a "
                                 f"route of more than {MAX_HOPS} hops to {alias}")
        return [*chain, hop]


# -- keys --------------------------------------------------------------------------------
Prompt = Callable[[str], "str | None"]
"""Asks for a passphrase: the message in, the answer out (None or "": no answer)."""


def terminal_prompt(message: str) -> str | None:
    """``getpass`` on the terminal; None when there is none (a service, CI): the key
    then cannot be used, and the error says to ``ssh-add`` it."""
    if sys.stdin is None or not sys.stdin.isatty():
        return None
    try:
        return getpass.getpass(message)
    except (EOFError, OSError):
        return None


class KeyRing:
    """The private keys this process has opened, each passphrase asked at most once.

    Why a process-wide ring: a host's reconnects (and its sibling hosts with the same
    key) make new transports, and a lab operator must not be asked again each time. Kept:
    the decrypted key object (or why it could not be opened), in memory only; the
    passphrase itself is dropped once the key is decrypted and is never logged. A key
    file replaced on disk (new mtime) is opened again."""

    def __init__(self, prompt: Prompt = terminal_prompt) -> None:
        self.prompt = prompt
        self._lock = threading.Lock()  # one prompt at a time; one opening per key
        self._keys: dict[tuple[str, int], paramiko.PKey | str] = {}

    def forget(self) -> None:
        """Drop every key (tests; a rerun of a preflight that should ask again)."""
        with self._lock:
            self._keys.clear()

    def load(self, path: str, who: str) -> paramiko.PKey:
        real = os.path.realpath(os.path.expanduser(path))
        try:
            stamp = os.stat(real).st_mtime_ns
        except OSError as exc:
            raise KeyUnavailable(f"key {path}: {exc.strerror}") from None
        with self._lock:
            got = self._keys.get((real, stamp))
            if got is None:
                got = self._keys[(real, stamp)] = self._open(path, real, who)
        if isinstance(got, str):
            raise KeyUnavailable(got)
        return got

    def _open(self, path: str, real: str, who: str) -> paramiko.PKey | str:
        try:
            return paramiko.PKey.from_path(real)
        except (TypeError, paramiko.PasswordRequiredException):
            pass  # encrypted: paramiko/cryptography say so with a TypeError
        except (OSError, ValueError, paramiko.SSHException) as exc:
            return one_line(f"key {path} cannot be read: {exc}")
        message = f"Passphrase for key {path} (to reach {who}): "
        for _ in range(PASSPHRASE_TRIES):
            answer = self.prompt(message)
            if not answer:
                return (f"key {path} is passphrase-protected and no passphrase was given "
                        f"(no terminal to ask, or no answer): ssh-add {path}, or start "
                        "from a terminal")
            try:
                return paramiko.PKey.from_path(real, password=answer.encode())
            except (TypeError, ValueError, paramiko.SSHException):
                message = f"Wrong passphrase. Passphrase for key {path}: "
        return f"key {path}: wrong passphrase {PASSPHRASE_TRIES} times"


KEYRING = KeyRing()
"""The process's keys; tests set ``KEYRING.prompt`` to answer the passphrase question."""


class _FileKey(PrivateKey):
    """A named key file, opened (and decrypted) only when its turn comes."""

    def __init__(self, username: str, path: str, who: str, ring: KeyRing) -> None:
        super().__init__(username=username)
        self.path, self.who, self.ring = path, who, ring

    def authenticate(self, transport: paramiko.Transport) -> list[str]:
        self.pkey = self.ring.load(self.path, self.who)
        return list(super().authenticate(transport))

    def __repr__(self) -> str:
        return f"key {self.path}"


def _agent_copy(path: str, agent_keys: tuple[paramiko.AgentKey, ...]
                ) -> paramiko.AgentKey | None:
    """The agent's key that is ``path`` (by its ``.pub``), as OpenSSH prefers it: no
    passphrase to ask for a key the operator already unlocked with ``ssh-add``."""
    if not agent_keys:
        return None
    try:
        blob = paramiko.PublicBlob.from_file(os.path.expanduser(path) + ".pub").key_blob
    except (OSError, ValueError):
        return None
    return next((k for k in agent_keys if k.asbytes() == blob), None)


class HopKeys(AuthStrategy):
    """The keys one hop is offered, in order, and only those (no ~/.ssh search)."""

    def __init__(self, hop: Hop, agent_keys: tuple[paramiko.AgentKey, ...],
                 ring: KeyRing) -> None:
        super().__init__(ssh_config=None)
        self.hop, self.agent_keys, self.ring = hop, agent_keys, ring

    def get_sources(self) -> Iterator[AuthSource]:
        user = self.hop.user
        if not self.hop.identity_files:
            for key in self.agent_keys:
                yield InMemoryPrivateKey(user, key)
            return
        for path in self.hop.identity_files:
            held = _agent_copy(path, self.agent_keys)
            yield (InMemoryPrivateKey(user, held) if held is not None
                   else _FileKey(user, path, self.hop.role, self.ring))


def _source_name(source: AuthSource) -> str:
    pkey = getattr(source, "pkey", None)
    if isinstance(pkey, paramiko.AgentKey):
        return f"ssh-agent key {pkey.get_name()} {pkey.fingerprint}"
    return repr(source)


def _why_not(result: object) -> str:
    """One source's failure: ours (a key we could not open) says why in full."""
    if isinstance(result, KeyUnavailable):
        return str(result)
    if isinstance(result, paramiko.AuthenticationException):
        return "refused by the server"
    return one_line(f"{type(result).__name__}: {result}")


def _auth_failed(hop: Hop, exc: AuthFailure) -> TransportError:
    tried = "; ".join(f"{_source_name(r.source)}: {_why_not(r.result)}" for r in exc.result)
    return hop.error(f"{hop.role} ({hop.where}): key authentication as {hop.user!r} "
                     f"failed ({tried or 'no key to try'})")


def _agent_state() -> str:
    sock = os.environ.get("SSH_AUTH_SOCK")
    if not sock:
        return "SSH_AUTH_SOCK is not set (no ssh-agent)"
    if not Path(sock).exists():
        return f"no ssh-agent answers at SSH_AUTH_SOCK={sock}"
    return f"the ssh-agent at {sock} holds no keys (ssh-add one)"


def _open_agent() -> paramiko.Agent | None:
    if not os.environ.get("SSH_AUTH_SOCK"):
        return None
    try:
        return paramiko.Agent()
    except paramiko.SSHException:
        return None


# -- host keys ---------------------------------------------------------------------------
def fingerprint(key: paramiko.PKey) -> str:
    digest = hashlib.sha256(key.asbytes()).digest()
    return "SHA256:" + base64.b64encode(digest).decode().rstrip("=")


def _files(paths: tuple[str, ...]) -> str:
    if not paths:
        return "any known_hosts file (UserKnownHostsFile none)"
    if len(paths) == 1:
        return f"the known_hosts file {paths[0]}"
    return "the known_hosts files " + ", ".join(paths)


class RefuseUnknownHostKey(paramiko.RejectPolicy):
    """A ``RejectPolicy`` whose refusal names the hop, the key and the known_hosts files."""

    def __init__(self, hop: Hop) -> None:
        self.hop = hop

    def missing_host_key(self, client: paramiko.SSHClient, hostname: str,
                         key: paramiko.PKey) -> None:
        hop = self.hop
        target = hop.known_hosts[0] if hop.known_hosts else "~/.ssh/known_hosts"
        raise HostKeyError(
            f"{hop.role}: the SSH server at {hostname} offered an unknown "
            f"{key.get_name()} host key ({fingerprint(key)}) that is not in "
            f"{_files(hop.known_hosts)}; refusing to connect (unknown host keys are "
            f"refused). Verify the fingerprint on the host, then add it, e.g. "
            f"ssh-keyscan -p {hop.port} ADDRESS >> {target}")


def _client_for(hop: Hop) -> paramiko.SSHClient:
    """An SSHClient that knows the hop's known_hosts files only (hashed entries too)."""
    client = paramiko.SSHClient()
    for path in hop.known_hosts:
        try:
            client.load_host_keys(path)
        except FileNotFoundError:
            continue  # as ssh: every key is then unknown, and the refusal names the file
        except (OSError, paramiko.SSHException) as exc:
            raise HostKeyError(one_line(f"{hop.role}: cannot read known_hosts file "
                                        f"{path}: {exc}")) from None
    client.set_missing_host_key_policy(RefuseUnknownHostKey(hop))
    return client


# -- connecting --------------------------------------------------------------------------
@dataclass
class Connection:
    """The SSH connection to the host and the bastions' under it (nearest first)."""

    client: paramiko.SSHClient
    bastions: list[paramiko.SSHClient]
    route: Route

    @property
    def transport(self) -> paramiko.Transport:
        t = self.client.get_transport()
        assert t is not None
        return t

    def close(self) -> None:
        """The host's connection first, then each bastion's; never raises."""
        for c in (self.client, *reversed(self.bastions)):
            with contextlib.suppress(Exception):
                c.close()


def _left(deadline: float) -> float:
    return max(deadline - time.monotonic(), 0.1)


def _tcp(hop: Hop, deadline: float) -> socket.socket:
    try:
        sock = socket.create_connection((hop.hostname, hop.port), timeout=_left(deadline))
    except OSError as exc:
        if hop.bastion:
            raise hop.error(f"{hop.role} ({hop.where}) unreachable: {exc}") from None
        raise hop.error(f"{hop.role}: cannot reach {hop.where}: {exc}") from None
    # Nagle + delayed ACK stall small frames by ~40 ms (docs/notes/drivers.md, "SSH").
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return sock


def _tunnel(via: paramiko.SSHClient, bastion: Hop, hop: Hop, deadline: float
            ) -> paramiko.Channel:
    """A ``direct-tcpip`` channel of the bastion's connection to the next hop's port."""
    transport = via.get_transport()
    try:
        assert transport is not None
        return transport.open_channel("direct-tcpip", (hop.hostname, hop.port),
                                      ("127.0.0.1", 0), timeout=_left(deadline))
    except paramiko.ChannelException as exc:
        why = f"{exc.text} (code {exc.code})"
    except (AssertionError, paramiko.SSHException, OSError, EOFError) as exc:
        why = f"{type(exc).__name__}: {exc}"
    raise BastionError(one_line(f"{bastion.role} ({bastion.where}) could not open a tunnel "
                                f"to {hop.where} for {hop.name}: {why}"))


def _login(hop: Hop, sock: Any, agent_keys: tuple[paramiko.AgentKey, ...], ring: KeyRing,
           deadline: float) -> paramiko.SSHClient:
    """SSH over ``sock`` to ``hop``: host key checked, then its keys tried in order."""
    try:
        client = _client_for(hop)
    except HostKeyError:
        sock.close()
        raise
    left = _left(deadline)
    done = False
    try:
        client.connect(hostname=hop.hostname, port=hop.port, username=hop.user, sock=sock,
                       timeout=left, banner_timeout=left, auth_timeout=left,
                       channel_timeout=left, allow_agent=False, look_for_keys=False,
                       auth_strategy=HopKeys(hop, agent_keys, ring))
        done = True
        return client
    except HostKeyError:
        raise
    except paramiko.BadHostKeyException as exc:
        raise HostKeyError(
            f"{hop.role} ({hop.where}): the server's host key does NOT match the entry in "
            f"{', '.join(hop.known_hosts)} (got {exc.key.get_name()} "
            f"{fingerprint(exc.key)}); refusing to connect. If the host was reinstalled, "
            "verify and replace its entry.") from None
    except AuthFailure as exc:
        raise _auth_failed(hop, exc) from None
    except (paramiko.SSHException, OSError, EOFError) as exc:
        raise hop.error(f"{hop.role} ({hop.where}): SSH failed: {type(exc).__name__}: "
                        f"{exc}") from None
    finally:
        if not done:  # the transport (and the socket or channel under it) closes too
            client.close()
            with contextlib.suppress(Exception):
                sock.close()


def _check_keys(route: Route, agent_keys: tuple[paramiko.AgentKey, ...]) -> None:
    """Every hop has a key to try, before anything is sent (a clear line, not an
    AuthFailure from the server)."""
    for hop in route.hops:
        if not hop.identity_files and not agent_keys:
            raise hop.error(f"{hop.role}: no key to log in to {hop.where} as {hop.user!r}: "
                            f"no key_file or IdentityFile names one, and {_agent_state()}")


def connect(route: Route, timeout_s: float, ring: KeyRing | None = None) -> Connection:
    """Log in along ``route`` within ``timeout_s``: the first hop over TCP, each next one
    through a ``direct-tcpip`` channel of the one before. Raises a one-line
    TransportError (BastionError for a bastion), HostKeyError or KeyUnavailable."""
    ring = KEYRING if ring is None else ring
    deadline = time.monotonic() + timeout_s
    agent = _open_agent()
    agent_keys: tuple[paramiko.AgentKey, ...] = tuple(agent.get_keys()) if agent else ()
    opened: list[paramiko.SSHClient] = []
    try:
        _check_keys(route, agent_keys)
        sock: Any = _tcp(route.hops[0], deadline)
        for i, hop in enumerate(route.hops):
            if i:
                sock = _tunnel(opened[-1], route.hops[i - 1], hop, deadline)
            opened.append(_login(hop, sock, agent_keys, ring, deadline))
    except BaseException:
        for c in reversed(opened):
            with contextlib.suppress(Exception):
                c.close()
        raise
    finally:
        if agent is not None:
            with contextlib.suppress(Exception):
                agent.close()  # agent keys sign during auth only
    return Connection(opened[-1], opened[:-1], route)
