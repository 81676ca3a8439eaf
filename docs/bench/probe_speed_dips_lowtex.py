"""python docs/bench/probe_speed_dips_lowtex.py OUT CACHE [A-B]: the first two low- or no-texture
(seed, layout) pairs of seeds A-B (default 7700-7799) per layout, with speed dips, rendered and run by
``bench sweep``'s own ``run_one`` and summarised by its ``summarise`` / ``format_markdown``
(sweep_speed_dips_lowtex_7700-7799_session41.md; run that stop under the name probe_dips.py)."""
import sys, json
from pathlib import Path
from concurrent.futures import ProcessPoolExecutor, as_completed
from planar_vo.sim.synth_random import randomized_config
from planar_vo.bench.sweep import run_one, summarise, format_summary, format_markdown
from planar_vo.io.atomic import write_text_atomic
out, cache = sys.argv[1], sys.argv[2]
lo, hi = (int(v) for v in (sys.argv[3] if len(sys.argv) > 3 else "7700-7799").split("-"))
Path(out).mkdir(parents=True, exist_ok=True); Path(cache).mkdir(parents=True, exist_ok=True)
pick = {}
for seed in range(lo, hi + 1):
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
cmd = f"python docs/bench/probe_speed_dips_lowtex.py OUT CACHE {lo}-{hi} (first two low/no-texture pairs per layout, --speed-dips)"
write_text_atomic(Path(out, "sweep.json"), json.dumps({"command": cmd, "summary": summary, "logs": recs}, indent=1, default=float) + "\n")
write_text_atomic(Path(out, "sweep.md"), format_markdown(summary, recs, cmd))
