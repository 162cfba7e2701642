"""A robot host's install (``scripts/setup.sh --host``) is a host install: the agent's side
and none of the operator's, and an agent run from it serves a YuMi host.

One real venv per session (``conftest.host_venv``): what pip put there, what its
interpreter imports from outside any checkout, and a rehearsal-like host (a hardware
twin behind a real sshd on loopback) whose agent is that venv's interpreter with no
``workdir``: the installed package, not this checkout on PYTHONPATH.
"""

from __future__ import annotations

import os
import select
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from host_install import OPERATOR_ONLY, HostVenv, clean_env, host_python, install_build, installed
from lab_fixtures import calibrate_exactly, tiny_protocol

from drivers import wire as p
from drivers.build_id import build_id
from drivers.testing.sshd import sshd_available
from testbed.core.host_config import HostConfig
from testbed.experiments.protocol import load_protocol
from testbed.lab.hardware_twin import HardwareTwinLab

# the first test to ask for host_venv runs scripts/setup.sh --host (a minute here, more
# on a cold pip cache): more than the default 300 s limit allows for
pytestmark = [pytest.mark.slow, pytest.mark.timeout(900)]
ONE_LINE = ("{what} needs the operator install: pip install 'fleet-testbed[operator]' "
            "(this is a host install: {missing} is not installed)")


def test_the_host_install_has_the_agents_side_and_nothing_of_the_operators(
        host_venv: HostVenv, tmp_path: Path) -> None:
    got = installed(host_venv, tmp_path)
    assert not set(OPERATOR_ONLY) & set(got), sorted(got)
    assert "opencv-python-headless" in got and "opencv-python" not in got
    assert {"abb-robot-client", "abb-motion-program-exec", "pydantic", "numpy"} <= set(got)
    assert got["fleet-testbed"].startswith("0.1.0+")  # stamped by setup.sh: a build id
    # Its interpreter imports the agent's side from the venv itself, not this checkout.
    proc = host_python(host_venv, "import drivers.agent, drivers.yumi.backend, "
                       "drivers.yumi.rws_controller, testbed.core.config, "
                       "testbed.perception.cube, cv2\nprint(drivers.__file__)", tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert Path(proc.stdout.strip()).is_relative_to(host_venv.site_packages)
    print(f"host install: scripts/setup.sh --host took {host_venv.setup_s:.1f} s, "
          f"{_size_mb(host_venv.path):.0f} MB, {len(got)} packages")


def _size_mb(path: Path) -> float:
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file() and not
               f.is_symlink()) / 2**20


def test_the_operators_rooms_fail_on_a_host_install_in_one_line(
        host_venv: HostVenv, tmp_path: Path) -> None:
    # The learning room's config loads without torch (the CLI validates configs on a
    # host); its learner is what needs the operator install.
    for module, missing, code in (
            ("testbed.learning", "torch", "from testbed.learning import Learner"),
            ("sim_twin", "pybullet", "import sim_twin")):
        proc = host_python(host_venv, code, tmp_path)
        assert proc.returncode == 1
        last = proc.stderr.strip().splitlines()[-1]
        if module == "sim_twin":  # sim_twin names the twin extra too (its own line)
            assert last == ("ImportError: sim_twin needs the operator install: pip install "
                            "'fleet-testbed[operator]' (or the twin extra; this is a host "
                            "install: pybullet is not installed)")
        else:
            assert last == "ImportError: " + ONE_LINE.format(what=module, missing=missing)
    # The testbed command is on a host too: a verb says what it lacks, once, exit 2.
    proc = subprocess.run([str(host_venv.path / "bin" / "testbed"), "trial", "--steps", "1"],
                          cwd=tmp_path, env=clean_env(), capture_output=True, text=True,
                          timeout=120, check=False)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1, proc.stderr[-2000:]
    assert lines[0].startswith("testbed trial: ") and "needs the operator install: pip " \
        "install 'fleet-testbed[operator]' (this is a host install: " in lines[0]
    assert not (tmp_path / "runs").exists()


