"""``report.html``: the whole report on one self-contained page, with what decided it.

Why a page: a reviewer (or the lab's PI) opens one file, not a folder of Markdown, CSVs
and a PNG, and the run metadata that decides the numbers (the commit, the versions,
the thresholds as resolved, each trial's order, the hosts and their builds) otherwise
lives in per-run JSON nobody opens. Self-contained on purpose: the figure is embedded
(a data: URI), the style is inline, and the page's Content-Security-Policy forbids
every request (``default-src 'none'``), so it reads the same offline, attached to an
e-mail, years later, and cannot leak where it was opened.

Never a secret: the metadata is picked field by field from run.json and config.toml
(``_public`` drops anything named like a password, token, secret or credential), never
dumped whole. Jinja2 (``autoescape``) writes the HTML, so a run or host name is text.
"""

from __future__ import annotations

import base64
import datetime as dt
import re
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from testbed.results.report_tables import Table

if TYPE_CHECKING:
    from testbed.results.run_record import RunRecord

__all__ = ["report_page", "run_metadata"]

SECRET = re.compile(r"pass|token|secret|credential|login", re.IGNORECASE)
CSP = "default-src 'none'; img-src data:; style-src 'unsafe-inline'"
NUMBER = re.compile(r"[+-]?\d[\d.]*( ±| \[|$| \(one)")
"""A cell that starts with a number (a mean, an interval, a count): right-aligned."""

TEMPLATE = """<!doctype html>
<html lang="en"><head><meta charset="utf-8">
<meta http-equiv="Content-Security-Policy" content="{{ csp }}">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>Fleet report: {{ title }}</title>
<style>
body { font: 14px/1.45 system-ui, sans-serif; margin: 2em auto; max-width: 1400px;
       padding: 0 1em; color: #1b1b1b; }
h1 { font-size: 1.5em; } h2 { font-size: 1.15em; margin-top: 2em; }
table { border-collapse: collapse; margin: .5em 0; font-variant-numeric: tabular-nums; }
th, td { border: 1px solid #ccc; padding: .25em .6em; text-align: left; }
th { background: #f2f2f2; } td.n { text-align: right; }
p.note { color: #444; max-width: 70em; } p.flag { color: #8a1c00; font-weight: 600; }
img { max-width: 100%; } nav a { margin-right: 1em; } code { font-size: .95em; }
</style></head><body>
<h1>Fleet report: {{ title }}</h1>
<p>{{ runs|length }} finished run(s); written {{ written }}.</p>
<nav>{% for t in tables %}<a href="#{{ t.key }}">{{ t.title or "Learning" }}</a>
{% endfor %}<a href="#curves">Curves</a><a href="#metadata">Metadata</a></nav>
{% for t in tables %}
<section id="{{ t.key }}"><h2>{{ t.title or "Learning (mean ± std over trials)" }}</h2>
<table><thead><tr>{% for h in t.header %}<th>{{ h }}</th>{% endfor %}</tr></thead>
<tbody>{% for row in t.rows %}<tr>{% for c in row %}<td{{ c|cls }}>{{ c }}</td>{% endfor %}</tr>
{% endfor %}</tbody></table>
{% for n in t.notes %}<p class="{{ 'flag' if n.startswith('IDENTICAL') else 'note' }}">
{{ n }}</p>{% endfor %}</section>
{% endfor %}
<section id="curves"><h2>Curves</h2>
<img alt="cumulative successes, hard resets, idle time, human actions and ROHE per
timestep" src="data:image/png;base64,{{ png }}">
<p class="note">Mean over trials per timestep; the shading is one standard deviation over
trials, as in the paper's figures.</p></section>
{% for n in notes %}<p class="flag">{{ n }}</p>{% endfor %}
<section id="metadata"><h2>Metadata</h2>
{% for name, rows in meta.items() %}<h3>{{ name }}</h3>
{% if rows %}<table><thead><tr>{% for h in rows[0] %}<th>{{ h }}</th>{% endfor %}</tr>
</thead><tbody>{% for row in rows[1:] %}<tr>{% for c in row %}<td{{ c|cls }}>{{ c }}</td>
{% endfor %}</tr>{% endfor %}</tbody></table>{% else %}<p class="note">not recorded
</p>{% endif %}{% endfor %}</section>
</body></html>
"""


