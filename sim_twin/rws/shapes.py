"""The two representations RWS 1.0 answers in: JSON (``?json=1``) and XHTML (default).

Why it exists: every RWS resource is a list of typed items (``<li class="rap-execution"
title="execution"><span class="ctrlexecstate">stopped</span>...``); with ``json=1`` the
same items come as ``{"_links": {"base": {"href": ...}}, "_embedded": {"_state": [{"_type":
"rap-execution", "_title": "execution", "ctrlexecstate": "stopped", ...}]}}``, all leaf
values strings. ``abb_robot_client.rws`` reads ``_embedded._state`` and, on an error, the
``_embedded.status`` object (``code``, ``msg``); it parses JSON only when the
``Content-Type`` is exactly ``application/json``. One renderer for both keeps the twin's
answers the same in both forms (the lab compares its controller's with ``curl``).

The XHTML form is generic (items as ``li``, fields as ``span``, nested lists as nested
``ul``); the ABB clients never read it, a person does.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any
from xml.sax.saxutils import escape, quoteattr

JSON_TYPE = "application/json"
XHTML_TYPE = "application/xhtml+xml;charset=utf-8"


@dataclass
class Doc:
    """One RWS answer: a head title (``rapid``, ``panel``, ...), the base path of its
    links (``rw/rapid/``) and its items."""

    title: str
    base: str
    items: list[dict[str, Any]] = field(default_factory=list)


def _leaf(v: Any) -> Any:
    if isinstance(v, bool):
        return "TRUE" if v else "FALSE"
    if isinstance(v, dict):
        return {k: _leaf(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_leaf(x) for x in v]
    return str(v)


def render(doc: Doc, host: str, as_json: bool) -> tuple[bytes, str]:
    """The body and Content-Type of ``doc``; ``host`` is ``http://name:port``."""
    base = f"{host}/{doc.base}"
    if as_json:
        body = {"_links": {"base": {"href": base}},
                "_embedded": {"_state": [_leaf(i) for i in doc.items]}}
        return json.dumps(body, separators=(",", ":")).encode(), JSON_TYPE
    lis = "".join(_li(i) for i in doc.items)
    return _page(doc.title, base, f'<div class="state"><a href="" rel="self"/><ul>{lis}</ul>'
                 "</div>"), XHTML_TYPE


def render_error(code: int, msg: str, host: str, as_json: bool) -> tuple[bytes, str]:
    """An error answer with RWS's ``status`` element."""
    if as_json:
        body = {"_links": {"base": {"href": f"{host}/"}},
                "_embedded": {"_state": [], "status": {"code": str(code), "msg": msg}}}
        return json.dumps(body, separators=(",", ":")).encode(), JSON_TYPE
    return _page("rw", "", f'<div class="status"><span class="code">{code}</span>'
                 f'<span class="msg">{escape(msg)}</span></div>'), XHTML_TYPE


def _page(title: str, base: str, body: str) -> bytes:
    return ('<?xml version="1.0" encoding="UTF-8"?>\n<html xmlns="http://www.w3.org/1999/xhtml">'
            f"<head><title>{escape(title)}</title><base href={quoteattr(base)}/></head>"
            f"<body>{body}</body></html>").encode()


def _li(item: Mapping[str, Any]) -> str:
    cls, title = item.get("_type", ""), item.get("_title", "")
    parts = []
    for k, v in item.items():
        if k.startswith("_"):
            continue
        if isinstance(v, Sequence) and not isinstance(v, str):
            inner = "".join(_li(x) if isinstance(x, Mapping) else
                            f"<li><span>{escape(str(_leaf(x)))}</span></li>" for x in v)
            parts.append(f"<ul class={quoteattr(k)}>{inner}</ul>")
        else:
            parts.append(f"<span class={quoteattr(k)}>{escape(str(_leaf(v)))}</span>")
    return f"<li class={quoteattr(str(cls))} title={quoteattr(str(title))}>{''.join(parts)}</li>"
