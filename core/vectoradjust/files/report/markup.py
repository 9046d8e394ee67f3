"""The report's HTML pieces: escaping, number formatting, tables and the page's CSS.

Cells are escaped unless they are :class:`_Raw` (HTML already built); numeric columns
are right-aligned. :func:`_records_table` and :func:`_generic` render lists of dicts and
JSON-like objects (the QA verdict, the interior orientation) as tables.
"""

from __future__ import annotations

import html
import math
import re
from collections.abc import Sequence
from typing import Any, Optional

import numpy as np

__all__: list = []  # helpers of the package's other modules


class _Raw(str):
    """HTML that is already escaped / built (not escaped again)."""


def _e(s: Any) -> str:
    return html.escape(str(s), quote=True)


def _fmt(v: Any, nd: int = 3) -> str:
    """Consistent number formatting: None/NaN -> '–', bool -> yes/no, int as is."""
    if v is None:
        return "\u2013"
    if isinstance(v, (bool, np.bool_)):
        return "yes" if v else "no"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        f = float(v)
        return f"{f:.{nd}f}" if math.isfinite(f) else "\u2013"
    return str(v)


def _fmt_col(values, nd: int = 3) -> list:
    """Format a column (array or list) of numbers quickly."""
    a = np.asarray(values)
    if a.dtype.kind == "f":
        out = np.char.mod(f"%.{nd}f", np.where(np.isfinite(a), a, 0.0)).astype(object)
        out[~np.isfinite(a)] = "\u2013"
        return out.tolist()
    if a.dtype.kind in "iu":
        return a.astype(str).tolist()
    return [_fmt(x, nd) if not isinstance(x, str) else x for x in a.tolist()]


_NUM_RE = re.compile(r"^[+\-\u2212]?\d[\d,]*(\.\d+)?( ?%)?$|^\u2013$")


def _cell(v: Any) -> str:
    if isinstance(v, _Raw):
        return str(v)
    return _e(v)


def _table(headers: Sequence[str], rows: Sequence[Sequence[Any]], *, cls: str = "",
           ident: Optional[str] = None, row_keys: Optional[Sequence[str]] = None,
           header_html: bool = False) -> str:
    """An HTML table; numeric columns right-aligned. Cells are escaped unless _Raw."""
    if not rows:
        return '<p class="note">(none)</p>'
    ncol = len(headers)
    numeric = []
    for j in range(ncol):
        col = [r[j] for r in rows[:200] if j < len(r)]
        numeric.append(bool(col) and all(isinstance(c, str) and not isinstance(c, _Raw)
                                         and _NUM_RE.match(c) for c in col))
    parts = [f'<table{f" id={_q(ident)}" if ident else ""} class="{_e(cls)}">', "<thead><tr>"]
    for h in headers:
        parts.append(f"<th>{h if header_html else _e(h)}</th>")
    parts.append("</tr></thead><tbody>")
    for i, r in enumerate(rows):
        key = f" data-key={_q(row_keys[i])}" if row_keys is not None else ""
        tds = "".join(
            f'<td class="num">{_cell(c)}</td>' if numeric[j] else f"<td>{_cell(c)}</td>"
            for j, c in enumerate(r))
        parts.append(f"<tr{key}>{tds}</tr>")
    parts.append("</tbody></table>")
    return "".join(parts)


def _q(s: str) -> str:
    return f'"{_e(s)}"'


def _kv_table(pairs: Sequence[tuple], ident: Optional[str] = None) -> str:
    """Two-column table of (label, value[, key]) pairs."""
    rows = [[p[0], p[1]] for p in pairs]
    keys = [p[2] if len(p) > 2 else re.sub(r"\W+", "_", str(p[0])).strip("_").lower()
            for p in pairs]
    return _table(["quantity", "value"], rows, cls="kv", ident=ident, row_keys=keys)


def _badge(passed: Optional[bool], yes: str = "passed", no: str = "FAILED",
           na: str = "not tested") -> _Raw:
    if passed is None:
        return _Raw(f'<span class="badge na">{_e(na)}</span>')
    return _Raw(f'<span class="badge {"pass" if passed else "fail"}">'
                f"{_e(yes if passed else no)}</span>")


def _note(text: str) -> str:
    return f'<p class="note">{_e(text)}</p>'


