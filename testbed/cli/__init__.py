"""The ``testbed`` command: the top of testbed, the one room that may import every other.

Every verb is one entry of ``testbed.cli.verbs.VERBS`` (its arguments and its handler
together, README "The verbs"); this module builds the parser from them and turns
their outcomes into exit statuses: 0 done, 1 the run failed (a fault the operator must
look at), 2 bad config or argument (one line naming the field and the fix, never a
traceback), 130 Ctrl-C.

The parser imports nothing heavy, so ``testbed --help`` is fast: torch, the hosts, cv2
and the console are imported by the handlers. gui is reached only lazily, to say a
console cannot open (``ConsoleUnavailable``); drivers and sim_twin never directly.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from typing import NoReturn

from testbed.cli.verbs import VERBS
from testbed.core.backend_registry import BackendError
from testbed.core.config import ConfigError
from testbed.core.extras import missing_operator_module, needs_operator
from testbed.core.interrupts import EXIT_INTERRUPTED, INTERRUPTS


class _Parser(argparse.ArgumentParser):
    """argparse, but a bad argument is one line and exit status 2."""

    def error(self, message: str) -> NoReturn:
        sys.stderr.write(f"{self.prog}: error: {message}; see {self.prog} --help\n")
        raise SystemExit(2)


def build_parser() -> argparse.ArgumentParser:
    """The ``testbed`` parser: one subparser per entry of ``VERBS``, in its order."""
    root = _Parser(prog="testbed", description="Fleet-DAgger testbed: a fleet of pushing arms, "
                   "remote humans, online behaviour cloning.")
    sub = root.add_subparsers(dest="verb", required=True, parser_class=_Parser)
    for verb in VERBS:
        verb.add_arguments(sub.add_parser(verb.name, help=verb.help,
                                          description=verb.description))
    return root


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    INTERRUPTS.install()
    from gui.errors import ConsoleUnavailable  # gui only now, once a verb runs

    run = next(v.run for v in VERBS if v.name == args.verb)
    try:
        return run(args)
    except (ConfigError, BackendError, ConsoleUnavailable) as exc:
        # BackendError: an unknown backend or a lab's plugin that does not load.
        # ConsoleUnavailable: a DISPLAY that is set but that no X server answers, found
        # only when the console opens its windows (its message is one line with the fix).
        sys.stderr.write(f"testbed {args.verb}: {exc}\n")
        return 2
    except ImportError as exc:
        if missing_operator_module(exc) is None:  # a bug, or another extra's own line
            raise
        # A robot host's install (no torch, pybullet, ...): what it lacks, in one line.
        sys.stderr.write(f"testbed {args.verb}: {needs_operator('this verb', exc)}\n")
        return 2
    except KeyboardInterrupt:
        sys.stderr.write("testbed: interrupted; arms at rest, records closed\n")
        return EXIT_INTERRUPTED


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
