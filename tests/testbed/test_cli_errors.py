"""Errors a user can cause, found before anything starts: exit 2, one line, no traceback.

Each case runs the real ``testbed.cli.main`` (argument parsing, config loading, the
checks in ``testbed.cli.checks``) and asserts that nothing was started: no run folder,
no output file. What the bad input would otherwise have done is said per test.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from testbed.cli import main

ROOT = Path(__file__).resolve().parents[2]
PHYSICAL = ROOT / "protocols" / "physical.toml"
TWIN_PROTOCOL = ROOT / "protocols" / "twin.toml"
HOST = '[[hosts]]\nname = "cell0"\n'
YUMI = (
    '[[hosts]]\nname = "yumi0"\nbackend = "yumi"\ncamera = "0"\n'
    'controller_url = "{url}"\n'
    'arms = [{{name = "left", crop = [0, 0, 300, 300], calibration = "/c/l.json"}}]\n'
)


def one_line(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    """Run the CLI; assert status 2 and exactly one stderr line; return that line."""
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's own errors
        code = int(exc.code or 0)
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert code == 2, err
    assert len(lines) == 1, err
    assert "Traceback" not in err
    return lines[0]


def write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


# ---- the wrong kind of file, and a protocol's fleet -------------------------------------
def test_protocol_verb_names_a_fleet_file(tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    fleet = write(tmp_path / "fleet.toml", HOST)
    line = one_line(["protocol", str(fleet), "--out", str(tmp_path / "runs")], capsys)
    assert f"{fleet} is a fleet config, not a protocol" in line
    assert not (tmp_path / "runs").exists()


def test_check_with_the_physical_protocol_names_key_file(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    # Before: "humans: Input should be a valid dictionary ... (+8 more)" (the protocol was
    # read as a fleet). Now its [fleet] is used, and this machine has no lab key.
    monkeypatch.setenv("HOME", str(tmp_path))  # no ~/.ssh/fleet_ed25519 here
    mosaic = tmp_path / "check.png"
    line = one_line(["check", "--config", str(PHYSICAL), "--mosaic", str(mosaic)], capsys)
    assert "fleet.hosts[0].key_file: no such file" in line and "fleet_ed25519" in line
    assert "humans" not in line and "valid dictionary" not in line
    assert not mosaic.exists()


def test_check_with_the_physical_protocol_gets_past_the_config(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / ".ssh").mkdir()
    for name in ("fleet_ed25519", "known_hosts"):
        (tmp_path / ".ssh" / name).write_text("x\n")
    monkeypatch.setenv("HOME", str(tmp_path))
    # The config is accepted: the next check (the mosaic's folder) is what stops it, so
    # the test needs no lab hosts.
    line = one_line(["check", "--config", str(PHYSICAL), "--mosaic",
                     str(tmp_path / "nowhere" / "check.png")], capsys)
    assert "--mosaic: no such folder" in line


def test_protocol_with_a_bad_fleet_names_the_field(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    proto = write(tmp_path / "p.toml", 'name = "p"\ntrials = 1\nalgorithms = ["bc"]\n'
                  '[fleet]\n[[fleet.hosts]]\nname = "h"\nbackend = "yumi"\n'
                  'camera = "0"\ncontroller_url = "ftp://x"\n')
    line = one_line(["protocol", str(proto), "--out", str(tmp_path / "runs")], capsys)
    assert "fleet.hosts[0].controller_url" in line
    assert not (tmp_path / "runs").exists()


# ---- the learner's device ---------------------------------------------------------------
def _no_cuda() -> None:
    import torch

    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA: learning.device = 'cuda' is fine here")


@pytest.mark.parametrize("verb", ["trial", "evaluate", "pretrain", "protocol"])
def test_cuda_without_cuda(verb: str, tmp_path: Path,
                           capsys: pytest.CaptureFixture[str]) -> None:
    _no_cuda()
    cfg = write(tmp_path / "fleet.toml", '[learning]\ndevice = "cuda"\n')
    out = tmp_path / "out"
    argv = {
        "trial": ["trial", "--config", str(cfg), "--out", str(out)],
        "evaluate": ["evaluate", "--config", str(cfg), "--out", str(out),
                     "--policy", str(cfg)],  # the device is checked before the policy
        "pretrain": ["pretrain", "--config", str(cfg), "--demos", str(cfg),
                     "--out", str(tmp_path / "learner.pt")],
        "protocol": ["protocol", str(write(tmp_path / "p.toml", 'name = "p"\ntrials = 1\n'
                                           '[fleet.learning]\ndevice = "cuda"\n')),
                     "--out", str(out)],
    }[verb]
    line = one_line(argv, capsys)
    assert "learning.device" in line and "cuda" in line and "no CUDA device" in line
    assert not out.exists() and not (tmp_path / "learner.pt").exists()


# ---- the operator console ---------------------------------------------------------------
@pytest.mark.parametrize("how", ["flag", "config", "collect", "protocol"])
def test_gui_humans_without_a_display(how: str, tmp_path: Path,
                                      capsys: pytest.CaptureFixture[str],
                                      monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("DISPLAY", raising=False)
    out = tmp_path / "out"
    gui_cfg = write(tmp_path / "gui.toml", '[humans]\nkind = "gui"\n')
    argv = {
        "flag": ["trial", "--humans", "gui", "--out", str(out)],
        "config": ["trial", "--config", str(gui_cfg), "--out", str(out)],
        "collect": ["collect", "--humans", "gui", "--out", str(tmp_path / "demos.npz")],
        "protocol": ["protocol", str(write(tmp_path / "p.toml", 'name = "p"\ntrials = 1\n'
                                           'humans = "gui"\n')), "--out", str(out)],
    }[how]
    line = one_line(argv, capsys)
    assert "gui" in line and "DISPLAY is not set" in line and "xvfb-run" in line
    assert not out.exists() and not (tmp_path / "demos.npz").exists()


def test_gui_humans_with_the_headless_opencv(tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str],
                                             monkeypatch: pytest.MonkeyPatch) -> None:
    # The two OpenCV wheels cannot be installed side by side (README), so the headless
    # build is stood in for by what gui.display reads from it: no HighGUI framework.
    import gui.display

    monkeypatch.setenv("DISPLAY", ":0")
    monkeypatch.setattr(gui.display, "gui_framework", lambda: "")
    line = one_line(["trial", "--humans", "gui", "--out", str(tmp_path / "out")], capsys)
    assert "headless build" in line and "pip install" in line
    assert not (tmp_path / "out").exists()


def test_gui_humans_need_someone(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cfg = write(tmp_path / "f.toml", '[humans]\ncount = 0\nkind = "gui"\n')
    line = one_line(["trial", "--config", str(cfg), "--out", str(tmp_path / "out")], capsys)
    assert "humans.count" in line


@pytest.mark.parametrize("how", ["flag", "config", "protocol"])
def test_web_humans_need_someone(how: str, tmp_path: Path,
                                 capsys: pytest.CaptureFixture[str]) -> None:
    # Without the check: a web server with no page to serve, and a trial no one can help.
    nobody = write(tmp_path / "f.toml", "[humans]\ncount = 0\n")
    out = tmp_path / "out"
    argv = {
        "flag": ["trial", "--humans", "web", "--config", str(nobody), "--out", str(out)],
        "config": ["trial", "--config", str(write(tmp_path / "w.toml", '[humans]\ncount = 0\n'
                                                  'kind = "web"\n')), "--out", str(out)],
        "protocol": ["protocol", str(write(tmp_path / "p.toml", 'name = "p"\ntrials = 1\n'
                                           'humans = "web"\n[fleet.humans]\ncount = 0\n')),
                     "--out", str(out)],
    }[how]
    line = one_line(argv, capsys)
    assert "humans.count" in line and "browser console" in line
    assert not out.exists()


def test_web_humans_without_the_web_extra(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                         monkeypatch: pytest.MonkeyPatch) -> None:
    # Without the check: an ImportError deep in gui.web after pretraining.
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "uvicorn" else real(name, *a))
    out = tmp_path / "out"
    line = one_line(["trial", "--humans", "web", "--out", str(out)], capsys)
    assert "web extra" in line and "uvicorn" in line and 'pip install -e ".[web]"' in line
    assert not out.exists()


@pytest.mark.parametrize("verb", [
    ["trial"], ["evaluate", "--policy", "p.pt"], ["collect"], ["pretrain", "--demos", "d.npz"],
    ["rehearse"]])
def test_every_humans_flag_offers_web(verb: list[str]) -> None:
    from testbed.cli import build_parser

    assert build_parser().parse_args([*verb, "--humans", "web"]).humans == "web"


def test_scripted_humans_cannot_teleoperate_a_physical_robot(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cfg = write(tmp_path / "f.toml", YUMI.format(url="http://192.0.2.1"))
    line = one_line(["trial", "--config", str(cfg), "--out", str(tmp_path / "out")], capsys)
    assert "scripted" in line and "yumi0" in line and "--humans gui" in line
    assert not (tmp_path / "out").exists()


def test_scripted_humans_may_drive_a_hardware_twin() -> None:
    # A rehearsal's yumi hosts run on the hardware twin (its RWS on loopback), whose side
    # channel the scripted humans read: no error for them, nor for the twin fleet.
    from testbed.cli.checks import check_humans
    from testbed.experiments.fleet_config import default_twin_config, parse_config

    check_humans("scripted", parse_config(tomllib.loads(
        YUMI.format(url="http://127.0.0.1:4101"))))
    check_humans("scripted", default_twin_config())


# ---- files and folders named on the command line ---------------------------------------
@pytest.fixture(scope="module")
def small_learner(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A real learner.pt with ensemble_size 1 (the default config asks for 5)."""
    from testbed.learning import Learner
    from testbed.learning.learning_config import LearningConfig

    path = tmp_path_factory.mktemp("learner") / "learner.pt"
    Learner(LearningConfig(ensemble_size=1), seed=0).save(path)
    return path


