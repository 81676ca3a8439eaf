"""planar-vo bench compare: two sweeps' records side by side (planar_vo/bench/compare.py)."""
from __future__ import annotations

import json
import re

import pytest

from planar_vo.bench.compare import compare, format_comparison, format_markdown, read_sweep
from planar_vo.cli import main
from planar_vo.core.errors import InputError


def _record(layout: str, seed: int, smoothed: float, raw: float = 0.5, motion: str = "estimated") -> dict:
    """One log's sweep record with the fields the summary reads."""
    return {"name": f"{layout}_s{seed}_n300_abc", "layout": layout, "seed": seed, "status": "ok", "motion": motion,
            "frames": 300, "path_m": 12.0, "steps": {"dpp": 290, "2pt": 9, "partial": 0, "bridged": 0},
            "raw_drift_pct": raw, "raw_yaw_deg": -0.2, "smoothed_drift_pct": smoothed, "smoothed_yaw_deg": 0.1,
            "normalised": {"dpp": {"n": 290, "sum_sq": [290.0, 72.5, 1160.0], "nees_sum": 870.0}},
            "manhattan_frames": 1, "scene": {"texture": "medium"}}


def _sweeps():
    before = [_record("straight", s, 0.1 * (s - 9)) for s in range(10, 14)] + [_record("hall", 10, 0.40)]
    after = [dict(r) for r in before]
    after[3] = dict(after[3], smoothed_drift_pct=0.90)   # straight_s13: 0.40 -> 0.90, worse
    after[4] = dict(after[4], smoothed_drift_pct=0.20)   # hall_s10: 0.40 -> 0.20, better
    after[0] = dict(after[0], smoothed_drift_pct=0.13)   # straight_s10: 0.10 -> 0.13, within 0.05
    after.append(_record("loop", 10, 0.05))               # only in after
    return {r["name"]: r for r in before}, {r["name"]: r for r in after}


def test_compare_counts_the_logs_that_moved_and_the_layouts_that_got_worse():
    before, after = _sweeps()
    c = compare(before, after, 0.05)
    st, hall = c["layouts"]["straight"], c["layouts"]["hall"]
    assert (st["logs"], st["better"], st["worse"], st["same"]) == (4, 0, 1, 3)
    assert (hall["better"], hall["worse"], hall["same"]) == (1, 0, 0)
    assert st["before"]["smoothed_drift_pct"]["worst"] == pytest.approx(0.40)
    assert st["after"]["smoothed_drift_pct"]["worst"] == pytest.approx(0.90)
    # worst first: the straight log that got worse, then the hall that got better
    assert [n for n, _, _ in c["changed"]] == ["straight_s13_n300_abc", "hall_s10_n300_abc"]
    assert [(w[0], w[2]) for w in c["worse_layouts"]] == [("straight", "p90"), ("straight", "worst")]
    assert c["only_after"] == ["loop_s10_n300_abc"] and c["only_before"] == []
    assert c["layouts"]["all"]["logs"] == 5
    text = format_comparison(c, ("A", "B"))
    assert "straight_s13_n300_abc" in text and "+0.50" in text and "only in B (1" in text
    # the five compared logs' 290 direction-plus-point steps each, normalised 1 / 0.5 / 2, 3.0
    assert "dpp         1450 -> 1450    1.00 / 0.50 / 2.00, 3.0 -> 1.00 / 0.50 / 2.00, 3.0" in text
    assert "| straight | 4 |" in format_markdown(c, ("A", "B"))


def test_identical_sweeps_show_no_change():
    before, _ = _sweeps()
    c = compare(before, before, 0.05)
    assert c["changed"] == [] and c["worse_layouts"] == []
    assert "layouts that got worse: none" in format_comparison(c, ("A", "A"))


def test_read_sweep_round_trip_and_bad_input(tmp_path):
    before, after = _sweeps()
    for name, recs in (("a", before), ("b", after)):
        (tmp_path / name).mkdir()
        (tmp_path / name / "sweep.json").write_text(json.dumps({"command": "x", "summary": {}, "logs": list(recs.values())}))
    assert read_sweep(tmp_path / "a") == before
    assert read_sweep(tmp_path / "b" / "sweep.json") == after
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(InputError, match="not a bench sweep result"):
        read_sweep(tmp_path / "bad.json")
    with pytest.raises(InputError, match="no sweep.json there"):
        read_sweep(tmp_path / "missing")


def test_cli_compares_and_fails_in_one_line(tmp_path, capsys):
    before, after = _sweeps()
    for name, recs in (("a", before), ("b", after)):
        (tmp_path / name).mkdir()
        (tmp_path / name / "sweep.json").write_text(json.dumps({"logs": list(recs.values())}))
    md = tmp_path / "cmp.md"
    assert main(["bench", "compare", str(tmp_path / "a"), str(tmp_path / "b"), "--md", str(md)]) == 0
    out = capsys.readouterr().out
    assert "5 compared" in out and "layouts that got worse: straight" in out
    assert "straight_s13_n300_abc" in md.read_text()
    # every row of the layout table has as many cells as its header (a bare | in a label splits one)
    rows = [r for r in md.read_text().splitlines() if r.startswith("| ")][:3]
    cells = [len(re.split(r"(?<!\\)\|", r)) for r in rows]
    assert len(set(cells)) == 1, rows
    assert main(["bench", "compare", str(tmp_path / "a"), str(tmp_path / "nowhere")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no sweep.json there" in err[0]
    (tmp_path / "c").mkdir()
    (tmp_path / "c" / "sweep.json").write_text(json.dumps({"logs": [_record("loop", 99, 0.1)]}))
    assert main(["bench", "compare", str(tmp_path / "a"), str(tmp_path / "c")]) == 2
    assert "no log in common" in capsys.readouterr().err
