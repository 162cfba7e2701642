"""Build ids: what a checkout's id is made of (real git, real files), that an agent
reports it at hello, and that a host running another checkout is refused at hello.

The scheme (``drivers.build_id``): ``<version>+g<sha7>`` for a clean checkout,
``.d<hash8>`` added for uncommitted changes to the product; tests, docs and ignored
files are not the product and change nothing; ``<version>+src.h<hash8>`` for a source
tree git cannot read.
"""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest
from driver_fakes import ROOT, local_host
from test_agent_process import Agent

from drivers import wire as p
from drivers.build_id import (
    build_id,
    checkout_build,
    is_checkout,
    mismatch_line,
    product_files,
    source_state,
    tree_build,
)
from drivers.errors import ProtocolError

GIT = ["git", "-c", "user.email=test@example.com", "-c", "user.name=test"]


def git(root: Path, *args: str) -> str:
    return subprocess.run([*GIT, "-C", str(root), *args], check=True, capture_output=True,
                          text=True).stdout


def sha7(root: Path) -> str:
    return git(root, "rev-parse", "HEAD").strip()[:7]


@pytest.fixture
def checkout(tmp_path: Path) -> Path:
    """A tiny project checkout: pyproject, a product module, a test, an ignored file."""
    root = tmp_path / "proj"
    (root / "drivers").mkdir(parents=True)
    (root / "tests").mkdir()
    (root / "pyproject.toml").write_text('[project]\nname = "x"\nversion = "1.2.3"\n')
    (root / "drivers" / "a.py").write_text("A = 1\n")
    (root / "tests" / "test_a.py").write_text("def test(): pass\n")
    (root / ".gitignore").write_text("*.log\n")
    git(root, "init", "-q")
    git(root, "add", "-A")
    git(root, "commit", "-qm", "one")
    return root


def test_a_clean_checkout_is_its_version_and_commit(checkout: Path) -> None:
    assert is_checkout(checkout)
    assert checkout_build(checkout) == f"1.2.3+g{sha7(checkout)}"
    (checkout / "tests" / "test_a.py").write_text("def test(): assert 1\n")
    (checkout / "drivers" / "debug.log").write_text("ignored\n")
    (checkout / "notes.md").write_text("not the product\n")
    assert checkout_build(checkout) == f"1.2.3+g{sha7(checkout)}"  # none of it is built


def test_uncommitted_changes_to_the_product_add_a_hash_of_them(checkout: Path) -> None:
    clean = checkout_build(checkout)
    a = checkout / "drivers" / "a.py"
    a.write_text("A = 2\n")
    dirty = checkout_build(checkout)
    assert re.fullmatch(rf"{re.escape(clean)}\.d[0-9a-f]{{8}}", dirty)
    assert checkout_build(checkout) == dirty  # the same tree, the same id
    git(checkout, "add", "drivers/a.py")  # staged: still uncommitted, still the same
    assert checkout_build(checkout) == dirty
    a.write_text("A = 3\n")
    other = checkout_build(checkout)
    assert other != dirty and other.startswith(clean + ".d")
    a.write_text("A = 1\n")
    git(checkout, "add", "drivers/a.py")
    assert checkout_build(checkout) == clean  # back to the commit's content
    (checkout / "drivers" / "new.py").write_text("B = 1\n")  # untracked, not ignored
    added = checkout_build(checkout)
    assert added.startswith(clean + ".d") and added not in (dirty, other)
    assert "drivers/new.py" in product_files(checkout)
    (checkout / "drivers" / "new.py").unlink()
    a.unlink()  # deleted: a change too
    assert checkout_build(checkout).startswith(clean + ".d")
    git(checkout, "rm", "-q", "drivers/a.py")
    git(checkout, "commit", "-qm", "two")
    assert checkout_build(checkout) == f"1.2.3+g{sha7(checkout)}" != clean


def test_a_source_tree_without_git_is_a_hash_of_its_files(checkout: Path, tmp_path: Path
                                                           ) -> None:
    """A copy without .git (a tarball): both ends hash every product file instead, so
    two copies agree exactly when their files do (caches aside)."""
    copies = []
    for name in ("one", "two"):
        copy = tmp_path / name
        shutil.copytree(checkout, copy, ignore=shutil.ignore_patterns(".git"))
        copies.append(copy)
    one, two = copies
    assert not is_checkout(one)
    assert re.fullmatch(r"1\.2\.3\+src\.h[0-9a-f]{8}", tree_build(one))
    assert tree_build(one) == tree_build(two)
    (two / "drivers" / "__pycache__").mkdir()
    (two / "drivers" / "__pycache__" / "a.cpython-311.pyc").write_bytes(b"cache")
    (two / "tests" / "test_a.py").write_text("def test(): assert 1\n")
    assert tree_build(one) == tree_build(two)
    (two / "drivers" / "a.py").write_text("A = 2\n")
    assert tree_build(one) != tree_build(two)


