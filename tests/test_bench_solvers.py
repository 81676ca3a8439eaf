"""`planar-vo bench solvers` in quick mode: figures written, and the paper's ordering holds."""
from __future__ import annotations

import argparse
import json

import pytest

from planar_vo.bench import solvers


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench_solvers")
    parser = argparse.ArgumentParser()
    solvers.add_arguments(parser)
    args = parser.parse_args(["--quick", "--trials", "15", "--no-poselib", "--timing-runs", "2",
                              "--json", str(out / "solvers.json"), "--plots", str(out / "plots")])
    assert solvers.main(args) == 0
    return out, json.loads((out / "solvers.json").read_text())


def _row(rows, motion, sweep, mode, level, method):
    (r,) = [r for r in rows if (r["motion"], r["sweep"], r["tilt_mode"], r["level"], r["method"])
            == (motion, sweep, mode, level, method)]
    return r


@pytest.mark.parametrize("motion", ["forward", "sideways"])
@pytest.mark.parametrize("noise", [1.0, 2.0])
def test_2pt_beats_5pt_under_image_noise(quick_run, motion, noise):
    rows = quick_run[1]["results"]
    a = _row(rows, motion, "noise", "none", noise, "2pt")
    b = _row(rows, motion, "noise", "none", noise, "5pt-opencv")
    assert a["trials"] == 15 and a["failures"] == 0
    assert a["mean_rot_deg"] < b["mean_rot_deg"] and a["mean_trans_deg"] < b["mean_trans_deg"]
    assert a["median_rot_deg"] < b["median_rot_deg"] and a["median_trans_deg"] < b["median_trans_deg"]


def test_outputs_are_complete(quick_run):
    out, data = quick_run
    assert data["config"]["methods"] == ["2pt", "5pt-opencv"]
    sweeps = {(r["sweep"], r["tilt_mode"]) for r in data["results"]}
    assert sweeps == {("noise", "none"), ("pitch", "shared"), ("pitch", "independent"),
                      ("roll", "shared"), ("roll", "independent")}
    tm = data["timing"]
    assert tm["median_ms_2pt"] > 0 and tm["ratio_2pt_over_5pt"] == pytest.approx(
        tm["median_ms_2pt"] / tm["median_ms_5pt_opencv"])
    for motion in ("forward", "sideways"):
        png = out / "plots" / f"solvers_{motion}.png"
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_bad_arguments_are_one_line_errors():
    from planar_vo.core.errors import InputError

    parser = argparse.ArgumentParser()
    solvers.add_arguments(parser)
    with pytest.raises(InputError, match="--trials"):
        solvers.main(parser.parse_args(["--trials", "0"]))
