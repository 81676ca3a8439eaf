"""Two accuracy sweeps side by side: ``planar-vo bench compare BEFORE AFTER``.

``planar-vo bench compare BEFORE AFTER [--threshold 0.05] [--md FILE]``

``BEFORE`` and ``AFTER`` are the ``--out`` folders (or their ``sweep.json``) of two
``planar-vo bench sweep`` runs over the same seeds -- the code or configuration before and
after a change. Printed, over the logs both hold (matched by name: seed, layout, frames
and scene hash): per layout, median / p90 / worst of the smoothed drift and |final yaw|,
the worst smoothed-minus-raw drift, before -> after, and how many logs got better, worse
or stayed within ``--threshold`` (% of the path); the steps per status and their
normalised errors (the stated uncertainty's honesty) over all compared logs; every log
whose smoothed drift moved by more than the threshold, worst first; and the layouts that
got worse (median, p90 or worst up by more than the threshold), the question a change
must answer before it lands. ``--md FILE`` also writes the tables as Markdown.

The logs are matched by name, so a change that renders different scenes (a new seed
range, a changed renderer) compares nothing: the logs only one sweep holds are listed.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from planar_vo.bench.sweep import GAP_LINK, STATUSES, group_records, summarise

#: The columns compared per layout: (summary key, label).
COLUMNS = (("smoothed_drift_pct", "smoothed drift %"), ("smoothed_yaw_deg", "smoothed |yaw| deg"),
           ("smoothed_minus_raw", "smoothed - raw %"))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("before", help="a bench sweep --out folder (or its sweep.json): the reference")
    parser.add_argument("after", help="a bench sweep --out folder (or its sweep.json) over the same seeds")
    parser.add_argument("--threshold", type=float, default=0.05,
                        help="%% of the path a log's smoothed drift must move to count as changed (default 0.05)")
    parser.add_argument("--md", default=None, metavar="FILE", help="also write the tables as Markdown")


def read_sweep(path: str | Path) -> dict[str, dict]:
    """The per-log records of a sweep (``sweep.json`` in ``path``, or ``path`` itself), by
    log name: ``{name: record}``. Raises InputError naming the file and the fix."""
    from planar_vo.core.errors import InputError

    p = Path(path)
    f = p / "sweep.json" if p.is_dir() else p
    if not f.is_file():
        raise InputError(f"{path}: no sweep.json there; run 'planar-vo bench sweep --seeds A-B --out {path}' first")
    try:
        logs = json.loads(f.read_text(encoding="utf-8"))["logs"]
        return {r["name"]: r for r in logs if "name" in r}
    except (ValueError, KeyError, TypeError) as exc:
        raise InputError(f"{f}: not a bench sweep result ({type(exc).__name__}: {exc}); "
                         "rerun planar-vo bench sweep to write it again") from None


def compare(before: dict[str, dict], after: dict[str, dict], threshold: float) -> dict:
    """The comparison of two sweeps' records (:func:`read_sweep`) over their common logs:
    ``{"layouts": {name: {"logs", "before": summary row, "after": summary row, "better",
    "worse", "same"}}, "changed": [(name, before record, after record)] worst first,
    "worse_layouts": [(name, key, statistic, before, after)], "only_before", "only_after",
    "failed": [names failed in either]}``.
    A log is better / worse when its smoothed drift moved by more than ``threshold`` (%)."""
    common = sorted(set(before) & set(after), key=lambda n: (before[n]["layout"], before[n]["seed"]))
    ok = [n for n in common if before[n].get("status") == "ok" and after[n].get("status") == "ok"]
    sb = summarise([dict(before[n]) for n in ok])
    sa = summarise([dict(after[n]) for n in ok])
    delta = {n: after[n]["smoothed_drift_pct"] - before[n]["smoothed_drift_pct"] for n in ok}
    layouts = {}
    # a log counts in the rows of its before-record (its layout; announced or estimated)
    for name, rs in group_records([before[n] for n in ok]).items():
        d = np.array([delta[r["name"]] for r in rs])
        layouts[name] = {"logs": len(rs), "before": sb[name], "after": sa[name],
                         "better": int((d < -threshold).sum()), "worse": int((d > threshold).sum()),
                         "same": int((np.abs(d) <= threshold).sum())}
    key = "smoothed_drift_pct"
    worse = [(name, key, stat, g["before"][key][stat], g["after"][key][stat])
             for name, g in layouts.items() if g["logs"] and name not in ("all", "announced", "estimated")
             for stat in ("median", "p90", "worst") if g["after"][key][stat] - g["before"][key][stat] > threshold]
    changed = sorted((n for n in ok if abs(delta[n]) > threshold), key=lambda n: -delta[n])
    return {"threshold": threshold, "layouts": layouts, "changed": [(n, before[n], after[n]) for n in changed],
            "worse_layouts": worse, "only_before": sorted(set(before) - set(after)),
            "only_after": sorted(set(after) - set(before)),
            "failed": sorted(n for n in common if n not in ok)}


def _stats(row: dict, key: str) -> str:
    s = row[key]
    return f"{s['median']:.2f} / {s['p90']:.2f} / {s['worst']:.2f}"


def _status_lines(g: dict | None) -> list[str]:
    """Per status of the summary row ``g`` (both sweeps): steps, and the normalised step
    errors (:func:`planar_vo.bench.sweep.pool_normalised`), before -> after."""
    if not g:
        return []
    out = []
    for s in STATUSES:
        nb, na = g["before"]["normalised"].get(s), g["after"]["normalised"].get(s)
        norm = " -> ".join("-" if v is None else
                           f"{v['rms'][0]:.2f} / {v['rms'][1]:.2f} / {v['rms'][2]:.2f}, {v['nees']:.1f}"
                           for v in (nb, na))
        out.append(f"{s:<8} {g['before']['steps'][s]:>7} -> {g['after']['steps'][s]:<7} {norm}")
    nb, na = g["before"]["normalised"].get(GAP_LINK), g["after"]["normalised"].get(GAP_LINK)
    if nb or na:  # translation only: x / y, e^T C^-1 e of 2 when honest
        norm = " -> ".join("-" if v is None else f"{v['rms'][0]:.2f} / {v['rms'][1]:.2f}, {v['nees']:.1f} of 2"
                           for v in (nb, na))
        out.append(f"{'gap link':<8} {(nb or {}).get('n', 0):>7} -> {(na or {}).get('n', 0):<7} {norm}")
    return out


def format_comparison(c: dict, names: tuple[str, str]) -> str:
    """The printed comparison of :func:`compare`; ``names`` label the two sweeps."""
    lines = [f"{'layout':<11}{'logs':>5}  " + "  ".join(f"{label + ' (median / p90 / worst)':>48}"
                                                      for _, label in COLUMNS) + "   better / worse / same"]
    for name, g in c["layouts"].items():
        cells = "  ".join(f"{_stats(g['before'], k) + '  ->  ' + _stats(g['after'], k):>48}" for k, _ in COLUMNS)
        lines.append(f"{name:<11}{g['logs']:>5}  {cells}   {g['better']:>6} / {g['worse']:>5} / {g['same']:>4}")
    lines += ["", "steps per status and normalised step error RMS x / y / theta, mean e^T C^-1 e (3 if honest), "
                  "all compared logs, before -> after:"]
    lines += [f"  {line}" for line in _status_lines(c["layouts"].get("all"))]
    lines += ["", f"logs whose smoothed drift moved by more than {c['threshold']:.2f} % of the path "
                  f"({len(c['changed'])}), worst first:"]
    for n, b, a in c["changed"]:
        lines.append(f"  {n:<34} {b.get('motion', ''):<14} smoothed {b['smoothed_drift_pct']:6.2f} -> "
                     f"{a['smoothed_drift_pct']:6.2f} ({a['smoothed_drift_pct'] - b['smoothed_drift_pct']:+.2f})  raw "
                     f"{b['raw_drift_pct']:6.2f} -> {a['raw_drift_pct']:6.2f}  yaw {b['smoothed_yaw_deg']:+.2f} -> "
                     f"{a['smoothed_yaw_deg']:+.2f} deg")
    if not c["changed"]:
        lines.append("  none")
    lines.append("")
    if c["worse_layouts"]:
        lines.append("layouts that got worse: " + "; ".join(
            f"{name} {stat} {b:.2f} -> {a:.2f} %" for name, _, stat, b, a in c["worse_layouts"]))
    else:
        lines.append(f"layouts that got worse: none (no median, p90 or worst smoothed drift up by more than "
                     f"{c['threshold']:.2f} %)")
    for key, label in (("only_before", names[0]), ("only_after", names[1])):
        if c[key]:
            lines.append(f"only in {label} ({len(c[key])}, not compared): " + ", ".join(c[key]))
    if c["failed"]:
        lines.append(f"failed in either ({len(c['failed'])}, not compared): " + ", ".join(c["failed"]))
    return "\n".join(lines)


def _md_cell(text: str) -> str:
    """``text`` safe inside a markdown table cell (``|yaw|`` would split the cell)."""
    return text.replace("|", "\\|")


def format_markdown(c: dict, names: tuple[str, str]) -> str:
    out = [f"`planar-vo bench compare {names[0]} {names[1]}` (threshold {c['threshold']:.2f} % of the path)", "",
           "| layout | logs | " + " | ".join(f"{_md_cell(label)} before -> after" for _, label in COLUMNS)
           + " | better / worse / same |", "|" + " --- |" * (3 + len(COLUMNS))]
    for name, g in c["layouts"].items():
        out.append(f"| {name} | {g['logs']} | " + " | ".join(
            f"{_stats(g['before'], k)} -> {_stats(g['after'], k)}" for k, _ in COLUMNS)
            + f" | {g['better']} / {g['worse']} / {g['same']} |")
    out += ["", "| log | motion | smoothed drift % | raw drift % | smoothed yaw deg |", "| --- | --- | --- | --- | --- |"]
    for n, b, a in c["changed"]:
        out.append(f"| {n} | {b.get('motion', '')} | {b['smoothed_drift_pct']:.2f} -> {a['smoothed_drift_pct']:.2f} | "
                   f"{b['raw_drift_pct']:.2f} -> {a['raw_drift_pct']:.2f} | "
                   f"{b['smoothed_yaw_deg']:+.2f} -> {a['smoothed_yaw_deg']:+.2f} |")
    return "\n".join(out) + "\n"


def main(args: argparse.Namespace) -> int:
    from planar_vo.core.errors import InputError
    from planar_vo.io.atomic import write_text_atomic

    if not args.threshold >= 0:
        raise InputError(f"--threshold {args.threshold!r}: must be >= 0 (% of the path)")
    before, after = read_sweep(args.before), read_sweep(args.after)
    c = compare(before, after, args.threshold)
    if not c["layouts"].get("all", {}).get("logs"):
        raise InputError(f"{args.before} and {args.after} hold no log in common: compare two sweeps over the "
                         "same seeds (and the same renderer)")
    names = (str(args.before), str(args.after))
    print(f"planar-vo bench compare: {names[0]} ({len(before)} logs) -> {names[1]} ({len(after)} logs), "
          f"{c['layouts']['all']['logs']} compared")
    print(format_comparison(c, names))
    if args.md:
        write_text_atomic(Path(args.md), format_markdown(c, names))
        print(f"\nwrote {args.md}")
    return 0
