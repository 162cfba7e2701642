"""The agent's command line: the common flags and the chosen backend plugin's own.

Why: a host's agent is started by argv alone (over SSH, by a deployed host's unit), so
what ``--help`` shows, which flag is refused and how a broken plugin on the host is
reported are its whole user interface."""

from __future__ import annotations

import os

import pytest

from drivers import agent
from drivers.agent import agent_cli
from testbed.core.backend_registry import BackendError


def test_help_after_backend_shows_its_flags(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as done:
        agent.parse_args(["--backend", "yumi", "--help"])
    shown = capsys.readouterr().out
    assert done.value.code == 0
    assert "--controller-url" in shown and "--motion-timeout" in shown  # the plugin's
    assert "--lock-id" in shown and "--no-physics" not in shown  # common; not the twin's
    with pytest.raises(SystemExit):
        agent.parse_args(["--backend=twin", "--help"])
    assert "--no-physics" in capsys.readouterr().out


def test_another_backends_flag_is_a_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as done:
        agent.parse_args(["--backend", "twin", "--camera", "0"])
    assert done.value.code == 2
    assert "unrecognized arguments: --camera 0" in capsys.readouterr().err
    with pytest.raises(SystemExit) as done:
        agent.parse_args(["--backend", "ur5e"])
    assert done.value.code == 2
    assert "invalid choice: 'ur5e'" in capsys.readouterr().err


def test_a_broken_plugin_is_one_line_exit_2(monkeypatch: pytest.MonkeyPatch,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    def broken() -> None:
        raise BackendError("backend 'ur5e' (package lab 1.0): cannot import lab.ur5e")

    monkeypatch.setattr("drivers.backends.plugin.agent_plugins", broken)
    frames_fd = os.dup(1)
    monkeypatch.setattr(agent_cli, "claim_stdout", lambda: frames_fd)  # pytest's stdout
    try:
        assert agent.main(["--backend", "ur5e"]) == 2
    finally:
        os.close(frames_fd)
    err = capsys.readouterr().err
    assert err == ("python -m drivers.agent: backend 'ur5e' (package lab 1.0): cannot "
                   "import lab.ur5e\n")
