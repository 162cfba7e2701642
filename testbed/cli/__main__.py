"""``python -m testbed.cli``: the ``testbed`` command (what hosts and tests run)."""

from testbed.cli import main

raise SystemExit(main())
