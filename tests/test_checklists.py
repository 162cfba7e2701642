"""The cross-room checklists of docs/ARCHITECTURE.md stay true.

Why: a checklist that names a file or a function that moved sends the next engineer
looking in the wrong place, which is worse than none. Every ``path::name`` in the
section "Cross-room changes, as checklists" must name a file that exists and a
function, class, method or constant defined in it (read with ``ast``, nothing
imported). The behavioural side (a step field reaching every place, a backend added
with no change to the product) is tested where the behaviour lives; this test also
checks each checklist names such a test and that the test exists.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "ARCHITECTURE.md"
SECTION = "## Cross-room changes, as checklists"
REF = re.compile(r"`([\w./-]+\.py)::([\w.]+)`")


def checklists() -> dict[str, str]:
    """Each checklist's title and text (the ``###`` headings of the section)."""
    text = DOC.read_text(encoding="utf-8")
    assert SECTION in text, f"docs/ARCHITECTURE.md has no section {SECTION!r}"
    body = text.split(SECTION, 1)[1]
    body = re.split(r"^## ", body, maxsplit=1, flags=re.M)[0]
    parts = re.split(r"^### (.+)$", body, flags=re.M)
    return {parts[i].strip(): parts[i + 1] for i in range(1, len(parts) - 1, 2)}


def defined(path: Path) -> set[str]:
    """Top-level functions, classes and assigned names, and ``Class.method``."""
    names: set[str] = set()
    for node in ast.parse(path.read_text(encoding="utf-8")).body:
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            names.add(node.name)
        if isinstance(node, ast.ClassDef):
            names |= {f"{node.name}.{n.name}" for n in node.body
                      if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef)}
            names |= {f"{node.name}.{t.id}" for n in node.body
                      if isinstance(n, ast.AnnAssign | ast.Assign)
                      for t in (n.targets if isinstance(n, ast.Assign) else [n.target])
                      if isinstance(t, ast.Name)}
        elif isinstance(node, ast.Assign | ast.AnnAssign):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            names |= {t.id for t in targets if isinstance(t, ast.Name)}
    return names


def stale_refs(text: str) -> list[str]:
    stale = []
    for path, name in REF.findall(text):
        file = ROOT / path
        if not file.is_file():
            stale.append(f"{path}::{name}: no such file")
        elif name not in defined(file):
            stale.append(f"{path}::{name}: {name} is not defined in {path}")
    return stale


def test_the_checklists_exist_and_name_places() -> None:
    found = checklists()
    assert "A new host backend" in found
    for title, text in found.items():
        assert REF.search(text), f"checklist {title!r} names no path::name"


def test_no_checklist_row_is_stale() -> None:
    stale = {title: s for title, text in checklists().items() if (s := stale_refs(text))}
    assert stale == {}, "docs/ARCHITECTURE.md checklists name places that are gone"


def test_a_stale_row_is_caught() -> None:
    """The check itself: a renamed function and a moved file are reported."""
    text = ("`drivers/backends/plugin.py::BackendPlugin` "
            "`drivers/backends/plugin.py::agent_plugin_renamed` "
            "`drivers/gone.py::anything` `testbed/core/host_config.py::HostBase.arms`")
    assert stale_refs(text) == [
        "drivers/backends/plugin.py::agent_plugin_renamed: agent_plugin_renamed is not "
        "defined in drivers/backends/plugin.py",
        "drivers/gone.py::anything: no such file"]


def test_each_checklist_names_the_test_that_exercises_it() -> None:
    """A checklist is also proven by behaviour: it names a test, which exists."""
    for title, text in checklists().items():
        tests = [(p, n) for p, n in REF.findall(text) if p.startswith("tests/")]
        assert tests, f"checklist {title!r} names no test (tests/...py::test_...)"
        for path, name in tests:
            assert name.startswith("test_") and name in defined(ROOT / path), (title, name)
