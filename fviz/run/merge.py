"""Merging the results of several runs (shards of one selection) into one run folder."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from fviz.atomic import replacing
from fviz.errors import FvizError
from fviz.lock import holder_of, locked
from fviz.run.config import _FLAGS, RESULTS_FILE, RUN_FILE, RunConfig, _flatten, _show
from fviz.run.reports import write_reports
from fviz.run.store import ResultStore, RunOutcome, payload_path, read_config, read_records, write_config


def merge_runs(dirs: list[Path], out_dir: Path) -> RunOutcome:
    """Merge the results of shards (or any runs of one configuration) into ``out_dir`` (locked meanwhile)."""
    configs = []
    for d in dirs:
        c = read_config(d)
        if c is None or not (Path(d) / RESULTS_FILE).is_file():
            raise FvizError(f"merge: {d} holds no fviz run ({RUN_FILE} and {RESULTS_FILE} expected)")
        holder = holder_of(Path(d))
        if holder is not None:
            raise FvizError(f"merge: {d} is still being written by {holder}: merge it when that run has finished")
        configs.append(c)
    first = configs[0]
    for d, c in zip(dirs, configs):
        if c.comparable() != first.comparable() or c.estimator_names() != first.estimator_names():
            ours, theirs = _flatten(first.comparable()), _flatten(c.comparable())
            diff = [f"{_FLAGS.get(k, k)} {_show(k, ours.get(k))} in {dirs[0]}, {_show(k, theirs.get(k))} in {d}"
                    for k in sorted(ours.keys() | theirs.keys()) if ours.get(k) != theirs.get(k)]
            if c.estimator_names() != first.estimator_names():
                diff.append(f"--estimator {','.join(first.estimator_names())} in {dirs[0]}, "
                            f"{','.join(c.estimator_names())} in {d}")
            raise FvizError(f"merge: {d} was run with other settings than {dirs[0]}: {'; '.join(diff)}")
    with locked(out_dir):
        return _merge_into(dirs, Path(out_dir), replace(first, shard=None))


def _merge_into(dirs: list[Path], out_dir: Path, config: RunConfig) -> RunOutcome:
    import shutil

    if (out_dir / RESULTS_FILE).exists():
        raise FvizError(f"--out-dir {out_dir} already holds a run: choose an empty folder")
    latest = {}  # key -> Entry; later dirs win
    for d in dirs:
        latest.update(ResultStore(d, config).latest())
    store, failed = ResultStore(out_dir, config), 0
    for rec in read_records(list(latest.values())):
        store.append(rec)
        failed += rec["error"] is not None
        payload = payload_path(latest[rec["key"]].path.parent, rec["index"])
        if payload.is_file():
            with replacing(payload_path(out_dir, rec["index"])) as tmp:
                shutil.copyfile(payload, tmp)
    store.close()
    write_config(out_dir, config)
    outcome = RunOutcome(total=len(config.pairs()), reused=len(latest), computed=0, interrupted=False,
                         out_dir=out_dir, failed=failed)
    outcome.paths = write_reports(out_dir, config)
    return outcome
