"""The paper's Table 1 experiment: its split, and the script that trains the variants and writes the table,
run on the shared samples (a tiny network, drive 0001 for training and drive 0002 for testing)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from fviz.errors import FvizError
from fviz.train.splits import kitti_items, make_datasets, paper_split_frames
from fviz.train.recipe import load_recipe

PROJECT = Path(__file__).resolve().parents[1]
RECIPE = PROJECT / "recipes" / "paper" / "city_stereo_paper_split.toml"
TINY = ["model.input_size=[32, 96]", "model.width=8", "model.hidden=16", "model.pool_grid=[2, 4]"]


def test_the_papers_split_is_80_10_10_disjoint_and_fixed():
    frames = range(154)
    parts = {p: paper_split_frames("2011_09_26_drive_0005", frames, p) for p in ("train", "val", "test")}
    for part, share in (("train", 0.8), ("val", 0.1), ("test", 0.1)):
        assert abs(len(parts[part]) - share * len(frames)) <= 1, part
    assert set().union(*parts.values()) == set(frames)
    assert sum(map(len, parts.values())) == len(frames)  # disjoint
    assert parts["test"] == paper_split_frames("2011_09_26_drive_0005", frames, "test")  # the same every run
    assert parts["test"] != paper_split_frames("2011_09_26_drive_0013", frames, "test")  # drawn per drive
    assert parts["test"] != set(range(138, 154))  # random frames, not a block


def test_paper_split_items_train_and_validate_on_disjoint_frames(kitti_root):
    recipe = load_recipe(RECIPE, [f"data.root={kitti_root}/raw", "data.roots=[]",
                                  'data.drives=["2011_09_26_drive_0002"]', *TINY])
    train, val = make_datasets(recipe)
    first = lambda ds: {it.frame for it in ds.items}  # noqa: E731
    assert first(train) and first(val) and not first(train) & first(val)
    assert first(train) <= paper_split_frames("2011_09_26_drive_0002", range(10), "train")
    assert {it.kind for it in train.items} == {"stereo"} and {it.cams for it in train.items} == {(0, 1)}
    assert len(kitti_items(recipe, "2011_09_26_drive_0002", "test")) == 2  # one frame, both directions
    with pytest.raises(FvizError, match="leave data.val_sequences empty"):
        make_datasets(load_recipe(RECIPE, [f"data.root={kitti_root}/raw", "data.roots=[]", 'data.drives=["2011_09_26_drive_0002"]',
                                           'data.val_sequences=["2011_09_26_drive_0001"]', *TINY]))


@pytest.mark.slow
def test_the_table_script_trains_evaluates_and_shows_the_constant(kitti_root, tmp_path):
    sets = [f"data.root={kitti_root}/raw", "data.roots=[]", 'data.drives=["2011_09_26_drive_0001"]',
            "data.val_fraction=0.2", *TINY]
    cmd = [sys.executable, str(PROJECT / "benchmarks" / "paper_table1.py"), "--split", "honest", "--variants",
           "siamese-rec-fbn,single-base-etr", "--steps", "3", "--out", str(tmp_path), "--test-drive", "2011_09_26_drive_0002",
           "--learned", "xfeat",  # the cheapest learned matcher: DISK + LightGlue on CPU would take most of the test
           *[a for s in sets for a in ("--set", s)]]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=900, cwd=PROJECT)
    assert r.returncode == 0, r.stdout + r.stderr
    assert (tmp_path / "honest" / "siamese-rec-fbn" / "model.pt").is_file()
    md = (tmp_path / "honest" / "table1.md").read_text()
    cells = [[c.strip() for c in line.split("|")[1:-1]] for line in md.splitlines() if line.startswith("| ") and "---" not in line]
    # paper, A (unrectified frame), B (rectified pixels, unrectified GT), A with fviz's filter, rectified, ÷ GT paper, A, B
    table = {(r[0], r[1]): r[2:] for r in cells if r[0] in ("ETR", "FBN", "ABS")}
    # the network's FBN cells in every reading, none under ABS (no ABS model), the paper's figures beside it
    assert all(table["FBN", "Siamese REC"][1:5]) and table["ABS", "Siamese REC"][1:5] == ["", "", "", ""]
    assert table["FBN", "Siamese REC"][0] == "0.92 / 1.11"
    # an ETR network, trained in the unrectified cameras' frame (model.norm_frame): its cells under every reading
    assert all(table["ETR", "Single-stream Base"][1:5]) and table["ETR", "Single-stream Base"][0] == "4.43 / 34.3"
    # the ground truth: ETR undefined on rectified stereo (F33 = 0), defined under both readings of the paper's frame,
    # where the three norms nearly agree (the paper's 0.05 / 0.004 in every block)
    assert table["ETR", "Ground-truth"][4] == "undefined" and table["ETR", "Ground-truth"][6:8] == ["1 / 1", "1 / 1"]
    assert all(table["ETR", "Ground-truth"][1:4])
    gt = [float(table[n, "Ground-truth"][1].split(" / ")[0]) for n in ("ETR", "FBN", "ABS")]
    assert max(gt) / min(gt) < 1.1 and 0.01 < gt[0] < 0.3
    for row in ("8-point", "LMedS", "RANSAC", "MAGSAC++"):  # estimated F have F33 != 0: every cell defined
        assert all(float(c) >= 0 for n in ("ETR", "FBN", "ABS") for c in table[n, row][1].split(" / ")), row
    assert table["FBN", "MAGSAC++"][0] == "—" and table["FBN", "Siamese EPI"][1:5] == ["", "", "", ""]  # no counterpart either way
    # the second table: drives 0001 and 0002 share one rig, so the training mean F is the test pairs' F
    second = {r[0]: r[1:] for r in cells if r[0] not in ("ETR", "FBN", "ABS", "Norm", "Estimator")}
    epipole_spread, _, epipole, _, failures = second["mean-training drives"]
    assert float(epipole_spread) < 1e-6 and float(epipole) < 1e-6 and failures == "0"
    assert float(second["8point"][0]) > 1e-3  # a real estimator's F moves from pair to pair
    assert all(float(c) >= 0 for c in table["FBN", "xfeat + MAGSAC++"][1].split(" / "))  # a learned matcher's row
