"""The web console's links, kept with the run so a resume gives every person the same one.

Why: the tokens in a person's link are credentials, so a run's ``config.toml`` is written
without them; before issue 44 a resumed run (``testbed trial --resume``, a protocol run
again after a crash) made new ones, and every link had to be sent again. Now the trial
keeps its tokens (every human's, the read-only overview's, the operator's) in
``web-links.json`` in the run's folder, mode 0600 (created so by ``testbed.core.atomic``:
only the operator's user reads it), and a resume reads them back. The tokens a process
makes are also kept for its later trials, so a protocol's trials share one set of links,
and a resumed run's become that set.
"""

from __future__ import annotations

import json
import secrets
from pathlib import Path
from typing import Final

from testbed.core.atomic import atomic_write_bytes
from testbed.people.people_config import WebConsoleConfig

__all__ = ["LINKS_FILE", "links_for_run"]

LINKS_FILE: Final = "web-links.json"
TOKEN_BYTES: Final = 24
_SESSION: dict[int, dict[str, object]] = {}
"""This process's tokens per number of humans (a protocol's trials share them)."""


def _made(count: int) -> dict[str, object]:
    if count not in _SESSION:
        _SESSION[count] = {"humans": [secrets.token_urlsafe(TOKEN_BYTES) for _ in range(count)],
                           "overview": secrets.token_urlsafe(TOKEN_BYTES),
                           "operator": secrets.token_urlsafe(TOKEN_BYTES)}
    return _SESSION[count]


def links_for_run(run_dir: Path, web: WebConsoleConfig, count: int) -> WebConsoleConfig:
    """``web`` with the run's tokens: those kept in its folder (a resume), else the
    config's own (kept there for a resume), else this process's random ones (kept
    likewise). A kept file for another number of humans is an error naming it."""
    path = run_dir / LINKS_FILE
    if path.exists():
        kept = json.loads(path.read_text(encoding="utf-8"))
        humans = [str(t) for t in kept["humans"]]
        if len(humans) != count:
            raise ValueError(f"{path}: {len(humans)} humans' links kept, the run has {count}; "
                             f"remove the file to make new links")
        _SESSION[count] = {"humans": humans, "overview": kept["overview"],
                           "operator": kept["operator"]}
    elif web.tokens:
        kept = {"humans": list(web.tokens), "overview": web.overview_token,
                "operator": web.operator_token}
        if kept["overview"] is None or kept["operator"] is None:
            made = _made(count)
            kept = {**kept, "overview": kept["overview"] or made["overview"],
                    "operator": kept["operator"] or made["operator"]}
    else:
        kept = dict(_made(count))
    run_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, (json.dumps(kept, indent=1) + "\n").encode("utf-8"))
    return web.model_copy(update={"tokens": list(kept["humans"]),  # type: ignore[call-overload]
                                  "overview_token": kept["overview"],
                                  "operator_token": kept["operator"]})
