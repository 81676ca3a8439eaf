"""probe_dips.py OUT CACHE: the first two low- or no-texture (seed, layout) pairs of seeds
7700-7799 per layout, with speed dips, rendered and run as bench sweep does (same code path)."""
import sys, json
from pathlib import Path
from concurrent.futures import ProcessPoolExecutor, as_completed
from planar_vo.sim.synth_random import randomized_config
from planar_vo.bench.sweep import run_one, summarise, format_summary, format_markdown
out, cache = sys.argv[1], sys.argv[2]
Path(out).mkdir(parents=True, exist_ok=True); Path(cache).mkdir(parents=True, exist_ok=True)
pick = {}
for seed in range(7700, 7800):
    for lay in ("straight", "lturn", "loop", "two_frames", "hall"):
        if len(pick.setdefault(lay, [])) < 2 and randomized_config(seed, lay, speed_dips=True).texture in ("none", "low"):
            pick[lay].append(seed)
jobs = [(s, lay) for lay, ss in pick.items() for s in ss]
print("probe:", jobs, flush=True)
recs = []
with ProcessPoolExecutor(2) as pool:
    futs = [pool.submit(run_one, s, lay, None, cache, out, None, True) for s, lay in jobs]
    for f in as_completed(futs):
        r = f.result(); recs.append(r)
        print(r.get("name"), r["status"], r.get("motion"), "raw %.2f sm %.2f" % (r.get("raw_drift_pct", -1), r.get("smoothed_drift_pct", -1)), r.get("steps"), flush=True)
summary = summarise(recs)
print(format_summary(summary))
cmd = "python probe_dips.py (first two low/no-texture pairs per layout of seeds 7700-7799, --speed-dips)"
Path(out, "sweep.json").write_text(json.dumps({"command": cmd, "summary": summary, "logs": recs}, indent=1, default=float) + "\n")
Path(out, "sweep.md").write_text(format_markdown(summary, recs, cmd))
