"""Who is who on the web console: one secret token per human.

A token is the only thing that says which human a browser is: the page, its frames
and its inputs all carry it, and the server takes the human's index from the token,
never from the URL or a message, so one human cannot act for another by editing a
number. Tokens are compared in constant time (``hmac.compare_digest``). They are made
at start (``secrets.token_urlsafe``, printed once) or come from the config.
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


class TokenBook:
    """The humans' tokens; ``human_of(token)`` is the index of its human or None."""

    def __init__(self, tokens: Sequence[str]) -> None:
        tokens = list(tokens)
        for i, tok in enumerate(tokens):
            if not TOKEN_RE.fullmatch(tok):
                raise ValueError(f"humans.web.tokens[{i}]: need 16+ characters of "
                                 "A-Z a-z 0-9 _ -")
        if len(set(tokens)) != len(tokens):
            raise ValueError("humans.web.tokens: every human needs a token of their own")
        self._tokens = tokens

    @classmethod
    def generate(cls, count: int) -> TokenBook:
        return cls([secrets.token_urlsafe(TOKEN_BYTES) for _ in range(count)])

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
