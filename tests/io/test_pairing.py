"""Online colour/depth association against the offline greedy reference (TUM associate.py)."""
import numpy as np
import pytest

from planar_vo.io.pairing import COLOR, DEPTH, Pair, StampPairer, Unpaired


def offline_greedy(cs, ds, tol):
    """Reference: all candidate pairs by increasing |dt|, each stamp used at most once."""
    cands = sorted((abs(c - d), i, j) for i, c in enumerate(cs) for j, d in enumerate(ds) if abs(c - d) <= tol)
    used_c, used_d, pairs = set(), set(), []
    for _, i, j in cands:
        if i not in used_c and j not in used_d:
            used_c.add(i)
            used_d.add(j)
            pairs.append((cs[i], ds[j]))
    return sorted(pairs)


def run_online(cs, ds, tol, max_pending=32):
    events = sorted([(c, COLOR) for c in cs] + [(d, DEPTH) for d in ds])
    p = StampPairer(tol, max_pending=max_pending)
    out = []
    for stamp, side in events:
        out += p.push(side, stamp, stamp)
    return out + p.finish()


@pytest.mark.parametrize("seed", range(6))
def test_matches_offline_greedy_on_jittered_streams(seed):
    rng = np.random.default_rng(seed)
    cs = np.cumsum(rng.uniform(0.025, 0.042, 300))
    ds = np.cumsum(rng.uniform(0.028, 0.040, 300)) + rng.uniform(-0.02, 0.02)
    cs = np.delete(cs, rng.choice(300, 20, replace=False))  # dropped frames
    ds = np.delete(ds, rng.choice(300, 25, replace=False))
    out = run_online(list(cs), list(ds), 0.02)
    pairs = sorted((e.color_stamp, e.depth_stamp) for e in out if isinstance(e, Pair))
    assert pairs == offline_greedy(list(cs), list(ds), 0.02)
    n_uc = sum(isinstance(e, Unpaired) and e.side == COLOR for e in out)
    n_ud = sum(isinstance(e, Unpaired) and e.side == DEPTH for e in out)
    assert (len(pairs) + n_uc, len(pairs) + n_ud) == (len(cs), len(ds))


def test_depth_at_double_rate_picks_nearest():
    cs = [0.0, 0.1, 0.2]
    ds = [-0.03, 0.004, 0.05, 0.098, 0.15, 0.21]
    out = run_online(cs, ds, 0.02)
    assert [(e.color_stamp, e.depth_stamp) for e in out if isinstance(e, Pair)] == \
        [(0.0, 0.004), (0.1, 0.098), (0.2, 0.21)]
    assert sorted(e.stamp for e in out if isinstance(e, Unpaired)) == [-0.03, 0.05, 0.15]


def test_pending_is_bounded_when_tolerance_exceeds_the_period():
    # A 0.1 s tolerance at 30 Hz links every message into one cluster; memory stays capped.
    cs = [i / 30 for i in range(300)]
    ds = [i / 30 + 0.001 for i in range(300)]
    p = StampPairer(0.1, max_pending=8)
    most, pairs = 0, 0
    for stamp, side in sorted([(c, COLOR) for c in cs] + [(d, DEPTH) for d in ds]):
        pairs += sum(isinstance(e, Pair) for e in p.push(side, stamp, None))
        most = max(most, p.pending)
    pairs += sum(isinstance(e, Pair) for e in p.finish())
    assert most <= 9
    assert pairs >= 290  # only the cuts of the forced clusters may lose a pair


def test_stream_that_stops_leaves_the_rest_unpaired():
    out = run_online([i / 30 for i in range(90)], [i / 30 + 0.002 for i in range(30)], 0.02)
    assert sum(isinstance(e, Pair) for e in out) == 30
    assert sum(isinstance(e, Unpaired) and e.side == COLOR for e in out) == 60


def test_payloads_travel_with_their_stamps():
    out = run_online([1.0, 2.0], [1.01, 2.01], 0.02)
    assert [(e.color, e.depth) for e in out] == [(1.0, 1.01), (2.0, 2.01)]


def test_negative_tolerance_rejected():
    with pytest.raises(ValueError, match="tolerance"):
        StampPairer(-1.0)
