"""Bad configs and arguments: exit status 2, one line naming the field, no traceback."""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from drivers.backends.twin.twin_host import TwinHost
from drivers.yumi.yumi_host import YumiHost
from testbed.cli import main
from testbed.core.config import ConfigError
from testbed.experiments.fleet_config import (
    default_twin_config,
    file_kind,
    load_config,
    load_fleet,
    parse_config,
)

HOST = '[[hosts]]\nname = "cell0"\n'
YUMI = (
    '[[hosts]]\nname = "yumi0"\nbackend = "yumi"\ncamera = "0"\n'
    'controller_url = "http://192.0.2.1"\n'
    'arms = [{name = "left", crop = [0, 0, 300, 300], calibration = "/c/l.json"}]\n'
)

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
    ("web-dead-link", '[humans.web]\nhost = "0.0.0.0"\npublic_url = "http://lab-pc:8765"\n',
     "humans.web.public_url"),
    ("steps-zero", "[trial]\nsteps = 0\n", "trial.steps"),
    ("host-name-space", '[[hosts]]\nname = "cell 0"\n', "name"),
    ("mirror-int", HOST + 'arms = [{name = "a", mirror = 3}]\n', "mirror"),
    ("deadline-negative", HOST + "deadline_s = -1\n", "deadline_s"),
    ("hosts-not-list", 'hosts = "cell0"\n', "hosts"),
    ("algorithm-name", '[algorithm]\nname = "magic"\n', "magic"),
    # The host union: YuMi fields checked at load time, each backend's own fields only.
    ("yumi-no-camera", YUMI.replace('camera = "0"\n', ""), "hosts[0].camera"),
    ("yumi-no-controller", YUMI.replace('controller_url = "http://192.0.2.1"\n', ""),
     "hosts[0].controller_url"),
    ("yumi-controller-scheme", YUMI.replace("http://192.0.2.1", "ftp://192.0.2.1"),
     "hosts[0].controller_url"),
    ("yumi-controller-no-host", YUMI.replace("http://192.0.2.1", "http://"),
     "hosts[0].controller_url"),
    ("yumi-controller-old-twin-scheme", YUMI.replace("http://192.0.2.1",
                                                     "twin+http://127.0.0.1:4101"),
     "hosts[0].controller_url"),
    ("yumi-motion-timeout-past-deadline", YUMI.replace(
        'controller_url = "http://192.0.2.1"\n',
        'controller_url = "http://192.0.2.1"\ndeadline_s = 10\nmotion_timeout_s = 12\n'),
     "hosts[0].motion_timeout_s"),
    ("yumi-credentials-empty", YUMI.replace(
        'controller_url = "http://192.0.2.1"\n',
        'controller_url = "http://192.0.2.1"\ncredentials_file = " "\n'),
     "hosts[0].credentials_file"),
    ("yumi-camera-scheme", YUMI.replace('camera = "0"', 'camera = "ftp://cam/x"'),
     "hosts[0].camera"),
    ("yumi-camera-empty", YUMI.replace('camera = "0"', 'camera = " "'), "hosts[0].camera"),
    ("yumi-no-crop", YUMI.replace("crop = [0, 0, 300, 300], ", ""), "hosts[0].arms[0].crop"),
    ("yumi-no-calibration", YUMI.replace(', calibration = "/c/l.json"', ""),
     "hosts[0].arms[0].calibration"),
    ("yumi-calibration-not-json", YUMI.replace("/c/l.json", "/c/l.yaml"),
     "hosts[0].arms[0].calibration"),
    ("yumi-seed", YUMI + "seed = 3\n", "hosts[0].seed: seed is a twin-only field"),
    ("yumi-physics", YUMI + "physics = false\n", "twin-only"),
    ("twin-camera", HOST + 'camera = "0"\n', "hosts[0].camera: camera is a yumi-only field"),
    ("twin-controller", HOST + 'controller_url = "http://x"\n', "yumi-only"),
    ("backend-not-string", HOST + "backend = 3\n", "hosts[0].backend"),
    ("key-file-missing", HOST + 'key_file = "/no/such/key"\n', "hosts[0].key_file: no such"),
    ("known-hosts-missing", HOST + 'known_hosts = "/no/such/kh"\n', "hosts[0].known_hosts"),
    ("unset-var", HOST + 'key_file = "$T1_SURELY_UNSET_VAR/k"\n', "$T1_SURELY_UNSET_VAR"),
    ("unset-var-local-workdir", HOST + 'workdir = "${T1_SURELY_UNSET_VAR}/x"\n',
     "hosts[0].workdir"),
    # The browser console ([humans.web]).
    ("web-kind", '[humans]\nkind = "webb"\n', "humans.kind"),
    ("web-tokens-count", f'[humans.web]\ntokens = ["{"a" * 16}"]\n',
     "humans.web.tokens: 1 token for humans.count = 2"),
    ("web-token-short", f'[humans.web]\ntokens = ["{"a" * 16}", "short"]\n',
     "humans.web.tokens[1]: a token of 5 characters"),
    ("web-token-chars", f'[humans.web]\ntokens = ["{"a" * 16}", "{"b" * 15}/"]\n',
     "humans.web.tokens[1]"),
    ("web-tokens-same", f'[humans.web]\ntokens = ["{"a" * 16}", "{"a" * 16}"]\n',
     "humans.web.tokens: two humans have the same token"),
    ("web-certfile-alone", '[humans.web]\ncertfile = "/etc/cert.pem"\n',
     "humans.web.keyfile: certfile is set but keyfile is not"),
    ("web-keyfile-alone", '[humans.web]\nkeyfile = "/etc/key.pem"\n', "humans.web.certfile"),
    ("web-certfile-missing", '[humans.web]\ncertfile = "/no/such/cert.pem"\n'
     'keyfile = "/no/such/key.pem"\n', "humans.web.certfile: no such file"),
    ("web-grace-negative", "[humans.web]\ngrace_s = -1\n", "humans.web.grace_s"),
    ("web-grace-nan", "[humans.web]\ngrace_s = nan\n", "humans.web.grace_s"),
    ("web-away-timeout-zero", "[humans.web]\naway_timeout_s = 0\n",
     "humans.web.away_timeout_s"),
    ("web-teleop-timeout-negative", "[humans.web]\nteleop_timeout_s = -2.5\n",
     "humans.web.teleop_timeout_s"),
    ("web-port", "[humans.web]\nport = 65536\n", "humans.web.port"),
    ("web-host", '[humans.web]\nhost = "http://lab-pc"\n', "humans.web.host"),
    ("web-unknown-key", '[humans.web]\ntoken = "x"\n', "humans.web.token: unknown key"),
    # Where the people are: a hard reset needs one in the room (issue 44).
    ("nobody-on-site", '[[humans.people]]\nname = "ana"\nwhere = "remote"\n'
     '[[humans.people]]\nname = "bo"\nwhere = "remote"\n',
     "humans.people: nobody is on site, and a hard reset needs a person in the room"),
    ("nobody-on-site-web", '[humans]\nkind = "web"\n[[humans.people]]\nname = "ana"\n'
     'where = "remote"\n', "humans.people: nobody is on site"),
    ("where-unknown", '[[humans.people]]\nname = "ana"\nwhere = "lab"\n',
     "humans.people[0].where"),
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


