"""Who is who on the web console: one secret token per human, one for the operator, one
for a read-only overview.

A token is the only thing that says which human a browser is: the page, its frames
and its inputs all carry it, and the server takes the human's index from the token,
never from the URL or a message, so one human cannot act for another by editing a
number. Tokens are compared in constant time (``hmac.compare_digest``). They are made
at start (``secrets.token_urlsafe``, printed once) or come from the config, and a run
keeps them for its resume (``testbed.experiments.web_links``).

Roles (issue 44): a human's token opens that human's page (pushes, resets) and the
overview to look at; the **overview** token opens the overview only, to look at (a link
to share with anyone who should watch); the **operator** token opens the overview with
its controls, pause and stop: stopping the trial is the operator's alone.
"""

from __future__ import annotations

import hmac
import re
import secrets
from collections.abc import Sequence
from typing import Final

TOKEN_RE: Final = re.compile(r"[A-Za-z0-9_-]{16,}")
TOKEN_BYTES: Final = 24
_SESSION: dict[int, TokenBook] = {}


OPERATOR: Final = "operator"
VIEWER: Final = "viewer"


class TokenBook:
    """The humans' tokens, the overview's and the operator's; ``human_of(token)`` is the
    index of its human or None, ``overview_role(token)`` who may open the overview."""

    def __init__(self, tokens: Sequence[str], overview: str | None = None,
                 operator: str | None = None) -> None:
        tokens = list(tokens)
        for i, tok in enumerate(tokens):
            if not TOKEN_RE.fullmatch(tok):
                raise ValueError(f"humans.web.tokens[{i}]: need 16+ characters of "
                                 "A-Z a-z 0-9 _ -")
        overview = overview or secrets.token_urlsafe(TOKEN_BYTES)
        operator = operator or secrets.token_urlsafe(TOKEN_BYTES)
        for name, tok in (("overview_token", overview), ("operator_token", operator)):
            if not TOKEN_RE.fullmatch(tok):
                raise ValueError(f"humans.web.{name}: need 16+ characters of "
                                 "A-Z a-z 0-9 _ -")
        if len(set(tokens)) != len(tokens):
            raise ValueError("humans.web.tokens: every human needs a token of their own")
        if len({*tokens, overview, operator}) != len(tokens) + 2:
            raise ValueError("humans.web: the overview and operator tokens must differ from "
                             "each other and from every human's")
        self._tokens = tokens
        self.overview = overview
        """The read-only overview's token (a link to share)."""
        self.operator = operator
        """The operator's token: the overview with pause and stop."""

    @classmethod
    def generate(cls, count: int) -> TokenBook:
        return cls([secrets.token_urlsafe(TOKEN_BYTES) for _ in range(count)])

    def as_dict(self) -> dict[str, object]:
        """What a run keeps of them for its resume (``testbed.experiments.web_links``)."""
        return {"humans": list(self._tokens), "overview": self.overview,
                "operator": self.operator}

    @classmethod
    def adopt(cls, book: TokenBook) -> None:
        """Make ``book`` this process's session tokens (a resumed run's, so the protocol's
        later trials keep the same links)."""
        _SESSION[len(book)] = book

    @classmethod
    def for_session(cls, count: int) -> TokenBook:
        """Random tokens made once per controller process and kept for its later trials.

        A protocol runs a dozen trials, each with its own console: the humans keep their
        URLs (with the same port, their pages reconnect by themselves) instead of being
        handed new links between trials.
        """
        if count not in _SESSION:
            _SESSION[count] = cls.generate(count)
        return _SESSION[count]

    def __len__(self) -> int:
        return len(self._tokens)

    def token(self, human: int) -> str:
        return self._tokens[human]

    def human_of(self, token: str | None) -> int | None:
        if not token:
            return None
        found = None
        for h, tok in enumerate(self._tokens):  # no early exit: constant time
            if hmac.compare_digest(tok.encode(), token.encode()):
                found = h
        return found

    def overview_role(self, token: str | None) -> str | None:
        """Who ``token`` is on the overview: :data:`OPERATOR` (its controls), :data:`VIEWER`
        (the overview token or a human's: to look at), None (no valid token)."""
        if not token:
            return None
        operator = hmac.compare_digest(self.operator.encode(), token.encode())
        viewer = hmac.compare_digest(self.overview.encode(), token.encode())
        human = self.human_of(token) is not None
        return OPERATOR if operator else VIEWER if viewer or human else None
