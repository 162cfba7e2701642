"""Docs that cannot drift (issue 37, item 4): every file, ``file.py::name`` and
``testbed`` command the README and the docs name exists.

What counts as named: a backticked span. A path with a folder must be a file the
repository tracks (from the project's root, the doc's own folder, or any tracked path
that ends with it); a bare file name must be a tracked file's name, or a file the
program writes (its name is a string in the product code, or one of ``GENERATED``);
``file.py::name`` (and ``file.py::Class.attr``) must be defined at that level of that
file; ``testbed VERB --flag`` must be a verb of ``testbed.cli.verbs.VERBS`` and a flag of
that verb. A note about the project's past that names a file since removed says so with
"(removed)" after the name.
"""

from __future__ import annotations

import argparse
import ast
import re
import subprocess
from functools import cache
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md")),
        *sorted(ROOT.glob("*/README.md"))]
NAMED = re.compile(r"`([A-Za-z0-9_./-]+\.(?:py|md|toml|sh|jsonl|json|txt|html|csv|npz|pt|png|"
                   r"log|pem|mod|sys|cfg))(?:::([A-Za-z0-9_.]+))?`(?!\s*\(removed\))")
COMMAND = re.compile(r"`(testbed [^`]+)`")
GENERATED = re.compile(r"^(report-[a-z-]+\.csv|learner-[0-9]+\.pt|frames-[0-9]+\.bin|"
                       r"[a-z0-9-]+\.rws\.jsonl|dryrun\.toml)$")
"""Files the program writes under names made at run time (f-strings), and the one a
guide has the reader write (robot/README.md's ``dryrun.toml``)."""


@cache
def _tracked() -> dict[str, list[Path]]:
    out: dict[str, list[Path]] = {}
    listed = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True,
                            check=True).stdout.split()
    for rel in listed:
        out.setdefault(Path(rel).name, []).append(ROOT / rel)
    return out


@cache
def _product_strings() -> frozenset[str]:
    """Every string constant of the product code: the names of the files it writes."""
    found: set[str] = set()
    for pkg in ("testbed", "drivers", "gui", "sim_twin"):
        for p in (ROOT / pkg).rglob("*.py"):
            for node in ast.walk(ast.parse(p.read_text(encoding="utf-8"))):
                if isinstance(node, ast.Constant) and isinstance(node.value, str):
                    found.add(node.value)
    return frozenset(found)


def _files(path: str, doc: Path) -> list[Path]:
    if "/" in path:
        direct = [c for c in (ROOT / path, doc.parent / path) if c.is_file()]
        return direct or [p for p in _tracked().get(Path(path).name, [])
                          if p.as_posix().endswith("/" + path)]
    return _tracked().get(path, [])


def _defines(path: Path, dotted: str) -> bool:
    body: list[ast.stmt] = ast.parse(path.read_text(encoding="utf-8")).body
    for part in dotted.split("."):
        found: ast.stmt | None = None
        for node in body:
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
                names = [node.name]
            elif isinstance(node, ast.Assign):
                names = [t.id for t in node.targets if isinstance(t, ast.Name)]
            elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
                names = [node.target.id]
            elif isinstance(node, ast.Import | ast.ImportFrom):
                names = [(a.asname or a.name).split(".")[0] for a in node.names]
            else:
                continue
            if part in names:
                found = node
        if found is None:
            return False
        body = getattr(found, "body", [])
    return True


def _named() -> list[tuple[Path, str, str | None]]:
    return [(doc, m.group(1), m.group(2)) for doc in DOCS
            for m in NAMED.finditer(doc.read_text(encoding="utf-8"))]


def test_every_file_the_docs_name_exists() -> None:
    missing = []
    for doc, path, _ in _named():
        if _files(path, doc):
            continue
        name = Path(path).name
        if name in _product_strings() or path in _product_strings() or GENERATED.match(name):
            continue  # a file the program writes (a run's, a report's, the lab's)
        missing.append(f"{doc.relative_to(ROOT)}: {path}")
    assert missing == []


def test_every_name_the_docs_cite_in_a_file_is_defined_there() -> None:
    undefined = []
    for doc, path, name in _named():
        if name is None or not path.endswith(".py"):
            continue
        files = [f for f in _files(path, doc) if f.suffix == ".py"]
        if not any(_defines(f, name) for f in files):
            undefined.append(f"{doc.relative_to(ROOT)}: {path}::{name}")
    assert undefined == []


def _subparsers() -> dict[str, argparse.ArgumentParser]:
    from testbed.cli import build_parser

    parser = build_parser()
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


def test_every_testbed_command_the_docs_show_exists() -> None:
    verbs = _subparsers()
    wrong = []
    for doc in DOCS:
        for m in COMMAND.finditer(doc.read_text(encoding="utf-8")):
            words = m.group(1).split()
            if len(words) < 2 or words[1].startswith(("-", "<", "[")) or words[1] == "...":
                continue
            verb = verbs.get(words[1])
            if verb is None:
                wrong.append(f"{doc.relative_to(ROOT)}: {m.group(1)} (no verb {words[1]})")
                continue
            flags = {s for a in verb._actions for s in a.option_strings}
            for w in words[2:]:
                flag = w.split("=")[0].rstrip(",.;:)")
                if flag.startswith("--") and flag not in flags and flag != "--help":
                    wrong.append(f"{doc.relative_to(ROOT)}: {m.group(1)} (no {flag})")
    assert wrong == []


def test_the_suites_durations_name_only_test_files_that_exist() -> None:
    """``tests/durations.json`` orders the suite (tests/conftest.py): a file renamed or
    removed must leave it, or its weight moves to nothing and the order silently decays."""
    import json

    weights = json.loads((ROOT / "tests" / "durations.json").read_text())
    assert weights and all(isinstance(s, int | float) and s >= 0 for s in weights.values())
    missing = [f for f in weights if not (ROOT / f).is_file()]
    assert not missing, f"tests/durations.json names files that do not exist: {missing}"
