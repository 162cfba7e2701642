"""A rehearsal run again finds the theta_0 its first session pretrained, for every trial
of a protocol that pretrains one per trial (``testbed/lab/rehearsal.py::_same_theta_0``).

A new session's twins listen on new ports, which are in theta_0's cache key (a host's
camera and controller URLs say what it is); the first session's key is linked to the new
one for each seed a theta_0 is pretrained from. Pure: folders and keys, no twin."""

from __future__ import annotations

from pathlib import Path

from lab_fixtures import tiny_protocol

from testbed.experiments.learners import PRETRAIN_SEED
from testbed.experiments.pretraining import pretrain_key
from testbed.experiments.protocol import Protocol, load_protocol, pretrain_critics
from testbed.fleet.algorithms import ALGORITHMS
from testbed.lab.rehearsal import _same_theta_0


def _session(proto: Protocol, port: int, tmp: Path) -> Protocol:
    """The protocol as a session's lab rewrites it: its twins' ports, its own key files."""
    key, known = tmp / "key", tmp / "known_hosts"
    key.touch(mode=0o600)
    known.touch()
    hosts = [h.model_copy(update={"controller_url": f"http://127.0.0.1:{port + i}",
                                  "key_file": str(key), "known_hosts": str(known)})
             for i, h in enumerate(proto.fleet.hosts)]
    return proto.model_copy(update={"fleet": proto.fleet.model_copy(update={"hosts": hosts})})


def _keys(proto: Protocol, seed: int) -> set[str]:
    both = pretrain_critics([proto.algorithm_of(a) for a in proto.algorithms])
    return {pretrain_key(proto.fleet_of(a), seed, sorted(
        set(ALGORITHMS[proto.algorithm_of(a)].critics) | set(both))) for a in proto.algorithms}


def _linked(per_trial: bool, tmp_path: Path) -> tuple[Protocol, Protocol, Path]:
    proto = load_protocol(tiny_protocol(tmp_path), check_files=False).model_copy(
        update={"pretrain_per_trial": per_trial, "seeds": [3, 5, 8]})
    first, second = _session(proto, 41000, tmp_path), _session(proto, 42000, tmp_path)
    _same_theta_0(first, tmp_path)  # the first session keeps its fleet
    cache = tmp_path / ".pretrained"
    for seed in (PRETRAIN_SEED, 3, 5, 8):  # what the first session pretrained
        for key in _keys(first, seed):
            (cache / key).mkdir(parents=True, exist_ok=True)
    _same_theta_0(second, tmp_path)
    return first, second, cache


def test_every_trials_theta_0_is_found_again_by_the_next_session(tmp_path: Path) -> None:
    first, second, cache = _linked(True, tmp_path)
    for seed in (3, 5, 8):
        new = _keys(second, seed)
        assert new.isdisjoint(_keys(first, seed))  # the ports changed the key
        for key in new:
            assert (cache / key).is_symlink(), (seed, key)
            assert (cache / key).resolve().name in _keys(first, seed)


def test_a_shared_theta_0_is_the_one_linked(tmp_path: Path) -> None:
    _, second, cache = _linked(False, tmp_path)
    assert all((cache / key).is_symlink() for key in _keys(second, PRETRAIN_SEED))
    assert not any((cache / key).exists() for key in _keys(second, 3))
