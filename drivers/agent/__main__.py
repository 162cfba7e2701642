"""``python -m drivers.agent``: the host agent (``drivers/agent/__init__.py``)."""

from __future__ import annotations

import sys

from drivers.agent.agent_cli import main

sys.exit(main())
