"""Edit -> re-estimated and redrawn (issue 42, item 1): target 150 ms for fviz's part, MAGSAC++ on a KITTI pair with
~1,000 matches, side by side with a full re-evaluation (features, matching, estimation, drawing) in the same run.

    python benchmarks/bench_edit.py [--edits 20] [--estimators magsac]

Per edit (one match excluded, then restored: every edit changes the match set): the page's command in -> the bytes
of the redrawn pair out (:class:`fviz.web.server.ClickApp` with an editor: re-estimation, scoring, diagnosis, verdict,
the pair's entities logged and encoded), median and p90; then the same split into re-estimation alone and drawing.
The baseline: ``fviz.inspect_pair`` from the images + ``fviz.log_result`` (what a user did before: run inspect again).
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from common import KITTI_ROOT


def stats(name: str, xs: list[float]) -> float:
    ms = sorted(1000 * x for x in xs)
    med = statistics.median(ms)
    print(f"{name}: median {med:.1f} ms, p90 {ms[int(0.9 * (len(ms) - 1))]:.1f} ms (n={len(ms)})")
    return med


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--edits", type=int, default=20)
    ap.add_argument("--estimators", nargs="+", default=["magsac"])
    ap.add_argument("--max-keypoints", type=int, default=3000)
    args = ap.parse_args()
    import rerun as rr

    import fviz
    from fviz.web.server import ClickApp

    pair = fviz.load_pair(KITTI_ROOT, sequence="00", frame=3, kind="temporal")
    base = fviz.inspect_pair(pair, args.estimators, max_keypoints=args.max_keypoints)
    print(f"KITTI 00 temporal 3->4: {base.n_matches} matches; estimators {', '.join(args.estimators)}")
    path = fviz.save_recording(Path(tempfile.mkdtemp()) / "pair.rrd", pair, base)

    def editor(rec, clicks):
        ed = fviz.edit(pair, base, rec)
        ed.clicks = clicks
        return ed

    app = ClickApp(path, editor=editor)
    _, answer = app.new_connection()
    for i in range(args.edits):
        op = "exclude" if i % 2 == 0 else "restore"
        out = answer(json.dumps({"fviz_edit": {"op": op, "matches": [i // 2]}}))
        assert any(isinstance(o, bytes) for o in out) and json.loads(out[-1])["fviz"] == "edit"
    edit_ms = stats("page: edit command -> redrawn pair's bytes", list(app.timings)[1:])

    keep = np.ones(base.n_matches, bool)
    est, draw = [], []
    rec = rr.RecordingStream("bench-edit")
    stream = rec.binary_stream()
    for i in range(args.edits):
        keep[i] = False
        t0 = time.perf_counter()
        r = fviz.reestimate(pair, base, keep)
        t1 = time.perf_counter()
        fviz.log_result(rec, pair, r)
        stream.read(flush=True)
        est.append(t1 - t0)
        draw.append(time.perf_counter() - t1)
    stats("  re-estimation alone (fviz.reestimate)", est)
    stats("  drawing alone (fviz.log_result, encoded)", draw)

    full = []
    for _ in range(max(3, args.edits // 5)):
        t0 = time.perf_counter()
        r = fviz.inspect_pair(pair, args.estimators, max_keypoints=args.max_keypoints)
        fviz.log_result(rec, pair, r)
        stream.read(flush=True)
        full.append(time.perf_counter() - t0)
    full_ms = stats("baseline: inspect_pair from the images + log_result", full)
    print(f"ratio edit / full re-evaluation: {edit_ms / full_ms:.2f}; target: edit <= 150 ms "
          f"({'met' if edit_ms <= 150 else 'NOT met'} on this machine)")


if __name__ == "__main__":
    main()
