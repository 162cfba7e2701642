"""Bad configs and arguments: exit status 2, one line naming the field, no traceback."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from testbed.cli import main
from testbed.config import ConfigError, default_twin_config, load_config

HOST = '[[hosts]]\nname = "cell0"\n'

# (id, TOML text, a word the one-line error must contain)
MALFORMED: list[tuple[str, str, str]] = [
    ("not-toml", "this is = = not toml", "TOML"),
    ("unknown-top-key", "trail = {}\n", "trail"),
    ("unknown-host-key", HOST + 'adress = "x"\n', "adress"),
    ("port-string", HOST + 'port = "ssh"\n', "port"),
    ("port-zero", HOST + "port = 0\n", "port"),
    ("port-too-big", HOST + "port = 70000\n", "port"),
    ("backend", HOST + 'backend = "kuka"\n', "backend"),
    ("transport", HOST + 'transport = "telnet"\n', "transport"),
    ("ssh-missing", HOST + 'transport = "ssh"\npython = "/usr/bin/python3"\n', "user"),
    ("ssh-relative-python", HOST + 'transport = "ssh"\nuser = "u"\nkey_file = "k"\n'
     'known_hosts = "kh"\n', "absolute"),
    ("duplicate-hosts", HOST + HOST, "unique"),
    ("duplicate-arms", HOST + 'arms = [{name = "a"}, {name = "a"}]\n', "unique"),
    ("no-arms", HOST + "arms = []\n", "arm"),
    ("no-hosts", "hosts = []\n", "host"),
    ("crop-negative", HOST + 'arms = [{name = "a", crop = [-1, 0, 10, 10]}]\n', "crop"),
    ("crop-inverted", HOST + 'arms = [{name = "a", crop = [10, 0, 5, 10]}]\n', "crop"),
    ("crop-length", HOST + 'arms = [{name = "a", crop = [1, 2, 3]}]\n', "crop"),
    ("humans-negative", "[humans]\ncount = -1\n", "humans.count"),
    ("humans-kind", '[humans]\nkind = "robot"\n', "humans.kind"),
    ("t_T-zero", "[algorithm]\nt_T = 0\n", "algorithm.t_T"),
    ("t_R-string", '[algorithm]\nt_R = "five"\n', "algorithm.t_R"),
    ("u_hat-range", "[algorithm]\nu_hat = 1.5\n", "algorithm.u_hat"),
    ("lr-zero", "[learning]\nlr = 0\n", "learning.lr"),
    ("batch-zero", "[learning]\nbatch_size = 0\n", "learning.batch_size"),
    ("ensemble-huge", "[learning]\nensemble_size = 100\n", "learning.ensemble_size"),
    ("device", '[learning]\ndevice = "tpu"\n', "learning.device"),
    ("critic-steps", "[learning]\ncritic_pretrain_steps = -1\n", "learning.critic_pretrain_steps"),
    ("steps-zero", "[trial]\nsteps = 0\n", "trial.steps"),
    ("host-name-space", '[[hosts]]\nname = "cell 0"\n', "name"),
    ("mirror-int", HOST + 'arms = [{name = "a", mirror = 3}]\n', "mirror"),
    ("deadline-negative", HOST + "deadline_s = -1\n", "deadline_s"),
    ("hosts-not-list", 'hosts = "cell0"\n', "hosts"),
    ("algorithm-name", '[algorithm]\nname = "magic"\n', "magic"),
]


def test_thirty_distinct_malformed_configs() -> None:
    assert len({text for _, text, _ in MALFORMED}) >= 30


@pytest.mark.parametrize(("case", "text", "word"), MALFORMED, ids=[m[0] for m in MALFORMED])
def test_malformed_config_exits_2_with_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], case: str, text: str, word: str
) -> None:
    cfg = tmp_path / "fleet.toml"
    cfg.write_text(text)
    code = main(["trial", "--config", str(cfg), "--out", str(tmp_path / "runs")])
    err = capsys.readouterr().err
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "Traceback" not in err
    assert word in lines[0], lines[0]
    assert not (tmp_path / "runs").exists(), "a bad config must not start a run"


@pytest.mark.parametrize(
    "argv",
    [
        ["trial", "--steps", "0"],
        ["trial", "--steps", "many"],
        ["trial", "--algorithm", "bogus"],
        ["trial", "--seed", "x"],
        ["trial", "--humans", "robots"],
        ["trial", "--frobnicate"],
        ["trial", "--config", "/no/such/file.toml"],
        ["trial", "--resume", "/no/such/run"],
        ["report", "/no/such/dir"],
        ["evaluate", "--policy", "/no/such/learner.pt"],
    ],
)
def test_bad_arguments_exit_2_with_one_line(
    argv: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    try:
        code = main(argv)
    except SystemExit as exc:
        code = int(exc.code or 0)
    err = capsys.readouterr().err
    assert code == 2
    assert len(err.strip().splitlines()) == 1, err
    assert "Traceback" not in err


def test_real_process_gives_one_line(tmp_path: Path) -> None:
    cfg = tmp_path / "fleet.toml"
    cfg.write_text(HOST + "port = 0\n")
    proc = subprocess.run(
        [sys.executable, "-m", "testbed.cli", "trial", "--config", str(cfg)],
        capture_output=True, text=True, timeout=60,
    )
    assert proc.returncode == 2
    assert proc.stderr.strip().count("\n") == 0 and "hosts[0].port" in proc.stderr


def test_default_config_is_the_twin_fleet() -> None:
    cfg = default_twin_config()
    assert cfg.robot_names == ["cell0/left", "cell0/right", "cell1/left", "cell1/right"]
    assert cfg.humans.count == 2 and cfg.humans.kind == "scripted"
    assert cfg.trial.steps == 250 and cfg.algorithm.name == "cur"
    assert all(h.transport == "local" and h.backend == "twin" for h in cfg.hosts)


def test_shipped_protocols_are_valid() -> None:
    from testbed.protocol import load_protocol

    root = Path(__file__).resolve().parents[2] / "protocols"
    twin = load_protocol(root / "twin.toml")
    phys = load_protocol(root / "physical.toml")
    assert twin.trials == 3 and twin.steps == 250 and len(twin.fleet.robot_names) == 4
    assert phys.algorithms == ["bc", "random", "fleet-ed", "cur"]
    assert phys.fleet.humans.kind == "gui" and phys.prompt_between_trials
    assert all(h.transport == "ssh" and h.backend == "yumi" for h in phys.fleet.hosts)
    # One calibrated u_hat for the twin: the default trial and the twin protocol agree.
    assert twin.fleet.algorithm.u_hat == default_twin_config().algorithm.u_hat == 0.17
    assert phys.fleet.learning.critic_steps == 3000


def test_load_config_missing_file_is_config_error(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="cannot read"):
        load_config(tmp_path / "none.toml")
