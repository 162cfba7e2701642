"""``testbed deploy``: this checkout's build onto the robot hosts, installed and verified.

Why: a host's agent must run the controller's own build (``drivers.link`` refuses any
other at hello, before an arm moves), and a lab's robot PC has no checkout to keep in
step: it has an environment (``scripts/setup.sh --host``) whose ``python`` the config
names. Deploying is the one way code gets there, and it checks what it did::

    operator's checkout                     each ssh host of the fleet (or --host NAME)
    drivers.build_id.build_wheel            (its own SSH route: drivers.ssh_setup)
      stamped 0.1.0+g<sha7>[.d<hash8>] ─SFTP─► <tmp>/fleet_testbed-<build>-py3-none-any.whl
                                             python -m pip install --no-deps --force-reinstall WHEEL
                                             python -m pip install 'WHEEL[<host extras>]'
                                               (only what is missing: the package is there)
                                             python -c "import drivers, ...; print(build_id())"
                                               == the stamped build, or the host is a FAULT

Every remote command is an argv quoted word by word (``SshTransport.remote_command``),
run on one SSH connection per host, the way the agent's channel reaches it (known_hosts
only, key auth, bastions). A host with ``workdir`` runs its checkout, not an install, and
a local host runs this checkout: deploying to either is refused in one line (exit 2).
"""

from __future__ import annotations

import contextlib
import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final

from testbed.core.backend_registry import backend_lines, backend_of
from testbed.core.config import ConfigError
from testbed.core.host_config import HostConfig
from testbed.experiments.fleet_config import FleetConfig

if TYPE_CHECKING:
    from drivers.ssh_setup import Connection

__all__ = ["AGENT_IMPORTS", "HOST_EXTRA", "DeployError", "Deployed", "deploy", "deploy_host",
           "deploy_targets", "host_install", "plan"]

HOST_EXTRA: Final = "headless"
"""The extra every host installs besides the base (pyproject.toml); its backend's plugin
adds its own (``Backend.extra``, ``Backend.host_requirements``)."""
AGENT_IMPORTS: Final = ("drivers", "drivers.agent", "drivers.wire", "testbed.core.config",
                        "testbed.perception.cube")
"""What every agent imports; the verification adds its backend's ``verify_imports`` (its
own modules and clients), so a host that cannot run its agent fails here, not at the
trial's start."""


def host_install(host: HostConfig) -> tuple[str, tuple[str, ...], tuple[str, ...]]:
    """What ``host`` installs and verifies, from its backend's plugin: (the product's
    extras, other requirements, the modules its verification imports)."""
    plugin = backend_of(host)
    extras = HOST_EXTRA + (f",{plugin.extra}" if plugin.extra else "")
    return extras, plugin.host_requirements, (*AGENT_IMPORTS, *plugin.verify_imports)
HOST_PYTHONS: Final = ((3, 10), (3, 12))
PROBE: Final = ("import importlib.util, json, sys, tempfile; print(json.dumps({'version': "
                "list(sys.version_info[:3]), 'pip': importlib.util.find_spec('pip') is not "
                "None, 'tmp': tempfile.mkdtemp(prefix='fleet-deploy-')}))")
STEP_TIMEOUT_S: Final = 900.0
"""One remote step (pip may download a dependency the host lacks)."""


class DeployError(RuntimeError):
    """One host could not be deployed; ``str()`` is the one line to print."""


@dataclass(frozen=True)
class Deployed:
    """What a host runs now, as its own ``python`` reported it."""

    host: str
    build: str
    where: str
    """The folder the host's ``drivers`` package was imported from."""
    python: str
    seconds: dict[str, float] = field(default_factory=dict)


def deploy_targets(fleet: FleetConfig, name: str | None) -> list[HostConfig]:
    """The hosts to deploy: ``name`` alone, or every ssh host. ConfigError (one line)
    for a host that does not run an installed build: unknown, local, or a checkout."""
    if name is not None:
        hosts = [h for h in fleet.hosts if h.name == name]
        if not hosts:
            raise ConfigError(f"--host: no host {name!r} in the fleet; its hosts: "
                              f"{', '.join(h.name for h in fleet.hosts)}")
        if hosts[0].transport != "ssh":
            raise ConfigError(f"--host: {name} is a local host: it runs this checkout "
                              "itself, there is nothing to deploy")
    else:
        hosts = [h for h in fleet.hosts if h.transport == "ssh"]
        if not hosts:
            raise ConfigError("--config: no host of this fleet is reached over ssh: local "
                              "hosts run this checkout, there is nothing to deploy")
    chosen = {h.name for h in hosts}
    for i, h in enumerate(fleet.hosts):
        if h.name in chosen and h.workdir is not None:
            raise ConfigError(f"hosts[{i}].workdir: host {h.name} runs its checkout "
                              f"{h.workdir} (on PYTHONPATH), not an installed build; remove "
                              "workdir to run what testbed deploy installs")
    return hosts


