"""The whole suite's one rule across test processes: a test marked ``alone`` runs with no
other test beside it.

Why: the suite runs on pytest-xdist workers (``scripts/test.sh``, docs/notes/tests.md),
two tests at a time on a 2-core machine. Most tests only share the CPUs and take longer
when they do; a few measure the wall clock as the product promises it (a motion stopped
within 1.5 s of a lost link, a camera frame taken after the push returned, heartbeats
answered during a push, perception agreeing with the truth at the frame rate), and a
neighbour's training makes them miss a bound the product keeps on a machine of its own.
Those are marked ``alone``: before one starts, the other workers finish the test they
are in and wait; every other test runs beside any other.

How: a readers-writer lock over two files every worker of a run shares (named by
xdist's ``PYTEST_XDIST_TESTRUNUID``): a test takes the main lock shared, an ``alone``
test exclusive; both pass a turnstile first, which an ``alone`` test holds until it is
done, so a waiting ``alone`` test is not starved by its neighbour's next tests. Without
xdist (one process) nothing is locked.

The heaviest files go first (``tests/durations.json``: each file's seconds, measured on
this machine; ``TESTBED_RECORD_DURATIONS=1`` writes it again at the end of a run): xdist
hands files out in the collection's order, and by default it puts the files with the
most tests first, which left the few-test, minutes-long files (the rehearsals, the
critics' training, the Ray fan-outs) for the end, one worker on each while the other had
nothing left (measured: the last 7 min of a 19-min run). The files with an ``alone``
test come last, heaviest first: an ``alone`` test waits for its neighbour's test to end,
which among the last files is a short one (one early waited 125 s beside a rehearsal).
A file not listed weighs nothing; the order only changes when tests run, never what they
check.

And the CPUs are shared out: a worker's torch (and every trial it starts in a
subprocess) takes ``cores / workers`` threads (``TESTBED_THREADS``, as a Ray worker's
trial does: ``testbed/learning/runtime.py::configure_torch``) instead of every core, so
two workers' training does not oversubscribe the cores (measured: the critics'
acceptance training took 272 s beside another worker's at two threads each, 85 s alone).
"""

from __future__ import annotations

import fcntl
import json
import os
import tempfile
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest


def _lock_files() -> tuple[Path, Path] | None:
    run = os.environ.get("PYTEST_XDIST_TESTRUNUID")
    if not run or not os.environ.get("PYTEST_XDIST_WORKER"):
        return None
    base = Path(tempfile.gettempdir()) / f"testbed-tests-{run}"
    return base.with_suffix(".turnstile"), base.with_suffix(".lock")


@contextmanager
def _turn(alone: bool) -> Iterator[None]:
    files = _lock_files()
    if files is None:
        yield
        return
    with open(files[0], "a") as turnstile, open(files[1], "a") as main:
        fcntl.flock(turnstile, fcntl.LOCK_EX)
        try:
            fcntl.flock(main, fcntl.LOCK_EX if alone else fcntl.LOCK_SH)
        finally:
            if not alone:
                fcntl.flock(turnstile, fcntl.LOCK_UN)
        try:
            yield
        finally:
            fcntl.flock(main, fcntl.LOCK_UN)
            if alone:
                fcntl.flock(turnstile, fcntl.LOCK_UN)


DURATIONS = Path(__file__).with_name("durations.json")
"""Each test file's seconds (setup, call and teardown of its tests) in a whole run."""
_seconds: Counter[str] = Counter()


def _file_of(nodeid: str) -> str:
    return nodeid.split("::", 1)[0]


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The heaviest files first, and the files with an ``alone`` test after all others
    (see the module's docstring); a stable sort, the same on every worker (xdist checks
    that they collected the same list). Not under mutmut (``MUTANT_UNDER_TEST`` set in
    each mutant's run): it lists a mutant's tests fastest first so that ``-x`` stops at
    the first quick kill; heaviest files first would run a slow sweep before every kill
    (scripts/mutation.sh, docs/notes/tests.md)."""
    if os.environ.get("MUTANT_UNDER_TEST"):
        return
    weight = json.loads(DURATIONS.read_text()) if DURATIONS.exists() else {}
    alone = {_file_of(i.nodeid) for i in items if i.get_closest_marker("alone") is not None}
    items.sort(key=lambda item: (_file_of(item.nodeid) in alone,
                                 -float(weight.get(_file_of(item.nodeid), 0.0))))


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    if os.environ.get("TESTBED_RECORD_DURATIONS") and not os.environ.get("PYTEST_XDIST_WORKER"):
        _seconds[_file_of(report.nodeid)] += report.duration


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    """The files this run measured replace their old figures (a run of a few files
    keeps every other file's)."""
    if _seconds and not os.environ.get("PYTEST_XDIST_WORKER"):
        weight = json.loads(DURATIONS.read_text()) if DURATIONS.exists() else {}
        weight.update({f: round(s, 1) for f, s in _seconds.items()})
        DURATIONS.write_text(json.dumps({f: s for f, s in sorted(weight.items()) if s >= 1.0},
                                        indent=1) + "\n")


def pytest_configure(config: pytest.Config) -> None:
    if hasattr(config.option, "loadscopereorder"):  # xdist: keep the order made above
        config.option.loadscopereorder = False
    workers = os.environ.get("PYTEST_XDIST_WORKER_COUNT", "")
    if os.environ.get("PYTEST_XDIST_WORKER") and workers.isdigit():
        cores = len(os.sched_getaffinity(0))
        os.environ.setdefault("TESTBED_THREADS", str(max(1, cores // int(workers))))


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None
                            ) -> Iterator[None]:
    with _turn(item.get_closest_marker("alone") is not None):
        yield
