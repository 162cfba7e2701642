"""The report's ROHE with its parts (issue 12, item 6): successes split by who pushed,
and where an algorithm is not below C.U.R. by ROHE, the paragraph names the part that
decides it, from the records."""

from __future__ import annotations

import json
from pathlib import Path

from testbed.records.steps import RunWriter
from testbed.results.report import write_report


def _run(folder: Path, algorithm: str, steps: list[list[tuple[str, bool, bool]]]) -> None:
    """Each step: one (mode, success, violation) per arm."""
    folder.mkdir(parents=True)
    with RunWriter(folder) as w:
        for t, arms in enumerate(steps):
            w.write_step({"t": t, "robots": [{
                "robot": f"h/{i}", "mode": mode,
                "human": 0 if mode in ("teleop", "reset") else None,
                "action": 1 if mode in ("teleop", "autonomous") else None,
                "success": ok, "violation": bad, "uncertainty": 0.1, "risk": 0.0,
                "key": [0.0]} for i, (mode, ok, bad) in enumerate(arms)]})
    (folder / "run.json").write_text(json.dumps({"options": {"algorithm": algorithm},
                                                 "status": "complete"}))


A, T, R = "autonomous", "teleop", "reset"


def test_an_algorithm_above_cur_gets_a_paragraph_naming_the_deciding_part(
        tmp_path: Path) -> None:
    # C.U.R.: 4 successes (2 by the policy, 2 by teleop) for 5 human actions
    _run(tmp_path / "cur-t0", "cur", [[(T, True, False), (A, True, False)],
                                      [(T, True, False), (A, True, False)],
                                      [(T, False, False), (R, False, False)],
                                      [(T, False, False), (A, False, False)]])
    # BC: 2 successes, no human at all, one violation in 8 pushes
    _run(tmp_path / "bc-t0", "bc", [[(A, True, False), (A, False, True)],
                                    [(A, True, False), (A, False, False)],
                                    [(A, False, False), (A, False, False)],
                                    [(A, False, False), (A, False, False)]])
    md = write_report([tmp_path], tmp_path).markdown
    assert "ROHE and its parts" in md
    rohe = md[md.index("ROHE and its parts"):]
    rows = {line.split(" | ")[0].strip("| "): line
            for line in rohe[:rohe.index("\n\n", rohe.index("|"))].splitlines()
            if line.startswith(("| cur |", "| bc |"))}
    # ROHE = (M/N) * successes / (1 + human actions), M = 2 (default), N = 2
    assert "| 0.6667 | 4.0 (2.0 + 2.0) | 5.0 | 0.667 | 0.000 | 0.500 |" in rows["cur"]
    assert "| 2.0000 | 2.0 (2.0 + 0.0) | 0.0 | 0.250 | 0.125 | 0.000 |" in rows["bc"]
    paragraph = next(p for p in md.split("\n\n") if p.startswith("bc is not below"))
    assert "successes are 0.50x C.U.R.'s" in paragraph
    assert "a factor 6.00 in its favour" in paragraph and "human actions decide it" in paragraph
    assert "policy succeeds 0.250 and violates 0.125 (C.U.R.'s 0.667 and 0.000)" in paragraph
    assert "cur is not below" not in md


def test_no_paragraph_when_cur_leads(tmp_path: Path) -> None:
    _run(tmp_path / "cur-t0", "cur", [[(A, True, False)], [(A, True, False)]])
    _run(tmp_path / "random-t0", "random", [[(T, True, False)], [(A, False, False)]])
    md = write_report([tmp_path], tmp_path).markdown
    assert "ROHE and its parts" in md and "is not below C.U.R." not in md