def plan(fleet: FleetConfig, name: str | None, *, print_line: Callable[[str], None]) -> None:
    """``testbed deploy --dry-run``: the backends found and where from, then what each
    target host would install and verify; connects to nothing, builds nothing."""
    for line in backend_lines():
        print_line(line)
    for host in deploy_targets(fleet, name):
        extras, others, modules = host_install(host)
        print_line(f"plan  {host.name}: backend {host.backend}; pip install "
                   f"fleet-testbed[{extras}]{''.join(' ' + r for r in others)} with "
                   f"{host.python}; verify imports {', '.join(modules)}")


def deploy(fleet: FleetConfig, name: str | None, *, print_line: Callable[[str], None]
           ) -> bool:
    """Build this checkout's stamped wheel once, then deploy it to each target host in
    turn; one line per host (``ok`` or ``FAULT``). True if every host runs the build."""
    import tempfile

    from drivers.build_id import ROOT, BuildIdError, build_id, build_wheel, is_checkout

    hosts = deploy_targets(fleet, name)
    for line in backend_lines():
        print_line(line)
    build = build_id()  # this process's: the same id its own hello check compares
    if not is_checkout(ROOT) or "+g" not in build:
        raise ConfigError(f"testbed deploy builds from a git checkout of the project; "
                          f"{ROOT} is not one git can read (build {build})")
    with tempfile.TemporaryDirectory(prefix="fleet-deploy-") as tmp:
        t0 = time.monotonic()
        try:
            wheel = build_wheel(ROOT, Path(tmp), build)
        except BuildIdError as exc:
            print_line(f"FAULT build: {exc}")
            return False
        print_line(f"built {wheel.name} ({wheel.stat().st_size // 1024} KB) in "
                   f"{time.monotonic() - t0:.1f} s")
        ok = True
        for host in hosts:
            try:
                done = deploy_host(host, wheel, build)
            except DeployError as exc:
                ok = False
                print_line(f"FAULT {host.name}: {exc}")
                continue
            took = ", ".join(f"{k} {v:.1f} s" for k, v in done.seconds.items())
            print_line(f"ok    {host.name}: build {done.build} in {done.where} (Python "
                       f"{done.python}; {took})")
    return ok


def deploy_host(host: HostConfig, wheel: Path, build: str) -> Deployed:
    """Copy, install and verify ``wheel`` (stamped ``build``) on one ssh host, over one
    SSH connection; DeployError (one line) for anything that went wrong."""
    import paramiko

    from drivers import ssh_setup
    from drivers.errors import DriverError

    try:
        conn = ssh_setup.connect(ssh_setup.resolve_route(host), host.connect_timeout_s)
    except DriverError as exc:
        raise DeployError(ssh_setup.one_line(str(exc))) from None
    remote = _Remote(host, conn)
    try:
        return _install(remote, host, wheel, build)
    except DriverError as exc:
        raise DeployError(ssh_setup.one_line(str(exc))) from None
    except (paramiko.SSHException, OSError, EOFError) as exc:  # the connection broke
        raise DeployError(ssh_setup.one_line(f"SSH failed mid-deploy: {type(exc).__name__}: "
                                             f"{exc}")) from None
    finally:
        conn.close()