def test_the_source_state_is_the_commit_dirty_and_build_of_one_git_reading(
        checkout: Path, tmp_path: Path) -> None:
    """What run.json ``code`` says: HEAD in full, dirty exactly when the build id has
    its ``.d<hash8>`` (the product changed, not the tests), the build id itself."""
    head = git(checkout, "rev-parse", "HEAD").strip()
    state = source_state(checkout)
    assert (state.commit, state.dirty, state.build) == (head, False, checkout_build(checkout))
    assert re.fullmatch(r"[0-9a-f]{40}", head)
    (checkout / "tests" / "test_a.py").write_text("def test(): assert 1\n")
    assert source_state(checkout).dirty is False  # not the product
    (checkout / "drivers" / "a.py").write_text("A = 2\n")
    state = source_state(checkout)
    assert state.commit == head and state.dirty is True
    assert state.build == checkout_build(checkout) and ".d" in state.build
    copy = tmp_path / "copy"
    shutil.copytree(checkout, copy, ignore=shutil.ignore_patterns(".git"))
    assert source_state(copy) == type(state)(None, None, tree_build(copy))  # no git: unknown


def test_the_controller_keeps_its_build_and_also_takes_its_trees_build_of_now(
        checkout: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Cached per process; on a mismatch asked once more: a file saved since the
    controller started is the tree its own local agents run (not another build)."""
    import drivers.build_id as b

    monkeypatch.setattr(b, "ROOT", checkout)
    b.build_id.cache_clear()
    try:
        started = b.build_id()
        assert started == checkout_build(checkout)
        (checkout / "drivers" / "a.py").write_text("A = 2\n")  # saved mid-run
        now = checkout_build(checkout)
        assert b.build_id() == started != now  # cached: git ran once
        assert b.matches(started) and b.matches(now)
        assert not b.matches("1.2.3+g0000000") and not b.matches(None)
    finally:
        b.build_id.cache_clear()  # the next caller computes this checkout's again


def test_an_agent_of_this_checkout_reports_its_build_at_hello() -> None:
    agent = Agent("--backend", "twin", "--no-physics", "--host", "cell7")
    try:
        hello = agent.call("hello", version=p.PROTOCOL_VERSION, host="cell7")
        info = p.parse_hello_reply(p.check_reply(hello, "hello_ok", 1, "agent"), "agent")
        # computed by the agent's own git run, the same way as ours (the same checkout)
        assert info.build == checkout_build(ROOT)
        assert info.controller is None  # a twin has no controller to name
        assert agent.call("bye").type == "bye_ok"
    finally:
        agent.proc.kill()
        agent.proc.wait(5)


def test_hello_ok_build_is_a_string_or_absent() -> None:
    base = {"type": "hello_ok", "id": 1, "version": p.PROTOCOL_VERSION, "backend": "twin",
            "arms": ["left"], "mirror": [False], "pid": 7}
    assert p.parse_hello_reply(p.Frame(base), "agent").build is None  # an older agent
    assert p.parse_hello_reply(p.Frame({**base, "build": "0.1.0+gabc1234"}),
                               "agent").build == "0.1.0+gabc1234"
    for bad in (5, "", ["x"]):
        with pytest.raises(ProtocolError, match="'build' must be a build id string"):
            p.parse_hello_reply(p.Frame({**base, "build": bad}), "agent")


def test_hello_ok_controller_is_an_object_of_strings_or_absent() -> None:
    """A YuMi agent's ``controller`` (no version change: optional, like ``build``)."""
    base = {"type": "hello_ok", "id": 1, "version": p.PROTOCOL_VERSION, "backend": "yumi",
            "arms": ["left"], "mirror": [False], "pid": 7, "build": "0.1.0+gabc1234"}
    assert p.parse_hello_reply(p.Frame(base), "agent").controller is None
    said = {"serial": "14000-512345", "robotware": "6.08.01.00", "system": "YUMI_A"}
    assert p.parse_hello_reply(p.Frame({**base, "controller": said}), "agent"
                               ).controller == said
    assert p.parse_hello_reply(p.Frame({**base, "controller": {"serial": "x" * 500}}),
                               "agent").controller == {"serial": "x" * 200}
    for bad in ("IRC5", {"serial": 5}, {"password": "secret"}):
        with pytest.raises(ProtocolError, match="'controller' must be null or an object"):
            p.parse_hello_reply(p.Frame({**base, "controller": bad}), "agent")


def test_a_host_running_another_checkout_is_refused_at_hello_naming_it(tmp_path: Path
                                                                         ) -> None:
    """A host whose ``workdir`` is a checkout of another commit (this product's files,
    committed elsewhere): refused before any request, in one line that names it."""
    from drivers.host_fleet import HostFleet
    from testbed.core.types import Fault

    other = tmp_path / "other-checkout"
    for rel in product_files(ROOT):
        (other / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / rel, other / rel)
    git(other, "init", "-q")
    git(other, "add", "-A")
    git(other, "commit", "-qm", "elsewhere")
    theirs = checkout_build(other)
    assert theirs != build_id()
    host = local_host("cell0", physics=False, workdir=str(other))
    with HostFleet([host], reconnect_backoff_s=30.0) as fleet:
        status = fleet.host_status()["cell0"]
        assert not status.connected
        assert status.error == mismatch_line("cell0", theirs, build_id(), str(other))
        assert status.error.startswith(f"host cell0 runs build {theirs} from its checkout "
                                       f"{other}, this controller is build {build_id()}")
        # refused at hello: not a host of this run's code, so its build stays unknown
        assert fleet.hosts_info()["cell0"] == {"backend": "twin", "transport": "local",
                                               "build": None, "arms": ["left", "right"]}
        obs = fleet.observe()
        assert all(isinstance(o, Fault) and status.error in o.reason for o in obs.values())
