"""What a host install lacks, said in one line: the operator-only packages and the error.

Why: a robot host installs the project without the extra ``operator`` (docs/setup.md, "Two
installs": no torch, pybullet, kornia or matplotlib there), and the same package tree is
on its disk, so ``import testbed.learning`` or a ``testbed`` verb can still be tried
there. That must fail with one line that names the extra and says why, not with a bare
``No module named 'torch'`` from deep inside a traceback. The rooms that need the
operator's packages turn the ``ModuleNotFoundError`` of one of them into that
``ImportError`` with :func:`needs_operator` (its ``name``: the missing package, as
Python's own); ``testbed.cli`` prints it as its one line (exit 2).
"""

from __future__ import annotations

import importlib.util
from typing import Final

OPERATOR_EXTRA: Final = "operator"
OPERATOR_MODULES: Final = ("torch", "kornia", "pybullet", "matplotlib", "rich", "tomli_w",
                           "paramiko")
"""The top-level modules of pyproject's ``operator`` extra: a host install has none."""
INSTALL_OPERATOR: Final = f"pip install 'fleet-testbed[{OPERATOR_EXTRA}]'"


def missing_operator_module(exc: BaseException) -> str | None:
    """The operator package that ``exc`` failed to import and that is indeed not
    installed, else None (a broken install or another extra keeps its own message)."""
    if not isinstance(exc, ImportError) or not exc.name:
        return None
    top = exc.name.split(".")[0]
    if top not in OPERATOR_MODULES or importlib.util.find_spec(top) is not None:
        return None
    return top


def needs_operator(what: str, exc: ImportError) -> ImportError:
    """The error to raise for ``what`` (a module, a verb) when importing it failed with
    ``exc``: the one line naming the extra if an operator package is missing, else
    ``exc`` itself (raised as it was; also when it is that line already)."""
    missing = missing_operator_module(exc)
    if missing is None or not isinstance(exc, ModuleNotFoundError):
        return exc
    return ImportError(f"{what} needs the operator install: {INSTALL_OPERATOR} (this is a "
                       f"host install: {missing} is not installed)", name=missing)
