"""On the real DAVIS-2016 train annotations: ground truth against itself, eroded and shifted ground truth."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.ndimage as ndi

from .evalkit import save_mask
from eponet.core.io import read_mask
from eponet.evaluation import evaluate, load_dataset
from eponet.evaluation.metrics import db_eval_iou, db_eval_t


def test_bear_00077_grey_alpha_reads_like_its_neighbours(shared_davis):
    folder = shared_davis / "Annotations" / "480p" / "bear"
    m77 = read_mask(folder / "00077.png")
    m76 = read_mask(folder / "00076.png")
    assert m77.shape == (480, 854) and set(np.unique(m77)) == {0, 1}
    assert db_eval_iou(m77, m76) > 0.9


def test_index_of_the_30_train_sequences(shared_davis):
    ds = load_dataset("davis2016", shared_davis)
    assert len(ds.sequences) == 30
    assert ds["bear"].eval_t and ds["bear"].attributes == ("DEF",)
    assert len(ds["bear"].frames) == 82 and len(ds["bear"].scored) == 80
    assert "OCC" in ds.attributes
    assert [s.name for s in load_dataset("davis2016", shared_davis, split="train").sequences] == \
        [s.name for s in ds.sequences]


def test_ground_truth_against_itself_scores_one(shared_davis):
    results = shared_davis / "Annotations" / "480p"  # <seq>/<frame>.png: the flat results layout
    out = evaluate("davis2016", shared_davis, results, sequences=["dog-agility", "rollerblade", "motorbike"],
                   compute_t=False)
    for entry in out["sequences"].values():
        assert entry["J"] == {"mean": 1.0, "recall": 1.0, "decay": 0.0}
        assert entry["F"] == {"mean": 1.0, "recall": 1.0, "decay": 0.0}
    assert out["overall"]["J"]["mean"] == 1.0 and out["overall"]["F"]["mean"] == 1.0
    assert "MB" in out["attributes"]


def test_eroded_and_shifted_ground_truth_order(shared_davis, tmp_path):
    seq = "rollerblade"
    folder = shared_davis / "Annotations" / "480p" / seq
    files = sorted(folder.glob("*.png"))
    variants = {"erode2": [], "erode10": [], "shift4": [], "shift24": []}
    for path in files:
        gt = read_mask(path).astype(bool)
        variants["erode2"].append(ndi.binary_erosion(gt, iterations=2))
        variants["erode10"].append(ndi.binary_erosion(gt, iterations=10))
        variants["shift4"].append(np.roll(gt, 4, axis=1))
        variants["shift24"].append(np.roll(gt, 24, axis=1))
    scores = {}
    for name, masks in variants.items():
        for path, m in zip(files, masks):
            save_mask(tmp_path / name / seq / "masks" / path.name, m)
        out = evaluate("davis2016", shared_davis, tmp_path / name, sequences=[seq], compute_t=False)
        scores[name] = out["overall"]
    j = {k: v["J"]["mean"] for k, v in scores.items()}
    f = {k: v["F"]["mean"] for k, v in scores.items()}
    assert 1.0 > j["erode2"] > j["erode10"]
    assert 1.0 > j["shift4"] > j["shift24"]
    # a 4 px shift keeps every boundary within the 8 px tolerance: F stays 1 while J drops
    assert f["shift4"] == 1.0 and f["shift24"] < 1.0
    # a 2 px erosion moves boundaries by <= 2 px but deletes structures thinner than 4 px (skates, fingers),
    # whose ground-truth boundary then has no predicted boundary nearby
    assert 1.0 > f["erode2"] > 0.98 > f["erode10"]
    assert j["shift24"] < j["shift4"] and scores["shift24"]["J"]["recall"] <= scores["shift4"]["J"]["recall"]


def test_t_on_real_masks_orders_stable_before_jittered(shared_davis):
    folder = shared_davis / "Annotations" / "480p" / "dog-agility"
    masks = [read_mask(p) for p in sorted(folder.glob("*.png"))[10:14]]
    gt_t = [db_eval_t(a, b) * 5 for a, b in zip(masks[:-1], masks[1:])]
    rng = np.random.default_rng(0)
    jittered = []
    for m in masks:
        blur = ndi.gaussian_filter(rng.random(m.shape), 3)
        noise = blur > np.quantile(blur, 0.85)
        jittered.append((m.astype(bool) ^ (noise & ndi.binary_dilation(m, iterations=12))))
    jit_t = [db_eval_t(a, b) * 5 for a, b in zip(jittered[:-1], jittered[1:])]
    assert np.all(np.isfinite(gt_t)) and np.all(np.isfinite(jit_t))
    assert np.mean(jit_t) > np.mean(gt_t)


@pytest.mark.slow
def test_ground_truth_with_t_on_several_sequences(shared_davis):
    seqs = ["car-turn", "lucia", "bmx-bumps"]
    out = evaluate("davis2016", shared_davis, shared_davis / "Annotations" / "480p", sequences=seqs)
    assert out["overall"]["J"]["mean"] == 1.0 and out["overall"]["F"]["mean"] == 1.0
    t = out["overall"]["T"]["mean"]
    assert t is not None and 0.0 <= t < 0.2
    eval_t = {s.name: s.eval_t for s in load_dataset("davis2016", shared_davis, sequences=seqs).sequences}
    assert not eval_t["bmx-bumps"] and out["sequences"]["bmx-bumps"]["T"]["mean"] is None
    for name, entry in out["sequences"].items():
        assert (entry["T"]["mean"] is not None) == eval_t[name]
    assert set(out["attributes"]) >= {"AC", "DB", "FM", "MB", "OCC"}
