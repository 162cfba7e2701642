"""The web console's links, kept with the run so a resume gives every person the same one.

Why: the tokens in a person's link are credentials, so a run's ``config.toml`` is written
without them; before issue 44 a resumed run (``testbed trial --resume``, a protocol run
again after a crash) made new ones, and every link had to be sent again. Now the trial
keeps its tokens (every human's, the read-only overview's, the operator's) in
``web-links.json`` in the run's folder, mode 0600 (created so by ``testbed.core.atomic``:
only the operator's user reads it), and a resume reads them back. The tokens a process
makes are also kept for its later trials, so a protocol's trials share one set of links,
and a resumed run's become that set. And across processes: the first command that opens
the console for a folder of runs (``testbed collect``/``pretrain`` into its cache, a
trial, a protocol) keeps its tokens in ``web-links.json`` of that folder (0600, the same
format), and every later one of that folder reads them back, so a day of collect,
pretrain and protocol hands each colleague one link. A config's own ``tokens`` still win.
"""

from __future__ import annotations

import json
import secrets
from pathlib import Path
from typing import Final, TypedDict

from testbed.core.atomic import atomic_write_bytes
from testbed.people.people_config import WebConsoleConfig

__all__ = ["LINKS_FILE", "links_for_folder", "links_for_run"]

LINKS_FILE: Final = "web-links.json"
TOKEN_BYTES: Final = 24


class Links(TypedDict):
    """A set of links' tokens, as ``web-links.json`` holds them."""

    humans: list[str]
    overview: str | None
    operator: str | None


_SESSION: dict[int, Links] = {}
"""This process's tokens per number of humans (a protocol's trials share them)."""


def _made(count: int, folder: Path | None = None) -> Links:
    """This process's tokens for ``count`` humans: made once; with ``folder`` (a folder
    of runs), those every earlier command of that folder kept in its ``web-links.json``,
    else this process's written there for the next."""
    if count in _SESSION:
        kept = _SESSION[count]
    elif folder is not None and (folder / LINKS_FILE).exists():
        got = _read(folder / LINKS_FILE)
        kept = _SESSION[count] = got if len(got["humans"]) == count else _new(count)
    else:
        kept = _SESSION[count] = _new(count)
    if folder is not None and not (folder / LINKS_FILE).exists():
        _write(folder / LINKS_FILE, kept)
    return kept


def _new(count: int) -> Links:
    return Links(humans=[secrets.token_urlsafe(TOKEN_BYTES) for _ in range(count)],
                 overview=secrets.token_urlsafe(TOKEN_BYTES),
                 operator=secrets.token_urlsafe(TOKEN_BYTES))


def _read(path: Path) -> Links:
    kept = json.loads(path.read_text(encoding="utf-8"))
    return Links(humans=[str(t) for t in kept["humans"]], overview=kept["overview"],
                 operator=kept["operator"])


def _write(path: Path, kept: Links) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, (json.dumps(kept, indent=1) + "\n").encode("utf-8"))


def _with(web: WebConsoleConfig, kept: Links) -> WebConsoleConfig:
    return web.model_copy(update={"tokens": list(kept["humans"]),
                                  "overview_token": kept["overview"],
                                  "operator_token": kept["operator"]})


def _given_or_made(web: WebConsoleConfig, count: int, folder: Path | None
                   ) -> Links:
    """The config's own tokens (what it leaves out made), else the session's."""
    if not web.tokens:
        return Links(**_made(count, folder))
    kept = Links(humans=list(web.tokens), overview=web.overview_token,
                 operator=web.operator_token)
    if kept["overview"] is None or kept["operator"] is None:
        made = _made(count, folder)
        kept["overview"] = kept["overview"] or made["overview"]
        kept["operator"] = kept["operator"] or made["operator"]
    return kept


def links_for_folder(folder: Path, web: WebConsoleConfig, count: int) -> WebConsoleConfig:
    """``web`` with the links of the folder of runs ``folder``: the config's own
    tokens, else those kept in ``folder/web-links.json`` by an earlier command (collect,
    pretrain, a trial, a protocol), else this process's, kept there for the next; so
    every command of the day in one folder gives each colleague the same link.
    ``testbed collect``/``pretrain`` build their browser console with it."""
    return _with(web, _given_or_made(web, count, folder))


def links_for_run(run_dir: Path, web: WebConsoleConfig, count: int,
                  folder: Path | None = None) -> WebConsoleConfig:
    """``web`` with the run's tokens: those kept in its folder (a resume), else the
    config's own (kept there for a resume), else this process's (those of ``folder``,
    the folder of runs, when given: :func:`links_for_folder`), kept likewise. A kept file
    for another number of humans is an error naming it."""
    path = run_dir / LINKS_FILE
    if path.exists():
        kept = _read(path)
        if len(kept["humans"]) != count:
            raise ValueError(f"{path}: {len(kept['humans'])} humans' links kept, the run "
                             f"has {count}; remove the file to make new links")
        _SESSION[count] = kept
    else:
        kept = _given_or_made(web, count, folder)
    _write(path, kept)
    return _with(web, kept)
