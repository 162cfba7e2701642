"""The port a twin server listens on, written for the process that started it.

Why a module: both twin servers (``sim_twin.yumi_server`` and ``python -m sim_twin.rws``)
listen on port 0 and tell their parent which port they got through ``--port-file``;
the parent polls for the file, so it must never see half of one.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

__all__ = ["write_port"]


def write_port(path: Path, port: int) -> None:
    """Atomically: a reader never sees a half-written port."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name + ".")
    with os.fdopen(fd, "w") as f:
        f.write(f"{port}\n")
    os.replace(tmp, path)
