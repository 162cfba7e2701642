"""The operator console in each human's own browser (``--humans web``).

``WebHumans`` serves one page per human and a fleet overview over HTTP + WebSocket
(Starlette on uvicorn, in a thread of the controller); see ``gui.web.web_humans`` for the
why and ``gui.web.server`` for the wire. Imported only on this path: the ``web`` extra
(starlette, uvicorn, websockets) is optional.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from gui.web.web_humans import WebHumans

__all__ = ["WebHumans"]


def __getattr__(name: str) -> Any:
    if name == "WebHumans":
        from gui.web.web_humans import WebHumans  # lazy: starlette only when asked for

        return WebHumans
    raise AttributeError(f"module 'gui.web' has no attribute {name!r}")
