"""The report a reviewer reads: intervals and paired comparisons over a protocol's
trials, identical records flagged, a sweep in its grid's order, and report.html opened
in Debian's headless Chromium: every table and the figure there, no request made."""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

import pytest

from testbed.records.steps import RunWriter
from testbed.results.report import write_report

A, T, R = "autonomous", "teleop", "reset"
PASSWORD = "hunter2-never-in-a-report"


def _run(folder: Path, algorithm: str, pattern: list[list[tuple[str, bool]]],
         meta: dict[str, Any], people: tuple[str, ...] = ("ana", "bo"),
         key: tuple[float, ...] = (0.0,)) -> None:
    """Each step: one (mode, success) per arm; humans by arm index."""
    folder.mkdir(parents=True)
    with RunWriter(folder) as w:
        for t, arms in enumerate(pattern):
            w.write_step({"t": t, "robots": [{
                "robot": f"h/{i}", "mode": mode,
                "human": i if mode in (T, R) else None,
                "action": 1 if mode in (T, A) else None,
                "success": ok, "violation": False, "uncertainty": 0.1, "risk": 0.0,
                "key": list(key), **({"served": 0} if mode in (T, R) else {})}
                for i, (mode, ok) in enumerate(arms)]})
    (folder / "run.json").write_text(json.dumps(
        {"options": {"algorithm": algorithm, "seed": 0, "steps": len(pattern)},
         "status": "complete", **meta}))
    names = "".join(f'[[humans.people]]\nname = "{n}"\n' for n in people)
    (folder / "config.toml").write_text(f"[humans]\ncount = {len(people)}\n{names}"
                                        "[algorithm]\nt_T = 3\nt_R = 5\nt_I = 10\n"
                                        'u_hat = 0.041\nr_hat = 0.5\n')


def _protocol(root: Path) -> None:
    """3 trials x {cur, fleet-ed, random}: fleet-ed = cur + 1 success per trial,
    random identical to cur step for step."""
    for k in range(3):
        order = ["cur", "fleet-ed", "random"][k:] + ["cur", "fleet-ed", "random"][:k]
        base = [[(T, j < k + 1), (A, j == 0)] for j in range(4)]
        for alg in ("cur", "fleet-ed", "random"):
            pattern = [list(s) for s in base]
            if alg == "fleet-ed":
                pattern[3][1] = (A, True)
            meta = {"protocol": {"name": "p", "trial": k, "position": order.index(alg),
                                 "order": order},
                    "code": {"commit": "ab" * 20, "dirty": False, "build": "0.1.0+gabababa"},
                    "numerics": {"torch": "2.13.0+cpu", "threads": 2, "device": "cpu"},
                    "hosts": {"yumi0": {"backend": "yumi", "transport": "ssh",
                                        "build": "0.1.0+gabababa",
                                        "password": PASSWORD,
                                        "controller": {"robotware": "6.15.02",
                                                       "serial": "14000-501234"}}}}
            # random's keys have another shape: what it did is what counts
            _run(root / f"{alg}-t{k}", alg, pattern, meta,
                 key=(0.5, 0.1) if alg == "random" else (0.0,))


def test_intervals_pairs_and_identical_records_over_three_trials(tmp_path: Path) -> None:
    _protocol(tmp_path)
    rep = write_report([tmp_path], tmp_path / "rep")
    tables = {t.key: t for t in rep.tables}
    assert {"learning", "learning-intervals", "learning-paired", "rohe", "humans"} <= set(
        tables)
    # cur's successes per trial: 1, 2, 3 by teleop + 1 autonomous = 2, 3, 4; by hand:
    # mean 3, sd 1, 3 +- t(0.975, 2) / sqrt(3) = 3 +- 2.484
    row = next(r for r in tables["learning-intervals"].rows if r[0] == "cur")
    assert row[2] == "3.0 [0.5, 5.5]"
    paired = {(r[0], r[1]): r for r in tables["learning-paired"].rows}
    fe = paired[("fleet-ed", "successes")]
    assert fe[2] == "t0: +1.0, t1: +1.0, t2: +1.0"
    assert (fe[3], fe[4], fe[5], fe[6]) == ("+1.0", "[1.0, 1.0]", "0.250", "3")
    rnd = paired[("random", "successes")]
    assert (rnd[3], rnd[5]) == ("+0.0", "1.000")
    flags = [n for n in tables["learning-intervals"].notes if n.startswith("IDENTICAL")]
    assert len(flags) == 1 and "cur and random" in flags[0]
    assert "smallest possible value is 2 / 2^n (3 pairs: 0.25)" in tables[
        "learning-paired"].notes[0]
    humans = {(r[0], r[1]): r for r in tables["humans"].rows}
    assert humans[("cur", "ana")][2] == "12"  # a teleop started every step, 3 trials
    assert ("cur", "bo") in humans
    with (tmp_path / "rep" / "report-learning-paired.csv").open() as f:
        got = {(r["algorithm"], r["metric"]): r for r in csv.DictReader(f)}
    assert float(got[("fleet-ed", "successes")]["p_value"]) == 0.25