def _install(remote: _Remote, host: HostConfig, wheel: Path, build: str) -> Deployed:
    """The steps on the host (the module docstring's figure), each timed."""
    py = host.python
    seconds: dict[str, float] = {}
    probe = remote.json([py, "-c", PROBE], "probing its python")
    version = tuple(probe["version"])
    shown = ".".join(str(v) for v in version)
    if not HOST_PYTHONS[0] <= version[:2] <= HOST_PYTHONS[1]:
        raise DeployError(f"its python {py} is Python {shown}; a host needs 3.10-3.12 "
                          "(scripts/setup.sh --host)")
    if not probe["pip"]:
        raise DeployError(f"its python {py} has no pip; set the host up with "
                          "scripts/setup.sh --host")
    target = f"{probe['tmp']}/{wheel.name}"
    try:
        t = time.monotonic()
        remote.put(wheel, target)
        seconds["copy"] = time.monotonic() - t
        pip = [py, "-m", "pip", "install", "-q", "--disable-pip-version-check"]
        t = time.monotonic()
        remote.run([*pip, "--no-deps", "--force-reinstall", target], "installing the wheel")
        seconds["install"] = time.monotonic() - t
        t = time.monotonic()
        extras, others, modules = host_install(host)
        remote.run([*pip, f"{target}[{extras}]", *others],
                   f"installing the {', '.join((extras, *others))} dependencies")
        seconds["dependencies"] = time.monotonic() - t
    finally:
        remote.remove(target, probe["tmp"])
    t = time.monotonic()
    got = remote.json([py, "-c", _verify_code(modules)], "verifying the install")
    seconds["verify"] = time.monotonic() - t
    if got["build"] != build:
        raise DeployError(f"installed, but its python {py} runs build {got['build']} from "
                          f"{got['where']}, not {build} (another copy first on its path?)")
    return Deployed(host.name, build, str(got["where"]), shown, seconds)


def _verify_code(modules: Sequence[str]) -> str:
    """The host's ``python -c``: import what its agent imports, print the build."""
    return (f"import json, os, {', '.join(modules)}\n"
            "from drivers.build_id import build_id\n"
            "print(json.dumps({'build': build_id(), "
            "'where': os.path.dirname(os.path.dirname(drivers.__file__))}))")


class _Remote:
    """Commands and files on one host over its SSH connection (no shell strings: each
    argv is quoted word by word, as the agent's own command line is)."""

    def __init__(self, host: HostConfig, conn: Connection) -> None:
        self.host = host
        self.conn = conn

    def run(self, argv: Sequence[str], what: str, timeout_s: float = STEP_TIMEOUT_S) -> str:
        """Run ``argv`` to its end; its output (stdout and stderr together). DeployError
        naming ``what`` and the output's last lines if it fails or outlives the timeout."""
        from drivers.transport import SshTransport

        deadline = time.monotonic() + timeout_s
        chan = self.conn.transport.open_session(timeout=min(timeout_s, 30.0))
        try:
            chan.set_combine_stderr(True)
            chan.exec_command(SshTransport.remote_command(self.host, list(argv)))
            chunks: list[bytes] = []
            while True:
                chan.settimeout(max(deadline - time.monotonic(), 0.1))
                try:
                    data = chan.recv(65536)
                except TimeoutError:
                    raise DeployError(f"{what} did not finish within {timeout_s:g} s"
                                      ) from None
                if not data:
                    break
                chunks.append(data)
            status = chan.recv_exit_status()
        finally:
            chan.close()
        out = b"".join(chunks).decode("utf-8", "replace")
        if status != 0:
            tail = " | ".join(ln.strip() for ln in out.strip().splitlines()[-4:])
            raise DeployError(f"{what} failed (exit status {status}): {tail or 'no output'}")
        return out

    def json(self, argv: Sequence[str], what: str) -> dict[str, Any]:
        """``run``, its last output line read as a JSON object."""
        out = self.run(argv, what)
        lines = out.strip().splitlines()
        try:
            got = json.loads(lines[-1]) if lines else None
        except ValueError:
            got = None
        if not isinstance(got, dict):
            raise DeployError(f"{what}: unexpected output {out.strip()[-200:]!r}")
        return got

    def put(self, local: Path, remote: str) -> None:
        """SFTP on the same connection: the wheel, to the host's temporary folder."""
        import paramiko

        try:
            sftp = self.conn.client.open_sftp()
        except (paramiko.SSHException, EOFError) as exc:
            raise DeployError(f"the host's sshd serves no SFTP ({exc}); enable its sftp "
                              "Subsystem (Debian's sshd_config has it)") from None
        try:
            sftp.put(str(local), remote)
        except OSError as exc:
            raise DeployError(f"copying {local.name} to {remote} by SFTP: {exc}") from None
        finally:
            sftp.close()

    def remove(self, path: str, folder: str) -> None:
        """The wheel and its temporary folder, gone (best effort: never hides the
        error that brought us here)."""
        try:
            sftp = self.conn.client.open_sftp()
        except Exception:  # the connection is gone: nothing to clean with
            return
        try:
            with contextlib.suppress(OSError):
                sftp.remove(path)
            with contextlib.suppress(OSError):
                sftp.rmdir(folder)
        finally:
            sftp.close()
