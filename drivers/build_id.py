"""Which build of the project a process runs: the id an agent reports at hello.

Why: the controller and every host's agent must run the same code. The wire protocol's
version says only that the frames agree; a fix to the YuMi backend, the camera or
perception changes no frame, and a host still running the old one would act on it. A
build id names the code exactly, so ``drivers.link`` refuses a host whose agent runs
another build before any arm moves, and ``testbed deploy`` (``testbed.lab.deploy``)
puts this checkout's build on a host: a wheel stamped with the id.

The scheme, a PEP 440 version (so ``pip list`` on a host shows it too)::

    0.1.0+g<sha7>             a clean checkout at commit <sha7>
    0.1.0+g<sha7>.d<hash8>    plus uncommitted changes to the product (PRODUCT below):
                              hash8 starts the SHA-256 over each changed, added or
                              untracked (not ignored) file: its path, then its bytes
                              (a deleted file: its path and a marker)
    0.1.0+src.h<hash8>        a source tree git cannot read (a copy without .git, no
                              git): the SHA-256 over all its product files instead

Where a process finds its own id (:func:`build_id`, computed once per process;
:func:`matches` asks the tree once more when a host differs, see there):

* its ``drivers`` package sits in a source tree (a pyproject.toml beside it: the
  operator's machine, the tests, a host with ``workdir``: today's rehearsal): computed
  from that tree, by git when it is a checkout, the same way on both ends, so a host
  running the controller's own checkout matches (whatever metadata an editable install
  left on the path);
* else it is an installed distribution: the version pip installed, which
  :func:`stage` stamped into the wheel's metadata (no git, no checkout on the host). A
  plain ``pip install .`` is stamped ``0.1.0`` and so never matches: deploy it.

Standard library only: ``python -m drivers.build_id --wheel DIR`` builds the stamped
wheel (``scripts/setup.sh --host``) before anything else is installed.
"""

from __future__ import annotations

import argparse
import functools
import hashlib
import importlib.metadata
import importlib.util
import re
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Final

from drivers.errors import DriverError

ROOT: Final = Path(__file__).resolve().parent.parent
"""Where this ``drivers`` package sits: a checkout's root, or site-packages."""
DIST: Final = "fleet-testbed"
PRODUCT: Final = ("drivers", "gui", "sim_twin", "testbed", "pyproject.toml")
"""What a wheel is built from, so what a build id covers: a change to the tests, the
docs or a protocol file changes no host's code and no id."""
GIT_TIMEOUT_S: Final = 30.0
_VERSION_LINE = re.compile(r'^version\s*=\s*"([^"]+)"\s*$', re.MULTILINE)


class BuildIdError(RuntimeError):
    """git could not say what a checkout holds; ``str()`` is one line."""


class BuildMismatch(DriverError):
    """A host's agent runs another build than the controller: refused at hello, before
    any arm moves; ``str()`` is the one line that says how to fix it."""


def mismatch_line(host: str, theirs: str | None, ours: str, workdir: str | None) -> str:
    """The refusal: what the host runs, what we run, and the command that fixes it."""
    runs = theirs or "no build id (an agent from before build ids)"
    deploy = f"testbed deploy --config <this fleet's config> --host {host}"
    if workdir is not None:
        return (f"host {host} runs build {runs} from its checkout {workdir}, this "
                f"controller is build {ours}: bring that checkout to this build, or "
                f"remove workdir and run {deploy}")
    return f"host {host} runs build {runs}, this controller is build {ours}: run {deploy}"


# -- a checkout -----------------------------------------------------------------------
def is_checkout(root: Path) -> bool:
    """``root`` is a project checkout git may know (``.git`` is a folder or, in a
    worktree, a file) rather than an install's site-packages."""
    return (root / ".git").exists() and (root / "pyproject.toml").is_file()


def _git(root: Path, *args: str) -> bytes:
    """``git -C root ARGS``'s stdout; BuildIdError (one line) if git cannot answer."""
    try:
        proc = subprocess.run(["git", "-C", str(root), *args], capture_output=True,
                              stdin=subprocess.DEVNULL, timeout=GIT_TIMEOUT_S, check=False)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise BuildIdError(f"git {args[0]} in {root}: {exc}") from None
    if proc.returncode != 0:
        why = " ".join(proc.stderr.decode("utf-8", "replace").split())[:300]
        raise BuildIdError(f"git {args[0]} in {root} failed: {why}")
    return proc.stdout


def _paths(out: bytes) -> list[str]:
    """Paths of a ``-z`` listing (NUL-separated: any file name survives)."""
    return [p.decode("utf-8", "surrogateescape") for p in out.split(b"\0") if p]