def test_a_trial_missing_a_run_is_left_out_of_its_pairs_and_named(tmp_path: Path) -> None:
    _protocol(tmp_path)
    meta = json.loads((tmp_path / "fleet-ed-t2" / "run.json").read_text())
    meta["status"] = "running"
    (tmp_path / "fleet-ed-t2" / "run.json").write_text(json.dumps(meta))
    tables = {t.key: t for t in write_report([tmp_path], tmp_path / "rep").tables}
    fe = next(r for r in tables["learning-paired"].rows if r[:2] == ["fleet-ed", "successes"])
    assert fe[6] == "2"
    assert any("fleet-ed: t2 has a finished run of only one" in n
               for n in tables["learning-paired"].notes)


def test_a_sweep_in_its_grids_order_with_numbers_as_numbers(tmp_path: Path) -> None:
    for index, t_r in enumerate([1, 3, 5, 10, 20]):
        for seed in (0, 1):
            pattern = [[(T, j < index % 3 + seed)] for j in range(3)]
            _run(tmp_path / f"algorithm.t_R-{t_r}-s{seed}", "cur", pattern,
                 {"sweep": {"name": "t_R", "point": f"algorithm.t_R-{t_r}", "index": index,
                            "values": {"algorithm.t_R": t_r}, "seed": seed}}, ("ana",))
    rep = write_report([tmp_path], tmp_path / "rep")
    first = rep.tables[0]
    assert [r[0] for r in first.rows] == [f"algorithm.t_R-{v}" for v in (1, 3, 5, 10, 20)]
    with (tmp_path / "rep" / "report.csv").open() as f:
        rows = list(csv.reader(f))
    assert rows[0][:3] == ["point", "algorithm.t_R", "trials"]
    assert [int(r[1]) for r in rows[1:]] == [1, 3, 5, 10, 20]
    paired = next(t for t in rep.tables if t.key == "learning-paired")
    assert paired.title.startswith("Paired against algorithm.t_R-1")
    flags = [n for n in rep.tables[1].notes if n.startswith("IDENTICAL")]
    assert any("algorithm.t_R-1 and algorithm.t_R-10" in f for f in flags)  # same pattern


@pytest.mark.browser
def test_report_html_in_chromium_has_every_table_and_makes_no_request(
        tmp_path: Path) -> None:
    from selenium.webdriver.common.by import By

    from gui.web.browser import browser_missing, chromium

    if browser_missing():
        pytest.fail(f"missing {browser_missing()}: scripts/setup.sh --dev installs them")
    _protocol(tmp_path)
    rep = write_report([tmp_path], tmp_path / "rep")
    page = tmp_path / "rep" / "report.html"
    text = page.read_text()
    assert PASSWORD not in text and "http://" not in text and "https://" not in text
    with chromium(1300, 2400) as driver:
        driver.get(page.as_uri())
        for t in rep.tables:
            section = driver.find_element(By.ID, t.key)
            assert len(section.find_elements(By.CSS_SELECTOR, "tbody tr")) == len(t.rows)
        img = driver.find_element(By.CSS_SELECTOR, "#curves img")
        assert driver.execute_script("return arguments[0].naturalWidth", img) > 500
        meta = driver.find_element(By.ID, "metadata").text
        assert "14000-501234" in meta and "6.15.02" in meta and "ab" * 20 in meta
        assert "cur, fleet-ed, random" in meta  # trial 0's order
        assert driver.execute_script(
            "return performance.getEntriesByType('resource').length") == 0
        csp = driver.find_element(By.CSS_SELECTOR, "meta[http-equiv]").get_attribute("content")
        assert csp.startswith("default-src 'none'")


def test_records_the_same_in_some_trials_only_are_named_with_those_trials() -> None:
    from testbed.results.report import trial_label
    from testbed.results.report_tables import identical_groups

    lines = identical_groups({"cur": {("seed", 0): "a", ("seed", 1): "b"},
                              "cur-i": {("seed", 0): "c", ("seed", 1): "b"},
                              "r": {("seed", 0): "x", ("seed", 1): "y"},
                              "cr": {("seed", 0): "x", ("seed", 1): "y"}}, trial_label)
    assert lines[0].startswith("Same records in part: cur and cur-i")
    assert "1 of their 2 shared trials (seed 1)" in lines[0]
    assert lines[1].startswith("IDENTICAL RECORDS: r and cr") and len(lines) == 2
