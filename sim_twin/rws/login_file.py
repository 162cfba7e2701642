"""An extra RWS login for the twin, read from a file only its owner can read.

Why a file: the rehearsal gives the twin the same login it gives the agent (its
``credentials_file``), so a wrong password shows up as the controller's ``401``; on the
command line a password would be visible to every user of the machine (``ps``). The
format is the agent's (``drivers/yumi/credentials.py``): one line ``USER:PASSWORD`` (the
first ``:`` separates them; the password may hold more), blank lines and ``#`` comments
ignored, and the file must not be readable by group or others (mode 0600 or 0400), as
ssh insists for keys. No message here ever holds the password.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

__all__ = ["read_login_file"]


def read_login_file(path: str | os.PathLike[str]) -> tuple[str, str]:
    """``(user, password)`` from ``path``; a one-line ``ValueError`` when the file is
    missing, not a regular file, readable by others, or not ``USER:PASSWORD``."""
    p = Path(path)
    try:
        st = p.stat()
        if not stat.S_ISREG(st.st_mode):
            raise ValueError(f"--rws-credentials {p}: not a regular file")
        if st.st_mode & 0o077:
            raise ValueError(f"--rws-credentials {p}: mode {stat.S_IMODE(st.st_mode):04o} "
                             f"lets other users read the password; run: chmod 600 {p}")
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise ValueError(f"--rws-credentials {p}: cannot read it: "
                         f"{exc.strerror or exc}") from None
    except UnicodeDecodeError:
        raise ValueError(f"--rws-credentials {p}: not UTF-8 text") from None
    lines = [s.strip() for s in text.splitlines() if s.strip() and not s.lstrip().startswith("#")]
    if len(lines) != 1 or ":" not in lines[0] or not lines[0].split(":", 1)[0]:
        raise ValueError(f"--rws-credentials {p}: expected one line USER:PASSWORD")
    user, password = lines[0].split(":", 1)
    return user, password