def test_policy_of_another_shape(small_learner: Path, tmp_path: Path,
                                 capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    line = one_line(["evaluate", "--policy", str(small_learner), "--out", str(out)], capsys)
    assert "--policy" in line and "learning.ensemble_size = 1" in line
    assert not out.exists()


@pytest.mark.parametrize("verb", ["trial", "evaluate"])
def test_policy_that_is_not_a_checkpoint(verb: str, tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    bogus = write(tmp_path / "learner.pt", "not a checkpoint\n")
    out = tmp_path / "out"
    line = one_line([verb, "--policy", str(bogus), "--out", str(out)], capsys)
    assert "--policy" in line and "is not a learner checkpoint" in line
    assert not out.exists()


def test_policy_missing(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    line = one_line(["trial", "--policy", str(tmp_path / "none.pt"),
                     "--out", str(tmp_path / "out")], capsys)
    assert "--policy: no such file" in line


def test_resume_of_folders_that_are_not_runs(tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    assert "--resume: no such run folder" in one_line(
        ["trial", "--resume", str(tmp_path / "none")], capsys)
    run = tmp_path / "run"
    run.mkdir()
    assert "not a run folder (no config.toml)" in one_line(
        ["trial", "--resume", str(run)], capsys)
    write(run / "config.toml", HOST)
    assert "no run.json" in one_line(["trial", "--resume", str(run)], capsys)
    write(run / "run.json", '{"options": {"algorithm": "cur", "steps": 5, "seed": 0, '
          f'"out": "{tmp_path}", "humans": "scripted"}}}}')
    assert "no checkpoint yet (state.json)" in one_line(["trial", "--resume", str(run)], capsys)
    write(run / "run.json", '{"options": {"algorithm": "cur", "colour": "red"}}')
    assert "run.json: unexpected options" in one_line(["trial", "--resume", str(run)], capsys)


def test_demos_that_are_not_demos(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    demos = write(tmp_path / "demos.npz", "not an npz\n")
    out = tmp_path / "learner.pt"
    line = one_line(["pretrain", "--demos", str(demos), "--out", str(out)], capsys)
    assert "--demos" in line and "not a demonstrations file" in line
    assert not out.exists()


@pytest.mark.parametrize(("argv", "words"), [
    (["trial", "--out", "{file}"], "is a file, not a folder"),
    (["trial", "--name", "../escape"], "--name"),
    (["collect", "--out", "{tmp}/nowhere/demos.npz"], "--out: no such folder"),
    (["collect", "--out", "{tmp}"], "is a folder"),
    (["check", "--mosaic", "{tmp}/nowhere/check.png"], "--mosaic: no such folder"),
    (["report", "{tmp}", "--out", "{file}"], "is a file, not a folder"),
    (["pretrain", "--demos", "{tmp}/none.npz"], "--demos: no such file"),
])
def test_output_paths(argv: list[str], words: str, tmp_path: Path,
                      capsys: pytest.CaptureFixture[str]) -> None:
    file = write(tmp_path / "a-file", "x\n")
    line = one_line([a.format(tmp=tmp_path, file=file) for a in argv], capsys)
    assert words in line


def test_twin_protocol_file_is_a_fine_fleet(tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    # A protocol file where a fleet is expected: its [fleet] (4 twin arms) is used; the
    # next problem (an unknown algorithm) is what this run is stopped for.
    line = one_line(["trial", "--config", str(TWIN_PROTOCOL), "--algorithm", "nope",
                     "--out", str(tmp_path / "out")], capsys)
    assert "unknown algorithm 'nope'" in line


def test_a_reference_with_no_runs_is_named(tmp_path: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    run = tmp_path / "cur-t0"
    run.mkdir()
    write(run / "steps.jsonl", '{"t": 0, "robots": [{"robot": "h/a", "mode": "autonomous", '
          '"human": null, "action": 1, "success": false, "violation": false, '
          '"uncertainty": 0.1, "risk": 0.0, "key": [0.0]}]}\n')
    write(run / "run.json", '{"options": {"algorithm": "cur"}, "status": "complete"}')
    line = one_line(["report", str(tmp_path), "--reference", "fleet-td"], capsys)
    assert "--reference" in line and "'fleet-td'" in line and "cur" in line
    assert not (tmp_path / "report.html").exists()  # nothing half-written


# ---- the failure monitor (issue 36, item 7) ---------------------------------------------
@pytest.mark.parametrize(("section", "field", "words"), [
    ("alpha = 1.5", "monitor.alpha", "must be in (0, 1)"),
    ("alpha = 0.0", "monitor.alpha", "must be in (0, 1)"),
    ("horizon = 0", "monitor.horizon", "greater than or equal to 1"),
    ("alpha = 0.05\nwindow = 5", "monitor.window", "at least 19 episodes"),
    ("gamma = 0.0", "monitor.gamma", "must be in (0, 1]"),
    ("gamma = 1.5", "monitor.gamma", "must be in (0, 1]"),
    ('alarm = "weighted"', "monitor.alarm", "'aci' or 'split'"),
    ('score = "goal_risk"', "monitor.score", "'ood_u'"),
    ('score = "fail_head"', "monitor.head", 'required with score = "fail_head"'),
    ('score = "fail_head"\nhead = "gone.json"', "monitor.head", "cannot read gone.json"),
    ('score = "fail_head"\nhead = "m.toml"', "monitor.head", "is not JSON"),
])
def test_a_bad_monitor_config_names_its_field(section: str, field: str, words: str,
                                              tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    """Each would otherwise have run a trial whose alarm promised nothing (alpha 1.5),
    scored no horizon, calibrated on too few episodes for its bound, watched a critic
    the monitor algorithm never trains, or a failure head it does not have."""
    monkeypatch.chdir(tmp_path)
    _names_its_field(tmp_path, capsys, f"[monitor]\n{section}\n", field, words,
                     ["--algorithm", "monitor"])


def _names_its_field(tmp_path: Path, capsys: pytest.CaptureFixture[str], toml: str,
                     field: str, words: str, argv: list[str]) -> None:
    """``testbed trial`` with the config ``toml``: one line naming ``field`` with
    ``words``, exit 2 (``one_line``), no run folder made."""
    cfg = write(tmp_path / "m.toml", toml)
    line = one_line(["trial", "--config", str(cfg), *argv, "--out", str(tmp_path / "runs")],
                    capsys)
    assert field in line and words in line, line
    assert not (tmp_path / "runs").exists()


# ---- learning from every push (issue 46, item 6) ----------------------------------------
@pytest.mark.parametrize(("section", "field", "words"), [
    ('weighting = "advantages"', "learning.weighting", "'advantage'"),
    ('conditioning = "recap"', "learning.conditioning", "'advantage'"),
    ("advantage_temperature = 0.0", "learning.advantage_temperature", "greater than 0"),
    ("advantage_temperature = 20.0", "learning.advantage_temperature", "less than or equal"),
    ("advantage_threshold = 1.5", "learning.advantage_threshold", "less than or equal to 1"),
    ("advantage_max_weight = 0.5", "learning.advantage_max_weight", "greater than or equal"),
    ("condition_dropout = -0.1", "learning.condition_dropout", "greater than or equal"),
    ("gamma_value = 1.2", "learning.gamma_value", "less than or equal to 1"),
    ("value_every = 0", "learning.value_every", "greater than or equal to 1"),
])
def test_a_bad_advantage_config_names_its_field(section: str, field: str, words: str,
                                                tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    _names_its_field(tmp_path, capsys, f"[learning]\n{section}\n", field, words, [])