def project_version(root: Path) -> str:
    """``[project] version`` of the tree's pyproject.toml: its first ``version = "..."``
    line, the one :func:`stage` stamps (read without tomllib or tomli, so this runs on
    a host's Python 3.10 before anything is installed)."""
    found = _VERSION_LINE.search((root / "pyproject.toml").read_text(encoding="utf-8"))
    if found is None:
        raise ValueError(f"{root / 'pyproject.toml'} has no version line")
    return found[1]


def product_files(root: Path) -> list[str]:
    """Every file a wheel of this checkout is built from: tracked or untracked but not
    ignored, under PRODUCT, present in the work tree (a deleted one is not built)."""
    out = _git(root, "ls-files", "-z", "--cached", "--others", "--exclude-standard", "--",
               *PRODUCT)
    return sorted({p for p in _paths(out) if (root / p).is_file()})


def changed_files(root: Path) -> list[str]:
    """The product's files that differ from the commit: changed, staged, deleted, added
    or untracked (not ignored)."""
    diff = _git(root, "diff", "--name-only", "--relative", "--no-renames", "-z", "HEAD",
                "--", *PRODUCT)
    new = _git(root, "ls-files", "-z", "--others", "--exclude-standard", "--", *PRODUCT)
    return sorted(set(_paths(diff)) | set(_paths(new)))


def changes_hash(root: Path, paths: Sequence[str]) -> str:
    """The first 8 hex digits of the SHA-256 over ``paths`` (sorted): each path, then
    its bytes with their length, or a marker for a file that is gone."""
    h = hashlib.sha256()
    for rel in sorted(paths):
        h.update(rel.encode("utf-8", "surrogateescape") + b"\0")
        path = root / rel
        if path.is_file():
            data = path.read_bytes()
            h.update(len(data).to_bytes(8, "big") + data)
        else:
            h.update(b"\xffdeleted")
    return h.hexdigest()[:8]


@dataclass(frozen=True, slots=True)
class Checkout:
    """What git says a checkout holds: the commit and the product's changed files."""

    commit: str
    """HEAD's full SHA-1 (40 hex digits)."""
    changed: tuple[str, ...]
    """:func:`changed_files`: empty when the product is exactly the commit's."""

    @property
    def dirty(self) -> bool:
        return bool(self.changed)


def checkout_state(root: Path) -> Checkout:
    """HEAD and the product's uncommitted changes, read once: what a build id is made
    of, and what a run's run.json says of its code (the one git reader of the project)."""
    sha = _git(root, "rev-parse", "--verify", "HEAD").decode().strip()
    return Checkout(sha, tuple(changed_files(root)))


def checkout_build(root: Path, state: Checkout | None = None) -> str:
    """The build id of a checkout (the scheme above); BuildIdError if git cannot tell.
    ``state``: the checkout as :func:`checkout_state` just read it (else read now)."""
    state = state if state is not None else checkout_state(root)
    label = f"g{state.commit[:7]}" + (
        f".d{changes_hash(root, state.changed)}" if state.changed else "")
    return f"{project_version(root)}+{label}"


# -- an install -----------------------------------------------------------------------
def installed_build() -> str:
    """The version of the installed distribution whose files are THIS ``drivers``
    package (another copy on the path says nothing about this one)."""
    for name in (DIST, DIST.replace("-", "_")):
        try:
            dist = importlib.metadata.distribution(name)
        except importlib.metadata.PackageNotFoundError:
            continue
        mine = Path(str(dist.locate_file("drivers/__init__.py")))
        if mine.resolve() == (ROOT / "drivers" / "__init__.py").resolve():
            return str(dist.version)
    return "unknown"


@dataclass(frozen=True, slots=True)
class SourceState:
    """Which code a process runs, as a reviewer asks it of a run (run.json ``code``)."""

    commit: str | None
    """The checkout's HEAD (40 hex digits); None: not a git checkout (an install, a
    copy without .git, or git could not tell)."""
    dirty: bool | None
    """The product (PRODUCT) had uncommitted changes; for an install, what its stamped
    id says (``.d<hash8>``); None where nothing can say (a tree without git, a wheel
    that was never stamped)."""
    build: str
    """The build id (the scheme above)."""


_STAMPED = re.compile(r"\+g[0-9a-f]{7}(\.d[0-9a-f]{8})?$")


def source_state(root: Path | None = None) -> SourceState:
    """The code of the tree ``root`` (default: this ``drivers`` package's, ROOT) now:
    commit, dirty and build id from ONE reading of git, so the three always agree.
    :func:`build_id` is this state's ``build``, computed once per process."""
    root = ROOT if root is None else root
    if not (root / "pyproject.toml").is_file():
        build = installed_build()
        stamped = _STAMPED.search(build)
        return SourceState(None, None if stamped is None else stamped[1] is not None, build)
    if is_checkout(root):
        try:
            state = checkout_state(root)
            return SourceState(state.commit, state.dirty, checkout_build(root, state))
        except (BuildIdError, OSError, ValueError) as exc:
            print(f"drivers.build_id: {exc}; the build is a hash of the files instead",
                  file=sys.stderr)
    return SourceState(None, None, tree_build(root))