_CSS = """
body{font-family:-apple-system,"Segoe UI",Roboto,"Helvetica Neue",Arial,sans-serif;
 color:#222;margin:0;background:#f6f7f9;font-size:14px;line-height:1.45}
main{max-width:1180px;margin:0 auto;padding:24px 28px 60px;background:#fff}
h1{font-size:26px;margin:0 0 4px}
h2{font-size:20px;border-bottom:2px solid #1f77b4;padding-bottom:3px;margin-top:36px}
h3{font-size:16px;margin-top:24px}
h4{font-size:14px;margin:16px 0 6px}
.meta{color:#666;margin:0 0 16px}
nav ol{columns:3;font-size:13px;margin:8px 0 0;padding-left:20px}
nav li.sub{margin-left:14px;font-size:12px}
nav a,main a{color:#1f5fa0;text-decoration:none}
table{border-collapse:collapse;margin:8px 0 14px;font-size:12.5px}
th,td{border:1px solid #d8dce2;padding:3px 7px;vertical-align:top}
th{background:#eef2f7;text-align:left;position:sticky;top:0}
tbody tr:nth-child(even){background:#fafbfc}
td.num{text-align:right;font-variant-numeric:tabular-nums;white-space:nowrap}
table.kv td:first-child{color:#444}
.scroll{max-height:560px;overflow:auto;border:1px solid #e3e6ea;margin:8px 0 14px}
.scroll table{margin:0}
.badge{display:inline-block;padding:1px 8px;border-radius:10px;font-weight:600;
 font-size:12px}
.badge.pass{background:#dff3e4;color:#146c2e;border:1px solid #9fd5ae}
.badge.fail{background:#fde2e1;color:#a4161a;border:1px solid #f1a7a4}
.badge.na{background:#eee;color:#555;border:1px solid #ccc}
.verdict{font-size:15px;padding:8px 12px;border-radius:6px;margin:10px 0}
.verdict.pass{background:#eef9f1;border-left:5px solid #2e9e4f}
.verdict.fail{background:#fdf0ef;border-left:5px solid #d62728}
.verdict.na{background:#f3f3f3;border-left:5px solid #999}
.note{color:#555;font-size:12.5px}
.statement{background:#f4f8fc;border-left:4px solid #1f77b4;padding:6px 10px;
 margin:6px 0}
figure{margin:12px 0 20px}
figure img{max-width:100%;height:auto;border:1px solid #e3e6ea}
figcaption{font-size:12.5px;color:#444;margin-top:4px}
details summary{cursor:pointer;color:#1f5fa0}
ul.warnings li{color:#8a4b00}
footer{color:#888;font-size:12px;margin-top:40px}
"""


def _columns_table(cols: dict, spec, mask: np.ndarray, ident: Optional[str] = None,
                   order: Optional[np.ndarray] = None) -> str:
    idx = np.flatnonzero(mask) if order is None else order
    if not len(idx):
        return '<p class="note">(none)</p>'
    columns = []
    heads = []
    for key, head, nd in spec:
        if key not in cols:
            continue
        a = np.asarray(cols[key])[idx]
        if key == "Used" or key == "Adjusted":
            columns.append(["yes" if int(x) == 1 else "no" for x in a.tolist()])
        elif nd is None:
            columns.append(_fmt_col(a) if a.dtype.kind in "iuf" else [str(x) for x in a])
        else:
            columns.append(_fmt_col(a.astype(float), nd))
        heads.append(head)
    rows = [list(r) for r in zip(*columns)]
    return _table(heads, rows, ident=ident)


def _records_table(records: Sequence[dict], ident: Optional[str] = None) -> str:
    """A table of dicts (union of keys, first-seen order); nested values compacted."""
    keys: list = []
    for r in records:
        for k in r:
            if k not in keys:
                keys.append(k)
    rows = [[_compact(r.get(k)) for k in keys] for r in records]
    return _table([str(k) for k in keys], rows, ident=ident)


def _compact(v: Any, depth: int = 0):
    if isinstance(v, dict):
        if depth > 2:
            return f"{len(v)} entries"
        return _Raw(_generic(v, depth + 1))
    if isinstance(v, (list, tuple)):
        if v and all(isinstance(x, dict) for x in v):
            if depth > 2:
                return f"{len(v)} rows"
            return _Raw(f"<details><summary>{len(v)} row{'s' if len(v) != 1 else ''}</summary>"
                        f"{_records_table(v)}</details>")
        items = [_fmt(x, 4) if not isinstance(x, str) else x for x in v]
        text = ", ".join(items[:30]) + (f", \u2026 ({len(items)} in all)" if len(items) > 30
                                         else "")
        return text or "\u2013"
    if isinstance(v, (float, np.floating)):
        return _fmt(v, 4)
    if v is None:
        return "\u2013"
    if isinstance(v, str) and v.lower() in ("pass", "fail"):
        return _badge(v.lower() == "pass", "pass", "fail")
    return _fmt(v)


def _generic(obj: Any, depth: int = 0) -> str:
    """Render a JSON-like object as tables."""
    if isinstance(obj, dict):
        scal = [(k, v) for k, v in obj.items()
                if not isinstance(v, (dict, list, tuple))]
        rest = [(k, v) for k, v in obj.items() if isinstance(v, (dict, list, tuple))]
        out = []
        if scal:
            out.append(_table(["key", "value"], [[str(k), _compact(v, depth)] for k, v in scal],
                              cls="kv"))
        for k, v in rest:
            out.append(f"<h4>{_e(k)}</h4>")
            if isinstance(v, dict):
                out.append(_generic(v, depth + 1))
            elif v and all(isinstance(x, dict) for x in v):
                out.append(_records_table(v))
            else:
                out.append(f"<p>{_e(_compact(v, depth))}</p>")
        return "".join(out)
    if isinstance(obj, (list, tuple)) and obj and all(isinstance(x, dict) for x in obj):
        return _records_table(obj)
    return f"<p>{_e(_compact(obj, depth))}</p>"