def test_a_twin_agent_on_a_host_install_refuses_at_hello_in_one_line(
        host_venv: HostVenv, tmp_path: Path) -> None:
    """``--backend twin`` needs PyBullet, which a host install has not: the agent says so
    at hello (a startup error, fatal), as it reports any backend that cannot start."""
    proc = subprocess.Popen([str(host_venv.python), "-m", "drivers.agent", "--backend",
                             "twin", "--host", "h"], cwd=tmp_path, env=clean_env(),
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)
    try:
        assert proc.stdin is not None and proc.stdout is not None
        proc.stdin.write(p.make_request("hello", 1, version=p.PROTOCOL_VERSION, host="h"))
        proc.stdin.flush()
        fd = proc.stdout.fileno()

        def read(n: int, deadline: float) -> bytes:
            if not select.select([fd], [], [], max(deadline - time.monotonic(), 0))[0]:
                raise TimeoutError("the agent did not answer hello")
            return os.read(fd, n)

        reply = p.FrameReader(read, "agent").read_frame(time.monotonic() + 60)
        assert reply.type == "error" and reply.header["kind"] == "startup"
        assert reply.header["message"] == (
            "ImportError: sim_twin needs the operator install: pip install "
            "'fleet-testbed[operator]' (or the twin extra; this is a host install: "
            "pybullet is not installed)")
        assert proc.wait(30) == 5  # EXIT_STARTUP
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(5)


# -- an agent of the host install, serving a hardware twin over a real sshd ---------------
@pytest.fixture(scope="module")
def lab(tmp_path_factory: pytest.TempPathFactory) -> Iterator[HardwareTwinLab]:
    if not sshd_available():
        pytest.skip("needs OpenSSH sshd (openssh-server)")
    root = tmp_path_factory.mktemp("host-lab")
    proto = load_protocol(tiny_protocol(root), check_files=False)
    fleet = proto.fleet.model_copy(update={"hosts": proto.fleet.hosts[:1]})
    twin_lab = HardwareTwinLab(fleet, root / "lab", seed=5)
    with twin_lab:
        calibrate_exactly(twin_lab)
        yield twin_lab


def installed_host(lab: HardwareTwinLab, venv: HostVenv) -> HostConfig:
    """The rehearsal's host, but run as a deployed host is: the host venv's interpreter,
    no workdir (no --chdir, no PYTHONPATH)."""
    return lab.rewrite().hosts[0].model_copy(update={"python": str(venv.python),
                                                     "workdir": None})


@pytest.mark.ssh
def test_an_agent_of_the_host_install_serves_a_yumi_host(
        host_venv: HostVenv, lab: HardwareTwinLab, tmp_path: Path) -> None:
    from drivers.host_fleet import HostFleet
    from testbed.core.types import ArmObservation, PushResult

    install_build(host_venv, build_id(), tmp_path)  # this controller's build, installed
    host = installed_host(lab, host_venv)
    with HostFleet([host]) as fleet:
        status = fleet.host_status()[host.name]
        assert status.connected and status.backend == "yumi", status.error
        pid = status.agent_pid
        argv = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
        assert argv[0].decode() == str(host_venv.python) and b"--chdir" not in argv
        env = Path(f"/proc/{pid}/environ").read_bytes().split(b"\0")
        assert not any(e.startswith(b"PYTHONPATH=") for e in env)
        assert Path(os.readlink(f"/proc/{pid}/cwd")) != Path(__file__).resolve().parents[2]
        obs = fleet.observe()
        assert all(isinstance(o, ArmObservation) for o in obs.values()), obs
        robot = f"{host.name}/left"
        face = obs[robot].expert_action if isinstance(obs[robot], ArmObservation) else None
        result = fleet.execute({robot: 1 if face is None else face}, [])[robot]
        assert isinstance(result, PushResult) and result.action is not None, result
