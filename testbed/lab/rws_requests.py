"""The RWS requests a rehearsal's controllers served: per run on disk, and per push.

Why: the hardware twin logs every Robot Web Services request it answers (one JSON line:
``t``, ``method``, ``path``, ``status``, ``ms``), for the life of the twin. A rehearsal
keeps each run's share next to its records (``runs/<run>/hosts/<host>.rws.jsonl``), so
what the agent asked of the controller in that run can be read beside the host's log,
and :func:`requests_table` says what one push costs on the wire: every endpoint's
requests per program start and their time.
"""

from __future__ import annotations

import json
import re
import statistics
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

START = ("POST", "rw/rapid/execution?action=start")
"""The request that starts a motion program: one per push step of a host."""


@dataclass
class RwsLogSlices:
    """Each host's RWS log from an offset on: what one run's controller served."""

    logs: Mapping[str, Path]
    _from: dict[str, int] = field(default_factory=dict)
    _run: Path | None = None

    def begin(self, run: Path) -> None:
        """A run starts: the previous one's share is written out, this one's is next."""
        self.end()
        self._run = run
        self._from = {h: (p.stat().st_size if p.exists() else 0) for h, p in self.logs.items()}

    def end(self) -> None:
        """Write the current run's share of every host's log into its ``hosts/`` folder."""
        if self._run is None:
            return
        out = self._run / "hosts"
        out.mkdir(parents=True, exist_ok=True)
        for host, src in self.logs.items():
            if not src.exists():
                continue
            with src.open("rb") as f:
                f.seek(self._from.get(host, 0))
                data = f.read()
            cut = data.rfind(b"\n") + 1  # whole lines only: the twin may be mid-write
            with open(out / f"{host}.rws.jsonl", "ab") as dst:  # a resumed run's after
                dst.write(data[:cut])
        self._run = None


def endpoint(method: str, path: str) -> str:
    """``GET rw/motionsystem/mechunits/ROB_L/robtarget`` -- one name per kind of request:
    the query kept for actions (``?action=start``), dropped otherwise, the leading ``/``
    and ``?json=1`` dropped, file names under the RAM disk folded into ``<file>``."""
    path = path.lstrip("/")
    base, _, query = path.partition("?")
    action = re.search(r"(?:^|&)action=([^&]+)", query)
    base = re.sub(r"^(fileservice/\$?\w+)/.+$", r"\1/<file>", base)
    return f"{method} {base}" + (f"?action={action.group(1)}" if action else "")


def read_requests(paths: Iterable[Path]) -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = []
    for p in paths:
        for line in p.read_text(encoding="utf-8").splitlines():
            if line.strip():
                rows.append(json.loads(line))
    return rows


def requests_table(rows: list[dict[str, Any]]) -> str:
    """Markdown: per endpoint, requests per program start, median and p95 ms, statuses."""
    starts = sum(1 for r in rows if (r["method"], endpoint(r["method"], r["path"]).split(
        " ", 1)[1]) == START)
    by: dict[str, list[dict[str, Any]]] = {}
    for r in rows:
        by.setdefault(endpoint(r["method"], r["path"]), []).append(r)
    lines = [f"RWS requests served: {len(rows)} in all, {starts} program starts "
             f"({len(rows) / starts:.1f} requests per start)" if starts else
             f"RWS requests served: {len(rows)} in all, no program start", "",
             "| endpoint | requests | per start | median ms | p95 ms | statuses |",
             "|---|---:|---:|---:|---:|---|"]
    for name, rs in sorted(by.items(), key=lambda kv: -len(kv[1])):
        ms = sorted(float(r["ms"]) for r in rs)
        p95 = ms[min(len(ms) - 1, int(0.95 * len(ms)))]
        counts = _count(r["status"] for r in rs)
        statuses = ", ".join(f"{s} x{n}" for s, n in sorted(counts.items()))
        per = f"{len(rs) / starts:.2f}" if starts else "-"
        lines.append(f"| `{name}` | {len(rs)} | {per} | {statistics.median(ms):.1f} | "
                     f"{p95:.1f} | {statuses} |")
    return "\n".join(lines) + "\n"


def _count(values: Iterable[Any]) -> dict[Any, int]:
    out: dict[Any, int] = {}
    for v in values:
        out[v] = out.get(v, 0) + 1
    return out