def lab_home(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A HOME holding the key and known_hosts files that physical.toml names."""
    home = tmp_path / "home"
    (home / ".ssh").mkdir(parents=True)
    for name in ("fleet_ed25519", "known_hosts"):
        (home / ".ssh" / name).write_text("x\n")
    monkeypatch.setenv("HOME", str(home))
    return home


def test_shipped_protocols_are_valid(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from testbed.experiments.protocol import load_protocol

    home = lab_home(tmp_path, monkeypatch)
    root = Path(__file__).resolve().parents[2] / "protocols"
    twin = load_protocol(root / "twin.toml")
    phys = load_protocol(root / "physical.toml")
    assert twin.trials == 3 and twin.steps == 250 and len(twin.fleet.robot_names) == 4
    assert phys.algorithms == ["bc", "random", "fleet-ed", "cur"]
    assert phys.fleet.humans.kind == "gui" and phys.prompt_when == "before_each_run"
    assert all(h.transport == "ssh" and h.backend == "yumi" for h in phys.fleet.hosts)
    assert all(h.key_file == str(home / ".ssh/fleet_ed25519") for h in phys.fleet.hosts)
    # Thresholds and Random's budget from data in both protocols (issue 12): u_hat is the
    # 75th percentile on theta_0, the quantile the default trial's 0.17 was measured at
    for p in (twin, phys):
        assert p.fleet.algorithm.u_hat == "q0.75", p.name
        assert p.fleet.algorithm.random_budget == "match:cur", p.name
    assert default_twin_config().algorithm.u_hat == 0.17
    assert phys.fleet.learning.critic_steps == 3000
    # The paper's fleet size: N = 100 arms on 50 twin hosts, M = 10, t_T = t_R = 5, C.U.R.
    scale = load_protocol(root / "twin-scale.toml")
    f = scale.fleet
    assert len(f.robot_names) == 100 and len(f.hosts) == 50 and f.humans.count == 10
    assert (f.algorithm.t_T, f.algorithm.t_R, scale.algorithms) == (5, 5, ["cur"])
    assert f.algorithm.u_hat == default_twin_config().algorithm.u_hat
    assert (f.learning.batch_size, f.learning.gradient_steps, f.learning.ensemble_size) == (
        256, 1, 5)


def test_load_config_missing_file_is_config_error(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="cannot read"):
        load_config(tmp_path / "none.toml")


def test_backend_selects_the_host_model() -> None:
    cfg = parse_config(tomllib.loads(HOST + YUMI))
    twin, yumi = cfg.hosts
    assert isinstance(twin, TwinHost) and twin.backend == "twin"  # absent key: twin
    assert isinstance(yumi, YumiHost) and yumi.camera == "0" and yumi.arms[0].crop
    assert not hasattr(yumi, "seed") and not hasattr(twin, "camera")
    assert parse_config(tomllib.loads(YUMI.replace('"0"', "2"))).hosts[0].camera == "2"
    again = parse_config(cfg.model_dump(mode="json"))  # a run's config.toml round trip
    assert again == cfg and [type(h) for h in again.hosts] == [TwinHost, YumiHost]


def test_paths_expand_tilde_and_vars(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    home = lab_home(tmp_path, monkeypatch)
    monkeypatch.setenv("LAB", str(tmp_path / "lab"))
    local = (YUMI.replace('camera = "0"', 'camera = "$LAB/cam.avi"')
             .replace("/c/l.json", "~/calib/left.json")
             + 'key_file = "~/.ssh/fleet_ed25519"\nknown_hosts = "${HOME}/.ssh/known_hosts"\n'
             'python = "$LAB/venv/bin/python"\nworkdir = "~/fleet"\n')
    h = parse_config(tomllib.loads(local)).hosts[0]
    assert h.key_file == str(home / ".ssh/fleet_ed25519")
    assert h.known_hosts == str(home / ".ssh/known_hosts")
    assert (h.python, h.workdir) == (f"{tmp_path}/lab/venv/bin/python", f"{home}/fleet")
    assert h.camera == f"{tmp_path}/lab/cam.avi"
    assert h.arms[0].calibration == f"{home}/calib/left.json"
    # Over ssh python/workdir/camera/calibration are the robot host's paths: as written.
    remote = local.replace('python = "$LAB/venv/bin/python"', 'python = "/opt/py"') + (
        'transport = "ssh"\nuser = "fleet"\n')
    r = parse_config(tomllib.loads(remote)).hosts[0]
    assert r.key_file == str(home / ".ssh/fleet_ed25519")  # read here: expanded
    assert (r.workdir, r.camera, r.arms[0].calibration) == (
        "~/fleet", "$LAB/cam.avi", "~/calib/left.json")


def test_missing_key_file_checked_unless_told(tmp_path: Path) -> None:
    text = HOST + 'key_file = "~/no-such-key"\n'
    with pytest.raises(ConfigError, match=r"hosts\[0\]\.key_file: no such file"):
        parse_config(tomllib.loads(text))
    # A caller that rewrites the hosts (a rehearsal) loads without the check.
    assert parse_config(tomllib.loads(text), check_files=False).hosts[0].key_file.endswith(
        "/no-such-key")


def test_load_fleet_reads_a_protocol_fleet(tmp_path: Path) -> None:
    root = Path(__file__).resolve().parents[2] / "protocols"
    cfg = load_fleet(root / "twin.toml")
    assert cfg.name == "twin" and len(cfg.robot_names) == 4
    assert load_fleet(root / "physical.toml", check_files=False).name == "yumi-lab"
    bad = tmp_path / "proto.toml"
    bad.write_text('name = "p"\ntrials = 1\n[fleet]\n[[fleet.hosts]]\nname = "a"\nport = 0\n')
    with pytest.raises(ConfigError, match=r"proto.toml: fleet.hosts\[0\].port"):
        load_fleet(bad)
    fleet = tmp_path / "fleet.toml"
    fleet.write_text(HOST)
    assert file_kind(tomllib.loads(HOST)) == "fleet" and load_fleet(fleet).hosts[0].name == "cell0"


def test_web_console_config(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    web = default_twin_config().humans.web
    assert (web.host, web.port, web.tokens, web.certfile, web.keyfile) == (
        "127.0.0.1", 8765, [], None, None)  # loopback unless the config says otherwise
    assert (web.grace_s, web.away_timeout_s, web.teleop_timeout_s) == (10.0, 5.0, 30.0)
    home = lab_home(tmp_path, monkeypatch)
    (home / "tls").mkdir()
    for name in ("cert.pem", "key.pem"):
        (home / "tls" / name).write_text("x\n")
    monkeypatch.setenv("TLS", str(home / "tls"))
    tokens = ["A" * 16, "b-_9" * 6, "c" * 40]
    cfg = parse_config({"humans": {"count": 3, "kind": "web", "web": {
        "host": "0.0.0.0", "port": 0, "tokens": tokens, "certfile": "~/tls/cert.pem",
        "keyfile": "$TLS/key.pem", "grace_s": 0, "away_timeout_s": 0.5,
        "teleop_timeout_s": 30}}})
    web = cfg.humans.web
    assert (cfg.humans.kind, web.host, web.port, web.tokens) == ("web", "0.0.0.0", 0, tokens)
    assert (web.certfile, web.keyfile) == (f"{home}/tls/cert.pem", f"{home}/tls/key.pem")
    assert parse_config(cfg.model_dump(mode="json")) == cfg  # a run's config.toml
    # A rehearsal loads without checking files: the paths are still expanded.
    lax = parse_config({"humans": {"web": {"certfile": "~/none.pem", "keyfile": "~/k.pem"}}},
                       check_files=False)
    assert lax.humans.web.certfile == f"{home}/none.pem"
    # A bad token is named by its place, never echoed: it is a secret.
    with pytest.raises(ConfigError) as err:
        parse_config({"humans": {"count": 1, "web": {"tokens": ["my pass word, do not show"]}}})
    assert "humans.web.tokens[0]" in str(err.value) and "pass word" not in str(err.value)


def test_a_public_url_the_console_cannot_answer_is_refused(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Off loopback with tls = "auto" the console serves https: an http:// public_url
    prints dead links (exit 2, one line saying both ways out). An https public_url
    before a loopback console (a proxy or a tunnel terminating TLS) and http with tls =
    "off" or on loopback stay accepted."""
    cfg = tmp_path / "fleet.toml"
    cfg.write_text('[humans]\nkind = "web"\n[humans.web]\nhost = "0.0.0.0"\n'
                   'public_url = "http://lab-pc:8765"\n')
    assert main(["check", "--config", str(cfg)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith(f"testbed check: {cfg}: ")
    assert ('humans.web.public_url: http:// but the console serves https off loopback (tls '
            '= "auto"); write https://..., or tls = "off" behind a proxy that terminates '
            "TLS") in err
    for web in ({"host": "0.0.0.0", "public_url": "https://lab-pc:8765"},
                {"host": "127.0.0.1", "public_url": "https://lab.example.org/fleet"},
                {"host": "0.0.0.0", "tls": "off", "public_url": "http://lab-pc:8765"},
                {"host": "127.0.0.1", "public_url": "http://127.0.0.1:9000"}):
        assert parse_config({"humans": {"web": web}}).humans.web.public_url == \
            web["public_url"]
