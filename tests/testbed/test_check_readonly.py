"""``testbed check`` never moves an arm (issue 43), on two YuMi hardware twins behind
real sshds, through the CLI: the twins' request logs (every RWS request they served)
hold no write during a check (no program file, no start, no reset), their pushers are
where they were, and an arm a person left in the camera's view is a FAULT naming the
fix instead of the motion to rest the picture step would have made.

The mutations this catches: a check that observes a YuMi (its picture step sends the
arm to rest), a ``describe`` that takes its picture that way, a check that rests the
arms, and an agent that rests them at bye after a session that only looked (each shows
as PUTs of program files and a start in the log, and a pusher that moved).
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from lab_fixtures import calibrate_exactly, tiny_protocol

from drivers.testing.sshd import sshd_available
from testbed.cli import main
from testbed.experiments.protocol import load_protocol
from testbed.lab.hardware_twin import HardwareTwinLab
from testbed.lab.preflight import mosaic_size
from testbed.records.run_dir import RunDir

pytestmark = [
    pytest.mark.slow,
    pytest.mark.ssh,
    pytest.mark.skipif(not sshd_available(), reason="needs OpenSSH sshd (openssh-server)"),
]

IN_VIEW_MM = (310.0, 220.0, 100.0)
"""Over the left arm's table box at clear height: in the camera's view."""


@pytest.fixture(scope="module")
def lab(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[HardwareTwinLab, Path]]:
    root = tmp_path_factory.mktemp("readonly")
    proto = load_protocol(tiny_protocol(root), check_files=False)
    twin_lab = HardwareTwinLab(proto.fleet, root / "lab", seed=7)
    with twin_lab:
        calibrate_exactly(twin_lab)
        fleet_dir = RunDir(root / "fleet")
        fleet_dir.path.mkdir()
        fleet_dir.write_config(twin_lab.rewrite())
        yield twin_lab, fleet_dir.path / "config.toml"


def log_sizes(lab: HardwareTwinLab) -> dict[str, int]:
    return {n: h.rws_log.stat().st_size for n, h in lab.hosts.items() if h.rws_log}


def writes_since(lab: HardwareTwinLab, sizes: dict[str, int]) -> dict[str, list[str]]:
    """Every RWS request but a read (GET) each twin served since ``sizes``; and how many
    requests in all, so an empty list is known to come from a log that was written."""
    out: dict[str, list[str]] = {}
    for name, size in sizes.items():
        log = lab.hosts[name].rws_log
        assert log is not None
        rows = [json.loads(line) for line in log.read_bytes()[size:].decode().splitlines()]
        assert len(rows) > 10, f"{name}: the check asked its controller nothing?"
        out[name] = [f"{r['method']} {r['path']}" for r in rows if r["method"] != "GET"]
    return out


def pushers(lab: HardwareTwinLab) -> dict[str, dict[str, list[float]]]:
    return {n: h.lab.tcp() for n, h in lab.hosts.items()}


def check(config: Path, mosaic: Path, capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    rc = main(["check", "--config", str(config), "--mosaic", str(mosaic)])
    return rc, capsys.readouterr().out


def test_check_reads_every_controller_and_camera_and_never_moves_an_arm(
        lab: tuple[HardwareTwinLab, Path], tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    import cv2

    twin_lab, config = lab
    robots = [f"{h}/{a}" for h in ("yumi-a", "yumi-b") for a in ("left", "right")]
    # A ready cell: every arm's line, the controllers' reports, the mosaic, no write.
    sizes, before = log_sizes(twin_lab), pushers(twin_lab)
    rc, out = check(config, tmp_path / "m.png", capsys)
    assert rc == 0, out
    assert "FAULT" not in out
    for robot in robots:
        assert f"ok    {robot}: frame (64, 64, 3), ready" in out
    for host in ("yumi-a", "yumi-b"):  # each controller's report, as a trial's check reads it
        assert f"{host}: controller YUMI_TWIN serial 14000-" in out
    picture = cv2.imread(str(tmp_path / "m.png"))
    assert picture is not None and picture.shape[:2] == mosaic_size(len(robots))
    assert float(np.asarray(picture).std()) > 5  # the crops, not an empty canvas
    assert (tmp_path / "check-yumi-a.png").exists() and (tmp_path / "check-yumi-b.png").exists()
    assert writes_since(twin_lab, sizes) == {"yumi-a": [], "yumi-b": []}
    assert pushers(twin_lab) == before

    # A person left yumi-a's left arm over the table: one FAULT with the fix, and the
    # arm stays there (the picture step would have sent it to rest, in Auto).
    hand = twin_lab.hosts["yumi-a"].lab
    home = hand.tcp()["left"]
    parked = hand.jog("left", IN_VIEW_MM)
    try:
        sizes, before = log_sizes(twin_lab), pushers(twin_lab)
        rc, out = check(config, tmp_path / "m2.png", capsys)
        assert rc == 1, out
        faults = [line for line in out.splitlines() if line.startswith("FAULT")]
        x, y, z = parked
        assert faults == [f"FAULT yumi-a: arm left is in the camera's view at ({x:.0f}, "
                          f"{y:.0f}, {z:.0f}) mm: jog it to rest on the FlexPendant, then "
                          f"check again"], out
        assert writes_since(twin_lab, sizes) == {"yumi-a": [], "yumi-b": []}
        assert pushers(twin_lab) == before
        assert np.allclose(before["yumi-a"]["left"], IN_VIEW_MM, atol=1.0)
        assert (tmp_path / "m2.png").exists()  # the mosaic still shows what the camera saw
    finally:
        hand.jog("left", home)  # back where it rests, for the module's other users