def _public(d: Any) -> Any:
    """``d`` without any key that names a secret (recursively)."""
    if isinstance(d, dict):
        return {k: _public(v) for k, v in d.items() if not SECRET.search(str(k))}
    if isinstance(d, list):
        return [_public(v) for v in d]
    return d


def _text(v: Any) -> str:
    if v is None:
        return "-"
    if isinstance(v, list):
        return ", ".join(_text(x) for x in v)
    if isinstance(v, dict):
        return ", ".join(f"{k}={_text(x)}" for k, x in v.items())
    if isinstance(v, float):
        return f"{v:.4g}"  # a resolved threshold or budget: 0.8083, not 0.80833333333
    return str(v)


def run_metadata(runs: Sequence[RunRecord]) -> dict[str, list[list[str]]]:
    """The page's metadata tables (header row first): runs, code, thresholds, hosts."""
    runs_rows = [["run", "algorithm", "trial", "position", "order of its trial", "seed",
                  "steps", "humans", "commit", "dirty", "build"]]
    numerics = [["run", "torch", "threads", "device", "versions"]]
    thresholds = [["run", "t_T", "t_R", "t_I", "u_hat", "r_hat", "random_budget",
                   "resolved"]]
    hosts = [["run", "host", "backend", "transport", "agent build", "RobotWare",
              "serial", "system"]]
    for r in runs:
        meta, cfg = _public(r.meta), _public(r.config)
        proto, opts = meta.get("protocol", {}), meta.get("options", {})
        code = meta.get("code", {})
        name = r.path.name
        runs_rows.append([name, r.algorithm, _text(proto.get("trial", meta.get(
            "sweep", {}).get("point"))), _text(proto.get("position")),
            _text(proto.get("order")), _text(opts.get("seed")), _text(opts.get("steps")),
            _text(r.humans), _text(code.get("commit")), _text(code.get("dirty")),
            _text(code.get("build"))])
        num = meta.get("numerics", {})
        numerics.append([name, _text(num.get("torch")), _text(num.get("threads")),
                         _text(num.get("device")),
                         _text({k: v for k, v in num.items()
                                if k not in ("torch", "threads", "device")}
                               | {k: code[k] for k in ("python",) if k in code}
                               | dict(code.get("libraries") or {}))])
        alg = cfg.get("algorithm", {})
        thresholds.append([name, *(_text(alg.get(k)) for k in
                                   ("t_T", "t_R", "t_I", "u_hat", "r_hat", "random_budget")),
                           _text(meta.get("thresholds"))])
        for host, info in (meta.get("hosts") or {}).items():
            ctrl = info.get("controller") or {}
            hosts.append([name, host, _text(info.get("backend")), _text(info.get("transport")),
                          _text(info.get("build")), _text(ctrl.get("robotware")),
                          _text(ctrl.get("serial")), _text(ctrl.get("system"))])
    total = len(runs)
    return {"Runs and code": runs_rows, "Versions and numerics": _grouped(numerics, total),
            "Thresholds as resolved": _grouped(thresholds, total),
            "Hosts": _grouped(hosts, total) if len(hosts) > 1 else []}


def _grouped(rows: list[list[str]], total: int) -> list[list[str]]:
    """Rows that say the same but for their run, once, with the runs they stand for
    ("all 27 runs" when every run agrees): a reviewer sees what differs."""
    groups: dict[tuple[str, ...], list[str]] = {}
    for row in rows[1:]:
        groups.setdefault(tuple(row[1:]), []).append(row[0])
    out = [["runs", *rows[0][1:]]]
    for rest, names in groups.items():
        runs = (f"all {total} runs" if len(set(names)) == total and total > 1
                else ", ".join(dict.fromkeys(names)))
        out.append([runs, *rest])
    return out


def report_page(tables: Sequence[Table], notes: Sequence[str], png: bytes,
                runs: Sequence[RunRecord]) -> str:
    """The page's HTML."""
    import jinja2
    from markupsafe import Markup  # jinja2's own escaping library

    env = jinja2.Environment(autoescape=True, undefined=jinja2.StrictUndefined)
    env.filters["cls"] = lambda c: Markup(' class="n"' if NUMBER.match(str(c)) else "")
    folders = sorted({str(r.path.parent) for r in runs})
    return env.from_string(TEMPLATE).render(
        title=", ".join(folders), runs=runs, tables=tables, notes=notes,
        png=base64.b64encode(png).decode(), meta=run_metadata(runs), csp=CSP,
        written=dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC"))
