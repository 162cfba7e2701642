"""``testbed deploy`` against a host behind a real sshd on loopback, and the hello check.

The host is a hardware twin's YuMi host (``sim_twin.yumi_server`` behind an OpenSSH
sshd) whose ``python`` is a robot host's install (``conftest.host_venv``) and which has
no ``workdir``: what a lab's deployed host is. It first runs another build (an older
wheel installed there): the controller refuses it at hello, before any arm moves, with
the one line that says to deploy; ``testbed deploy`` (the real CLI, real SFTP, real pip
on the host) installs this checkout's build, and the same host is then accepted.
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterator
from pathlib import Path

import pytest
from host_install import HostVenv, install_build, installed, write_fleet
from lab_fixtures import calibrate_exactly, tiny_protocol

from drivers.build_id import build_id
from drivers.testing.sshd import sshd_available
from testbed.cli import main
from testbed.experiments.fleet_config import FleetConfig, load_fleet
from testbed.experiments.protocol import load_protocol
from testbed.lab.hardware_twin import HardwareTwinLab

pytestmark = [pytest.mark.slow, pytest.mark.ssh, pytest.mark.timeout(900),  # setup.sh
              pytest.mark.skipif(not sshd_available(), reason="needs OpenSSH sshd")]
OLD_BUILD = "0.1.0+g0000000"


@pytest.fixture(scope="module")
def lab(tmp_path_factory: pytest.TempPathFactory) -> Iterator[HardwareTwinLab]:
    root = tmp_path_factory.mktemp("deploy-lab")
    proto = load_protocol(tiny_protocol(root), check_files=False)
    fleet = proto.fleet.model_copy(update={"hosts": proto.fleet.hosts[:1]})
    twin_lab = HardwareTwinLab(fleet, root / "lab", seed=7)
    with twin_lab:
        calibrate_exactly(twin_lab)
        yield twin_lab


def deployed_fleet(lab: HardwareTwinLab, venv: HostVenv, path: Path, **host: object
                   ) -> tuple[Path, FleetConfig]:
    """The lab's fleet as a lab writes it for a deployed host (the host venv's python,
    no workdir), in a config file, read back as the CLI reads it."""
    fleet = lab.rewrite()
    hosts = [h.model_copy(update={"python": str(venv.python), "workdir": None, **host})
             for h in fleet.hosts]
    config = write_fleet(fleet.model_copy(update={"hosts": hosts}), path)
    return config, load_fleet(config)


def motions(lab: HardwareTwinLab) -> int:
    """RAPID program starts the twin's controller has served (each is a motion)."""
    log = lab.hosts["yumi-a"].rws_log
    rows = [json.loads(x) for x in log.read_text().splitlines()] if log.exists() else []
    return sum(1 for r in rows if r["method"] == "POST" and "rw/rapid/execution" in r["path"]
               and "action=start" in r["path"])


def test_another_build_is_refused_before_any_arm_moves_and_deploy_brings_the_host_in(
        host_venv: HostVenv, lab: HardwareTwinLab, tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    from drivers.host_fleet import HostFleet
    from testbed.core.types import ArmObservation, Fault

    install_build(host_venv, OLD_BUILD, tmp_path)  # the host still runs an older build
    config, fleet = deployed_fleet(lab, host_venv, tmp_path / "lab.toml")
    ours = build_id()
    refusal = (f"host yumi-a runs build {OLD_BUILD}, this controller is build {ours}: run "
               "testbed deploy --config <this fleet's config> --host yumi-a")
    tcp, started = lab.hosts["yumi-a"].lab.tcp(), motions(lab)
    with HostFleet(fleet.hosts, reconnect_backoff_s=30.0) as hosts:
        status = hosts.host_status()["yumi-a"]
        assert not status.connected and status.error == refusal
        obs = hosts.observe()
        assert all(isinstance(o, Fault) and refusal in o.reason for o in obs.values()), obs
        pushed = hosts.execute({"yumi-a/left": 1, "yumi-a/right": 3}, [])
        assert all(isinstance(r, Fault) for r in pushed.values())
    assert motions(lab) == started and lab.hosts["yumi-a"].lab.tcp() == tcp  # nothing moved

    assert main(["deploy", "--config", str(config), "--host", "yumi-a"]) == 0
    out = capsys.readouterr().out
    with capsys.disabled():
        print("\n" + out, end="")  # the deploy's own lines: its timings, for the notes
    assert re.search(rf"^built fleet_testbed-{re.escape(ours)}-py3-none-any\.whl \(\d+ KB\)",
                     out, re.M), out
    line = next(x for x in out.splitlines() if x.startswith("ok    yumi-a: "))
    assert f"build {ours} in {host_venv.site_packages} (Python 3." in line
    assert re.search(r"copy [\d.]+ s, install [\d.]+ s, dependencies [\d.]+ s, verify", line)
    assert installed(host_venv, tmp_path)["fleet-testbed"] == ours
    with HostFleet(fleet.hosts) as hosts:
        assert hosts.host_status()["yumi-a"].connected, hosts.host_status()
        assert all(isinstance(o, ArmObservation) for o in hosts.observe().values())


def test_a_host_deploy_cannot_reach_is_a_fault_line_naming_the_step(
        host_venv: HostVenv, lab: HardwareTwinLab, tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    config, _ = deployed_fleet(lab, host_venv, tmp_path / "lab.toml",
                               python="/nonexistent/venv/bin/python")
    assert main(["deploy", "--config", str(config)]) == 1
    fault = [x for x in capsys.readouterr().out.splitlines() if x.startswith("FAULT")]
    assert len(fault) == 1 and fault[0].startswith("FAULT yumi-a: probing its python failed "
                                                   "(exit status 127): ")
    assert "/nonexistent/venv/bin/python" in fault[0]


def one_line(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    """The CLI's refusal: status 2, one stderr line, no traceback."""
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    return err.strip()


def test_deploy_refuses_what_it_cannot_deploy_in_one_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    for name in ("key", "known_hosts"):
        (tmp_path / name).write_text("x\n")
    ssh = (f'transport = "ssh"\nuser = "lab"\nkey_file = "{tmp_path}/key"\n'
           f'known_hosts = "{tmp_path}/known_hosts"\npython = "/opt/fleet/bin/python"\n')
    config = tmp_path / "fleet.toml"
    config.write_text(f'[[hosts]]\nname = "cell0"\n\n[[hosts]]\nname = "far"\n{ssh}'
                      f'workdir = "/opt/fleet"\n')
    line = one_line(["deploy", "--config", str(config), "--host", "nope"], capsys)
    assert "--host: no host 'nope' in the fleet; its hosts: cell0, far" in line
    line = one_line(["deploy", "--config", str(config), "--host", "cell0"], capsys)
    assert "cell0 is a local host: it runs this checkout itself" in line
    line = one_line(["deploy", "--config", str(config)], capsys)
    assert "hosts[1].workdir: host far runs its checkout /opt/fleet" in line
    assert "remove workdir" in line
    config.write_text('[[hosts]]\nname = "cell0"\n')
    line = one_line(["deploy", "--config", str(config)], capsys)
    assert "no host of this fleet is reached over ssh" in line