@functools.lru_cache(maxsize=1)
def build_id() -> str:
    """This process's build id, computed once (git runs once per process)."""
    return source_state().build


def matches(theirs: str | None) -> bool:
    """Whether a host's build is this controller's: the build this process started
    with (cached), or, asked only when that one differs, what its own tree is now.

    Why the second: a file of this checkout saved since this process started changes
    the tree's id, and an agent started from this very tree (a local host, the
    rehearsal's workdir, the tests) runs that; the code is this checkout's either way.
    A deployed host runs a stamped wheel: it matches one of the two or it is refused."""
    if theirs is None:
        return False
    if theirs == build_id():
        return True
    now: str = build_id.__wrapped__()  # uncached: git once more, on a mismatch only
    return theirs == now


def tree_build(root: Path) -> str:
    """The id of a source tree without git: a hash of every product file in it (not
    caches: ``__pycache__``, ``*.pyc``), so two copies agree exactly when their files do."""
    files = [str(f.relative_to(root)) for top in PRODUCT for f in
             ((root / top).rglob("*") if (root / top).is_dir() else [root / top])
             if f.is_file() and "__pycache__" not in f.parts and f.suffix != ".pyc"]
    try:
        version = project_version(root)
    except (OSError, ValueError):
        version = "0"
    return f"{version}+src.h{changes_hash(root, files)}"


# -- the stamped wheel ----------------------------------------------------------------
def stage(root: Path, dest: Path, build: str | None = None) -> str:
    """Copy the product files of ``root`` into ``dest`` (a new folder), its
    pyproject's version replaced by the build id, so the wheel built from ``dest`` is
    stamped; returns the id. ``build``: stamp this id instead (a test's other build)."""
    build = build or checkout_build(root)
    for rel in product_files(root):
        target = dest / rel
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(root / rel, target)
    pyproject = dest / "pyproject.toml"
    text, n = _VERSION_LINE.subn(f'version = "{build}"', pyproject.read_text("utf-8"),
                                 count=1)
    if n != 1:
        raise BuildIdError(f"{root / 'pyproject.toml'} has no version line to stamp")
    pyproject.write_text(text, encoding="utf-8")
    return build


def _can_build_offline() -> bool:
    """This interpreter's setuptools builds wheels itself (bdist_wheel is built in
    since 70.1): no build environment to download."""
    if importlib.util.find_spec("setuptools") is None:
        return False
    found = re.match(r"(\d+)\.(\d+)", importlib.metadata.version("setuptools"))
    return found is not None and (int(found[1]), int(found[2])) >= (70, 1)


def build_wheel(root: Path, out: Path, build: str | None = None) -> Path:
    """The stamped wheel of ``root``, moved into ``out``: staged and built in a
    temporary folder (never in the checkout: no build/ left there, no stale file of an
    earlier build carried along), by pip with this interpreter's setuptools when it can
    (offline), else in pip's own build environment."""
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="fleet-wheel-") as tmp:
        src, dist = Path(tmp) / "src", Path(tmp) / "dist"
        build = stage(root, src, build)
        isolation = ["--no-build-isolation"] if _can_build_offline() else []
        proc = subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps",
                               "--disable-pip-version-check", *isolation, "-w", str(dist),
                               str(src)], capture_output=True, text=True,
                              stdin=subprocess.DEVNULL, check=False)
        if proc.returncode != 0:
            tail = " ".join((proc.stderr or proc.stdout).split())[-600:]
            raise BuildIdError(f"pip wheel of {root} failed: {tail}")
        wheels = sorted(dist.glob("fleet_testbed-*.whl"))
        if len(wheels) != 1:
            raise BuildIdError(f"pip wheel of {root} made {len(wheels)} wheels, not one")
        target = out / wheels[0].name
        shutil.move(str(wheels[0]), target)
    return target


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m drivers.build_id``: print this checkout's build id; with ``--wheel
    DIR``, build its stamped wheel there and print the wheel's path."""
    ap = argparse.ArgumentParser(prog="python -m drivers.build_id",
                                 description="This checkout's build id, or its stamped wheel.")
    ap.add_argument("--wheel", metavar="DIR", help="build the stamped wheel into DIR")
    ap.add_argument("--root", default=str(ROOT), help="the checkout (default: this one)")
    args = ap.parse_args(argv)
    root = Path(args.root).resolve()
    try:
        if args.wheel is None:
            print(checkout_build(root) if is_checkout(root) else build_id())
        else:
            print(build_wheel(root, Path(args.wheel).resolve()))
    except BuildIdError as exc:
        print(f"drivers.build_id: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
