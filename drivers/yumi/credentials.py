"""The controller's RWS login, read from a file on the robot host.

Why a file: a password in argv is visible to every user of the host (``ps``), one in
config.toml travels with the protocol and the run records. The host config names the file
(``credentials_file``, a path on the host); only the agent reads it, on the host, and the
password goes nowhere but the controller's digest authentication. The file must be
readable by its owner alone (mode 0600 or 0400), as ssh insists for keys.

Format: one line ``USER:PASSWORD`` (the first ``:`` separates them; the password may hold
more). Blank lines and ``#`` comments are ignored.

There is no silent fallback to ABB's factory login (``Default User``): a host without a
``credentials_file`` is an error at the agent's start. ``credentials_file =
"factory-default"`` (:data:`FACTORY_DEFAULT`) asks for the factory login by name, and the
driver takes it only from a controller on this machine (a loopback URL: the hardware
twin), never from a lab's IRC5 (``drivers/yumi/rws_controller.py``).
"""

from __future__ import annotations

import os
import stat
from dataclasses import dataclass
from pathlib import Path

from drivers.errors import BackendError

FACTORY_USER, FACTORY_PASSWORD = "Default User", "robotics"
"""An IRC5's factory login (RWS Application manual's examples): for the twin only."""
FACTORY_DEFAULT = "factory-default"
"""The ``credentials_file`` value that names the factory login instead of a file; taken
only against a controller on this machine (the twin)."""


@dataclass(frozen=True, slots=True)
class RwsLogin:
    user: str
    password: str
    factory: bool = False
    """ABB's factory login, asked for by name (:data:`FACTORY_DEFAULT`): twin only."""

    def __repr__(self) -> str:  # never the password, whatever prints this
        return f"RwsLogin(user={self.user!r}, password=<hidden>)"


FACTORY_LOGIN = RwsLogin(FACTORY_USER, FACTORY_PASSWORD, factory=True)
"""The login :data:`FACTORY_DEFAULT` names (tests against the twin pass it directly)."""


def read_login(path: str | os.PathLike[str]) -> RwsLogin:
    """The login in ``path`` (:data:`FACTORY_LOGIN` for :data:`FACTORY_DEFAULT`); a
    :class:`BackendError` of one line when the file is missing, readable by others, or
    not ``USER:PASSWORD``."""
    if str(path) == FACTORY_DEFAULT:
        return FACTORY_LOGIN
    p = Path(path)
    try:
        st = p.stat()
        if not stat.S_ISREG(st.st_mode):
            raise BackendError(f"credentials_file {p}: not a regular file")
        if st.st_mode & 0o077:
            raise BackendError(f"credentials_file {p}: mode {stat.S_IMODE(st.st_mode):04o} "
                               f"lets other users read the controller's password; "
                               f"run: chmod 600 {p}")
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise BackendError(f"credentials_file {p}: cannot read it: "
                           f"{exc.strerror or exc}") from None
    lines = [s.strip() for s in text.splitlines() if s.strip() and not s.lstrip().startswith("#")]
    if len(lines) != 1 or ":" not in lines[0] or not lines[0].split(":", 1)[0]:
        raise BackendError(f"credentials_file {p}: expected one line USER:PASSWORD")
    user, password = lines[0].split(":", 1)
    return RwsLogin(user, password)
