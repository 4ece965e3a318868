"""fviz runs from Python: evaluate a few KITTI pairs with two estimators, triage the run, compare the two
estimators pair by pair, and make the paper's table; what ``fviz eval``, ``triage``, ``compare`` and ``table`` do.

    FVIZ_KITTI_ROOT=/path/to/kitti python examples/runs.py [RUN_DIR]

Uses only the public API (``import fviz``) on KITTI odometry 00 (the shared samples: ``$FVIZ_KITTI_ROOT``,
default ``../shared/data/kitti`` beside this repository). The run folder keeps every report: summary.md,
triage.md / triage.rrd, compare.md / compare.rrd, table.md (open a recording with ``fviz open``).
"""

import os
import sys
import tempfile
from pathlib import Path

import fviz

root = Path(os.environ.get("FVIZ_KITTI_ROOT", Path(__file__).resolve().parents[2] / "shared" / "data" / "kitti"))
out_dir = Path(sys.argv[1] if len(sys.argv) > 1 else tempfile.mkdtemp(prefix="fviz-runs-")) / "run"

# 1. Which pairs: frames 0..2 of odometry 00, stereo (camera 0 -> 1) and temporal (frame t -> t+1) pairs.
pairs = fviz.select(root, sequence="00", frames=(0, 3), kinds=("stereo", "temporal"))

# 2. Evaluate two estimators on each pair into the run folder (results.jsonl, metrics.csv, summary.md, eval.rrd).
run = fviz.evaluate_run(pairs, out_dir, estimators=("8point", "magsac"), max_keypoints=500, workers=1)
print(f"evaluated {run.outcome.computed} pairs into {run.out_dir}")
for name, f in run.summary["estimators"].items():
    print(f"{name:8s} median SED {f['sed_median']:.3g} px, pose AUC@10 {f['pose_auc']['10']:.3g}")

# 3. Triage: the pairs ranked worst first by 8point's median SED, with likely causes (triage.md, triage.rrd).
triage = fviz.triage_run(run, by="8point", top=3)
for r in triage.ranked[:3]:
    value = "error (no F)" if r.failed else f"{r.value:.3g} px"
    print(f"worst #{r.rank}: {r.key} sed_median {value} ({', '.join(tag for tag, _ in r.tags) or 'no tag'})")

# 4. Compare the two estimators pair by pair (compare.md, compare.rrd).
c = fviz.compare_runs(run, estimators=("8point", "magsac"))
print(f"8point vs magsac: {len(c.wins)} wins, {len(c.losses)} losses, {len(c.ties)} ties; {c.markdown}")

# 5. The paper's table (table.md, table.csv), and the run read back from its folder.
md, csv = fviz.run_table(run)
print(md.read_text().splitlines()[0])
again = fviz.read_run(out_dir)
print(f"read back: {len(list(again.records()))} pairs, estimators {', '.join(again.estimators)}")
