"""The house rules of docs/ARCHITECTURE.md, checked: rooms, arrows, names, sizes.

Why tests (besides ``lint-imports`` in scripts/test.sh): import-linter checks the
contracts in pyproject.toml, and a planted violation below proves it would catch one;
what a contract cannot say is checked here from the source itself: the arrows to
``drivers``, ``gui`` and ``sim_twin`` are lazy (inside functions), no import hides
behind ``importlib``, the rooms have no circle, no two product modules share a name,
no product function is over 80 lines, and what a robot host imports stays Python 3.10
code that needs only the host install.
"""

from __future__ import annotations

import ast
import os
import shutil
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("testbed", "drivers", "gui", "sim_twin")
OUTSIDE = ("drivers", "gui", "sim_twin")
"""What the core of testbed/ reaches only lazily: hosts, consoles, the twin."""
BIN = Path(sys.executable).parent


def _product_files() -> list[Path]:
    return sorted(p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py"))


def _module(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imported(node: ast.AST, here: str) -> list[str]:
    if isinstance(node, ast.Import):
        return [a.name for a in node.names]
    if isinstance(node, ast.ImportFrom):
        if node.level:
            base = here.split(".")[: len(here.split(".")) - node.level + 1]
            return [".".join([*base, node.module] if node.module else base)]
        return [node.module or ""]
    return []


def _module_level_imports(path: Path) -> list[tuple[int, str]]:
    """Imports run when the module is imported: not in a function, not TYPE_CHECKING."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    found: list[tuple[int, str]] = []

    def walk(body: list[ast.stmt]) -> None:
        for node in body:
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                continue
            if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
                walk(node.orelse)
                continue
            found.extend((node.lineno, m) for m in _imported(node, _module(path)))
            for field in ("body", "orelse", "finalbody", "handlers"):
                inner = getattr(node, field, None)
                if isinstance(inner, list):
                    walk([n for n in inner if isinstance(n, ast.stmt | ast.ExceptHandler)])

    walk(tree.body)
    return found


def _lint_imports(cwd: Path, env: dict[str, str] | None = None
                  ) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(BIN / "lint-imports"), "--no-cache"], cwd=cwd,
                          capture_output=True, text=True, timeout=300, env=env)


def test_the_import_contracts_hold() -> None:
    proc = _lint_imports(ROOT)
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-2000:]
    assert " 0 broken." in proc.stdout.split("Contracts:")[-1]


def test_the_import_contracts_catch_a_planted_violation(tmp_path: Path) -> None:
    """A copy of the tree with two planted arrows: the fleet loop importing the host
    fleet, and core importing the fleet room. lint-imports must name both contracts."""
    for pkg in PACKAGES:
        shutil.copytree(ROOT / pkg, tmp_path / pkg,
                        ignore=shutil.ignore_patterns("__pycache__", "static"))
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    loop = tmp_path / "testbed" / "fleet" / "loop.py"
    loop.write_text(loop.read_text() + "\nimport drivers.host_fleet  # planted\n")
    types = tmp_path / "testbed" / "core" / "types.py"
    types.write_text(types.read_text() + "\nimport testbed.fleet.loop  # planted\n")
    proc = _lint_imports(tmp_path, env={**os.environ, "PYTHONPATH": str(tmp_path)})
    assert proc.returncode != 0
    out = " ".join(proc.stdout.split())
    assert "testbed.fleet.loop -> drivers.host_fleet" in out
    assert "testbed.core.types -> testbed.fleet.loop" in out
    assert "testbed.core is not allowed to import testbed.fleet" in out  # the layers
    assert "testbed.fleet is not allowed to import drivers" in out  # the reach rule


def test_testbed_reaches_drivers_gui_and_the_twin_only_inside_functions() -> None:
    eager = [f"{p.relative_to(ROOT)}:{line} imports {m}"
             for p in _product_files() if p.relative_to(ROOT).parts[0] == "testbed"
             for line, m in _module_level_imports(p) if m.split(".")[0] in OUTSIDE]
    assert eager == []


def test_importing_all_of_testbed_loads_no_driver_console_or_twin() -> None:
    """The rule at run time: every module of testbed/ imported, nothing of the rooms
    that talk to the world comes with it (nor torch, for the rooms that must not)."""
    mods = [_module(p) for p in _product_files()
            if p.relative_to(ROOT).parts[0] == "testbed" and p.name != "__main__.py"]
    code = ("import importlib, sys, json\n"
            f"for m in {mods!r}: importlib.import_module(m)\n"
            "print(json.dumps(sorted({n.split('.')[0] for n in sys.modules})))")
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                          text=True, timeout=300, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert proc.returncode == 0, proc.stderr[-3000:]
    loaded = set(proc.stdout.split("\n")[-2].strip('[]').replace('"', "").split(", "))
    assert not loaded & set(OUTSIDE)


def test_no_import_hides_behind_importlib() -> None:
    hidden = []
    for p in _product_files():
        for node in ast.walk(ast.parse(p.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Call):
                name = ast.unparse(node.func)
                if name in ("importlib.import_module", "import_module", "__import__"):
                    hidden.append(f"{p.relative_to(ROOT)}:{node.lineno} {name}")
    assert hidden == []


def test_the_rooms_have_no_import_circle() -> None:
    """Every import (lazy and TYPE_CHECKING ones included) as an arrow between rooms
    (testbed's sub-packages, drivers, gui, sim_twin): the room graph is acyclic."""

    def room(module: str) -> str | None:
        parts = module.split(".")
        if parts[0] not in PACKAGES:
            return None
        return ".".join(parts[:2]) if parts[0] == "testbed" and len(parts) > 1 else parts[0]

    arrows: dict[str, set[str]] = defaultdict(set)
    for p in _product_files():
        here = room(_module(p))
        for node in ast.walk(ast.parse(p.read_text(encoding="utf-8"))):
            for m in _imported(node, _module(p)):
                there = room(m)
                if here and there and there != here and there != "testbed":
                    arrows[here].add(there)
    _assert_no_circle(arrows)


def test_no_module_imports_in_a_circle() -> None:
    """Between files too (issue 37): every import of a product module (lazy and
    TYPE_CHECKING ones included) as an arrow to the module it names; the graph is
    acyclic. A circle is named with its arrows."""
    modules = {_module(p): p for p in _product_files()}
    arrows: dict[str, set[str]] = defaultdict(set)
    for name, path in modules.items():
        for target in _all_imports(path):
            if target in modules and target != name and modules[target].name != "__init__.py":
                arrows[name].add(target)
    _assert_no_circle(arrows)


def _assert_no_circle(arrows: dict[str, set[str]]) -> None:
    """A depth-first walk of ``arrows``; an AssertionError naming the circle it meets."""
    state: dict[str, int] = {}

    def visit(node: str, path: list[str]) -> None:
        state[node] = 1
        for nxt in sorted(arrows[node]):
            if state.get(nxt) == 1:
                circle = [*path, node]
                raise AssertionError(" -> ".join([*circle[circle.index(nxt):], nxt]))
            if nxt not in state:
                visit(nxt, [*path, node])
        state[node] = 2

    for node in sorted(arrows):
        if node not in state:
            visit(node, [])


LONG = 450
"""A module longer than this says why at its top (issue 37)."""


def test_a_long_module_says_why_at_its_top() -> None:
    """Every product module over ``LONG`` lines has, in its docstring, a paragraph that
    starts "Over 450 lines, on purpose:" and gives the reason (what it keeps together,
    and where what could leave it went)."""
    silent = []
    for p in _product_files():
        if len(p.read_text(encoding="utf-8").splitlines()) <= LONG:
            continue
        doc = ast.get_docstring(ast.parse(p.read_text(encoding="utf-8"))) or ""
        why = doc.partition(f"Over {LONG} lines, on purpose:")[2].strip()
        if len(why) < 40:
            silent.append(str(p.relative_to(ROOT)))
    assert silent == []


def test_no_two_product_modules_share_a_name() -> None:
    allowed = {"__init__", "__main__", "errors"}
    names: dict[str, list[str]] = defaultdict(list)
    for p in _product_files():
        if p.stem not in allowed:
            names[p.stem].append(str(p.relative_to(ROOT)))
        if p.name == "__init__.py" and p.parent != ROOT / p.parent.name:
            names[p.parent.name].append(str(p.parent.relative_to(ROOT)) + "/")
    assert {k: v for k, v in names.items() if len(v) > 1} == {}


def test_no_product_function_is_over_80_lines() -> None:
    long = []
    for p in _product_files():
        for node in ast.walk(ast.parse(p.read_text(encoding="utf-8"))):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                n = (node.end_lineno or node.lineno) - node.lineno + 1
                where = (str(p.relative_to(ROOT)), node.name)
                if n > 80:
                    long.append(f"{where[0]}:{node.lineno} {node.name} ({n} lines)")
    assert long == []


def test_every_package_says_why_it_exists() -> None:
    silent = [str(p.relative_to(ROOT)) for p in _product_files() if p.name == "__init__.py"
              and ast.get_docstring(ast.parse(p.read_text(encoding="utf-8"))) is None]
    assert silent == []


def test_product_code_cites_only_files_that_exist() -> None:
    """Comments and docstrings cite the project's own files, never a design document
    that is not in the repository."""
    cited = [f"{p.relative_to(ROOT)}:{n}" for p in _product_files()
             for n, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1)
             if "DESIGN.md" in line or "../shared" in line]
    assert cited == []


HOST_ENTRY_POINTS = ("drivers.agent", "drivers.build_id", "drivers.backends")
"""What a robot host runs: ``python -m drivers.agent`` and its backends, and ``python -m
drivers.build_id`` (``scripts/setup.sh --host``); with every module of ``drivers.yumi``,
``testbed.core`` and ``testbed.perception`` (the host install's part of testbed)."""
HOST_PACKAGES = ("numpy", "cv2", "pydantic", "pydantic_core", "typing_extensions", "tomli",
                 "abb_robot_client", "abb_motion_program_exec")
"""What the host install provides besides the standard library (pyproject's base and
its extras headless and yumi; pydantic_core comes with pydantic, whose own version pins
it: the hosts' union of backend models builds its schema with it)."""
REMOVED_IN_3_12 = ("distutils", "imp", "asynchat", "asyncore", "smtpd")


def _module_file(module: str) -> Path | None:
    base = ROOT.joinpath(*module.split("."))
    for candidate in (base / "__init__.py", base.with_suffix(".py")):
        if candidate.is_file():
            return candidate
    return None


def _all_imports(path: Path) -> list[str]:
    """Every import of a file, lazy and TYPE_CHECKING ones included, with ``from X
    import y`` also as ``X.y`` (y may be a module)."""
    found: list[str] = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        for m in _imported(node, _module(path)):
            found.append(m)
            if isinstance(node, ast.ImportFrom):
                found.extend(f"{m}.{a.name}" for a in node.names)
    return found


def _host_modules() -> dict[str, Path]:
    """The modules a robot host imports: the entry points and every product module they
    import (lazily too), each module's packages included; not ``sim_twin``, which a
    twin backend imports only with the twin extra (an operator's Python 3.11)."""
    todo = [*HOST_ENTRY_POINTS,
            *(_module(p) for room in ("drivers/yumi", "testbed/core", "testbed/perception")
              for p in sorted((ROOT / room).glob("*.py")))]
    seen: dict[str, Path] = {}
    while todo:
        parts = todo.pop().split(".")
        for i in range(1, len(parts) + 1):
            name = ".".join(parts[:i])
            path = _module_file(name)
            if path is None or name in seen or parts[0] == "sim_twin":
                continue
            seen[name] = path
            todo.extend(m for m in _all_imports(path) if m.split(".")[0] in PACKAGES)
    return seen


def test_a_hosts_code_is_python_3_10_code() -> None:
    """A robot host runs Python 3.10-3.12 and only 3.11 exists here: every module it
    imports is checked statically (vermin: nothing newer than 3.10; nothing 3.12 removed)."""
    modules = _host_modules()
    assert {"drivers.agent", "drivers.wire", "drivers.yumi.backend", "drivers.cameras.camera",
            "testbed.core.config", "testbed.perception.cube"} <= set(modules)
    assert not {m for m in modules if m.startswith(("testbed.learning", "testbed.lab"))}
    proc = subprocess.run([str(BIN / "vermin"), "-t=3.10-", "--violations", "--no-tips",
                           "--eval-annotations", *sorted(map(str, set(modules.values())))],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout[-3000:]
    removed = [f"{m}: {i}" for m, p in modules.items() for i in _all_imports(p)
               if i.split(".")[0] in REMOVED_IN_3_12]
    assert removed == []


def test_a_hosts_code_needs_only_the_host_install() -> None:
    """What a host's modules import beyond the product is the standard library or the
    host install's packages: never torch, pybullet, kornia, matplotlib (the operator's)."""
    outside = {i.split(".")[0] for p in _host_modules().values() for i in _all_imports(p)
               if i and i.split(".")[0] not in PACKAGES}
    assert outside - set(sys.stdlib_module_names) - {"__future__"} <= set(HOST_PACKAGES)


def test_every_list_of_the_algorithms_is_the_registrys() -> None:
    """The algorithms have one home, ``testbed.fleet.algorithms.ALGORITHMS``; the
    ``--algorithm`` help, the README's list and ARCHITECTURE's comment name exactly its
    names (an algorithm added to the registry and forgotten in one of them fails here)."""
    import re

    from testbed.cli.arguments import ALGORITHM_HELP
    from testbed.fleet.algorithms import ALGORITHMS

    names = set(ALGORITHMS)
    help_names = set(re.findall(r"[a-z][a-z-]*", ALGORITHM_HELP.split("(")[0])) - {
        "and", "the", "ablations"}
    assert help_names == names, help_names ^ names
    readme = (ROOT / "README.md").read_text()
    listed = readme.partition("Algorithms (`--algorithm`):")[2].partition("\n\n")[0]
    assert set(re.findall(r"`([a-z][a-z-]*)`", listed)) == names
    arch = (ROOT / "docs" / "ARCHITECTURE.md").read_text()
    comment = arch.partition("ALGORITHMS: dict[str, ...]   #")[2].partition("\n")[0]
    shown = [n.strip() for n in comment.split(",") if n.strip() != "..."]
    assert shown and set(shown) <= names, set(shown) - names
