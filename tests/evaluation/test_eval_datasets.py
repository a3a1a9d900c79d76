"""Loaders and end-to-end scoring on small synthetic folders of every supported format."""

from __future__ import annotations

import math

import numpy as np
import pytest
from PIL import Image

from .evalkit import make_davis2016, moving_square, save_mask, write_results
from eponet.core.errors import InputError
from eponet.evaluation import (
    evaluate,
    format_report,
    load_dataset,
    locate_results,
    read_ground_truth,
    write_bar_chart,
    write_csv,
    write_json,
)
from eponet.evaluation.metrics import db_eval_iou

INFO = {
    "attributes": ["AC", "DB", "FM", "MB", "OCC"],
    "sequences": [
        {"name": "alpha", "attributes": ["FM", "MB"], "eval_t": True, "set": "train", "num_frames": 8},
        {"name": "beta", "attributes": ["OCC"], "eval_t": False, "set": "val", "num_frames": 6},
    ],
}


@pytest.fixture
def davis16(tmp_path):
    seqs = {"alpha": moving_square(8), "beta": moving_square(6, step=1, start=(20, 20))}
    root = make_davis2016(tmp_path / "DAVIS", seqs, INFO)
    return root, seqs


# ---------------------------------------------------------------------------------------------------------------
# DAVIS-2016
# ---------------------------------------------------------------------------------------------------------------
def test_davis2016_index(davis16):
    root, _ = davis16
    ds = load_dataset("DAVIS-2016", root)
    assert ds.name == "davis2016"
    assert [s.name for s in ds.sequences] == ["alpha", "beta"]
    alpha = ds["alpha"]
    assert alpha.frames == tuple(f"{t:05d}" for t in range(8))
    assert alpha.scored == alpha.frames[1:-1]
    assert alpha.attributes == ("FM", "MB") and alpha.eval_t
    assert not ds["beta"].eval_t
    assert ds.attributes == ("AC", "DB", "FM", "MB", "OCC")


def test_davis2016_split_from_db_info_and_imagesets(davis16, tmp_path):
    root, _ = davis16
    assert [s.name for s in load_dataset("davis2016", root, split="val").sequences] == ["beta"]
    # without db_info, ImageSets/<split>.txt in the DAVIS-2016 "image annotation" pair format
    (root / "db_info.yml").unlink()
    (root / "ImageSets" / "480p").mkdir(parents=True)
    (root / "ImageSets" / "480p" / "val.txt").write_text(
        "/JPEGImages/480p/alpha/00000.jpg /Annotations/480p/alpha/00000.png\n"
        "/JPEGImages/480p/alpha/00001.jpg /Annotations/480p/alpha/00001.png\n")
    ds = load_dataset("davis2016", root, split="val")
    assert [s.name for s in ds.sequences] == ["alpha"]
    assert ds["alpha"].eval_t  # no db_info: T for every sequence
    with pytest.raises(InputError, match="split 'test'"):
        load_dataset("davis2016", root, split="test")


def test_davis2016_errors_name_what_is_wrong(davis16, tmp_path):
    root, _ = davis16
    with pytest.raises(InputError, match="does not exist"):
        load_dataset("davis2016", tmp_path / "nowhere")
    with pytest.raises(InputError, match="unknown dataset 'kitti'"):
        load_dataset("kitti", root)
    with pytest.raises(InputError, match="'gamma'"):
        load_dataset("davis2016", root, sequences=["alpha", "gamma"])
    with pytest.raises(InputError, match=r"Annotations/1080p: no such folder.*480p"):
        load_dataset("davis2016", root, resolution="1080p")


@pytest.mark.parametrize("flavour", ["grey255", "grey01", "rgb", "palette", "greyalpha"])
def test_davis2016_perfect_results_in_every_png_flavour(davis16, tmp_path, flavour):
    root, seqs = davis16
    results = write_results(tmp_path / "res", seqs, layout="flat" if flavour == "rgb" else "masks", flavour=flavour)
    out = evaluate("davis2016", root, results, workers=1)
    for seq in ("alpha", "beta"):
        assert out["sequences"][seq]["J"] == {"mean": 1.0, "recall": 1.0, "decay": 0.0}
        assert out["sequences"][seq]["F"] == {"mean": 1.0, "recall": 1.0, "decay": 0.0}
    assert out["sequences"]["alpha"]["T"]["mean"] == pytest.approx(0.0, abs=1e-12)
    assert out["sequences"]["beta"]["T"]["mean"] is None  # eval_t: false
    assert out["overall"]["J"]["mean"] == 1.0 and out["overall"]["JF"]["mean"] == 1.0


def test_davis2016_first_and_last_frame_are_not_scored(davis16, tmp_path):
    root, seqs = davis16
    res = {k: [m.copy() for m in v] for k, v in seqs.items()}
    for masks in res.values():
        masks[0][:] = 0
        masks[-1][:] = 1
    out = evaluate("davis2016", root, write_results(tmp_path / "res", res), workers=1, compute_t=False)
    assert out["overall"]["J"]["mean"] == 1.0
    # and missing first/last results are fine too: they are never read
    for seq in res:
        (tmp_path / "res" / seq / "masks" / "00000.png").unlink()
    assert evaluate("davis2016", root, tmp_path / "res", workers=1, compute_t=False)["overall"]["J"]["mean"] == 1.0


def test_davis2016_per_sequence_numbers_and_attributes(davis16, tmp_path):
    root, seqs = davis16
    res = {k: [m.copy() for m in v] for k, v in seqs.items()}
    # alpha: frames 1..3 perfect, frames 4..6 empty -> J = [1, 1, 1, 0, 0, 0]
    for t in (4, 5, 6):
        res["alpha"][t][:] = 0
    out = evaluate("davis2016", root, write_results(tmp_path / "res", res), workers=1, compute_t=False,
                   per_frame=True)
    alpha = out["sequences"]["alpha"]
    assert alpha["per_frame"]["J"] == [1, 1, 1, 0, 0, 0]
    assert alpha["J"]["mean"] == pytest.approx(0.5)
    assert alpha["J"]["recall"] == pytest.approx(0.5)
    # 6 values: ids round([1, 2.25, 3.5, 4.75, 6]) - 1 = [0, 1, 3, 4, 5]: bin 0 = [1, 1], bin 3 = [0, 0]
    assert alpha["J"]["decay"] == pytest.approx(1.0)
    assert alpha["F"]["mean"] == pytest.approx(0.5)
    assert out["overall"]["J"]["mean"] == pytest.approx(0.75)
    attrs = out["attributes"]
    assert attrs["FM"] == {"with": 0.5, "without": 1.0, "change": -0.5, "n_with": 1, "n_without": 1}
    assert attrs["OCC"]["with"] == 1.0
    assert attrs["AC"]["with"] is None and attrs["AC"]["n_with"] == 0


def test_missing_results_are_named(davis16, tmp_path):
    root, seqs = davis16
    results = write_results(tmp_path / "res", {"alpha": seqs["alpha"]})
    with pytest.raises(InputError, match=r"missing results: sequence 'beta' \(no folder"):
        evaluate("davis2016", root, results, workers=1)
    write_results(results, {"beta": seqs["beta"]})
    (results / "alpha" / "masks" / "00003.png").unlink()
    (results / "alpha" / "masks" / "00005.png").unlink()
    with pytest.raises(InputError, match=r"sequence 'alpha' frame\(s\) 00003, 00005 \(2 of 6 scored frames"):
        locate_results(load_dataset("davis2016", root), results)


def test_result_of_another_size_is_an_error_naming_the_file(davis16, tmp_path):
    root, seqs = davis16
    results = write_results(tmp_path / "res", seqs)
    save_mask(results / "beta" / "masks" / "00002.png", np.zeros((24, 32), np.uint8))
    with pytest.raises(InputError, match=r"beta/masks/00002.png: result is 32x24 but the ground truth .* 64x48"):
        evaluate("davis2016", root, results, workers=1, compute_t=False)


def test_pool_and_inline_give_the_same_numbers(tmp_path):
    seqs = {"long": moving_square(60, shape=(40, 56), size=10, step=0)}
    root = make_davis2016(tmp_path / "D", seqs)
    res = {"long": [np.roll(m, t % 3, axis=1) for t, m in enumerate(seqs["long"])]}
    results = write_results(tmp_path / "res", res)
    a = evaluate("davis2016", root, results, workers=1)
    b = evaluate("davis2016", root, results, workers=2)
    assert a["sequences"] == b["sequences"]


# ---------------------------------------------------------------------------------------------------------------
# DAVIS-2017 unsupervised
# ---------------------------------------------------------------------------------------------------------------
def _davis17(tmp_path):
    root = tmp_path / "DAVIS17"
    gts = []
    for t in range(5):
        lab = np.zeros((40, 60), np.uint8)
        lab[5:15, 5 + t : 20 + t] = 1
        lab[22:35, 30:45] = 2
        lab[0:3, :] = 255  # void band
        gts.append(lab)
        save_mask(root / "Annotations_unsupervised" / "480p" / "duo" / f"{t:05d}.png", lab, "palette")
    (root / "ImageSets" / "2017").mkdir(parents=True)
    (root / "ImageSets" / "2017" / "val.txt").write_text("duo\n")
    return root, gts


def test_davis2017_matches_objects_and_ignores_void(tmp_path):
    root, gts = _davis17(tmp_path)
    ds = load_dataset("davis2017", root, split="val")
    assert ds["duo"].scored == ds["duo"].frames  # every frame is scored
    labels, void = read_ground_truth("labels", ds["duo"].gt["00000"])
    assert void[0:3].all() and not void[3:].any() and labels.max() == 2
    preds = []
    for lab in gts:
        p = np.zeros_like(lab)
        p[lab == 1] = 3  # ids swapped and renumbered
        p[lab == 2] = 1
        p[0:3, 0:30] = 1  # garbage inside the void band only
        p[36:40, 0:4] = 2  # an extra proposal
        preds.append(p)
    results = write_results(tmp_path / "res", {"duo": preds}, flavour="palette")
    out = evaluate("davis2017", root, results, workers=1)
    seq = out["sequences"]["duo"]
    assert set(seq["objects"]) == {"1", "2"}
    assert seq["objects"]["1"]["matched_id"] == 3 and seq["objects"]["2"]["matched_id"] == 1
    assert seq["objects"]["1"]["J"]["mean"] == 1.0 and seq["objects"]["2"]["F"]["mean"] == 1.0
    assert out["overall"]["JF"]["mean"] == 1.0 and out["overall"]["n_objects"] == 2
    _check_reports(out, tmp_path)


def _check_reports(out, tmp_path):
    text = format_report(out)
    assert "J  Mean" in text and "T  Mean" not in text  # T is DAVIS-2016 only
    write_json(out, tmp_path / "r.json")
    write_csv(out, tmp_path / "r.csv")
    write_bar_chart(out, tmp_path / "r.png")
    assert (tmp_path / "r.png").stat().st_size > 0 and "T_mean" not in (tmp_path / "r.csv").read_text()


def test_davis2017_missing_object_scores_zero_and_too_many_ids_fail(tmp_path):
    root, gts = _davis17(tmp_path)
    preds = [np.where(lab == 1, 1, 0).astype(np.uint8) for lab in gts]  # object 2 never predicted
    out = evaluate("davis2017", root, write_results(tmp_path / "res", {"duo": preds}), workers=1)
    assert out["sequences"]["duo"]["objects"]["1"]["J"]["mean"] == 1.0
    assert out["sequences"]["duo"]["objects"]["2"]["J"]["mean"] == 0.0
    assert out["overall"]["J"]["mean"] == pytest.approx(0.5)
    bad = [p.copy() for p in preds]
    bad[2][30:32, 50:52] = 21
    write_results(tmp_path / "res2", {"duo": bad})
    with pytest.raises(InputError, match=r"00002.png: object id 21"):
        evaluate("davis2017", root, tmp_path / "res2", workers=1)


# ---------------------------------------------------------------------------------------------------------------
# SegTrack-v2
# ---------------------------------------------------------------------------------------------------------------
def test_segtrack_merges_objects_from_subfolders(tmp_path):
    root = tmp_path / "SegTrackv2"
    one, a, b = [], [], []
    for t in range(4):
        m = np.zeros((30, 40), np.uint8)
        m[5:15, 5:15] = 1
        one.append(m)
        save_mask(root / "GroundTruth" / "single" / f"frame{t + 1}.png", m, "rgb")
        ma = np.zeros((30, 40), np.uint8)
        ma[2:10, 2:10] = 1
        mb = np.zeros((30, 40), np.uint8)
        mb[15:25, 20:36] = 1
        a.append(ma)
        b.append(mb)
        save_mask(root / "GroundTruth" / "pair" / "1" / f"pair_{t:03d}.png", ma, "grey255")
        save_mask(root / "GroundTruth" / "pair" / "2" / f"pair_{t:03d}.bmp", mb, "grey255")
    ds = load_dataset("segtrack-v2", root)
    assert [s.name for s in ds.sequences] == ["pair", "single"]
    assert ds["single"].frames == ("frame1", "frame2", "frame3", "frame4")
    assert len(ds["pair"].gt["pair_000"]) == 2
    union = [x | y for x, y in zip(a, b)]
    results = write_results(tmp_path / "res", {"single": one}, layout="flat", names=list(ds["single"].frames))
    write_results(results, {"pair": a}, names=list(ds["pair"].frames))  # only object 1 predicted
    out = evaluate("segtrackv2", root, results, workers=1)
    assert out["sequences"]["single"]["J"]["mean"] == 1.0
    expected = db_eval_iou(a[0], union[0])
    assert expected == pytest.approx(64 / (64 + 160))
    assert out["sequences"]["pair"]["J"]["mean"] == pytest.approx(expected)
    assert out["overall"]["J"]["mean"] == pytest.approx((1.0 + expected) / 2)
    assert "F" not in out["sequences"]["pair"] and "T" not in out["overall"]
    _check_reports(out, tmp_path)


# ---------------------------------------------------------------------------------------------------------------
# FBMS-59
# ---------------------------------------------------------------------------------------------------------------
def test_fbms_sparse_ground_truth(tmp_path):
    root = tmp_path / "FBMS"
    seq = root / "Testset" / "cars1"
    masks = moving_square(5, shape=(36, 48), size=10)
    seq.mkdir(parents=True)
    for t in range(5):
        Image.fromarray(np.full((36, 48, 3), 90, np.uint8)).save(seq / f"cars1_{t + 1:02d}.jpg")
    # annotated frames 1 and 4 (1-based names); white background, object grey 128, in PGM
    for t in (0, 3):
        lab = np.where(masks[t] > 0, 128, 255).astype(np.uint8)
        save_mask(seq / "GroundTruth" / f"cars1_{t + 1:02d}_gt.pgm", lab, "pgm")
    save_mask(seq / "GroundTruth" / "cars1_01_gtPROB.pgm", np.zeros((36, 48), np.uint8), "pgm")
    ds = load_dataset("fbms", root, split="test")
    cars = ds["cars1"]
    assert len(cars.frames) == 5
    assert cars.scored == ("cars1_01", "cars1_04")
    gt, _ = read_ground_truth(cars.gt_mode, cars.gt["cars1_04"])
    assert (gt == masks[3].astype(bool)).all()  # the white background is recognised
    results = tmp_path / "res"
    save_mask(results / "cars1" / "cars1_01.png", masks[0])
    save_mask(results / "cars1" / "cars1_04.png", np.zeros((36, 48), np.uint8))
    out = evaluate("fbms59", root, results, workers=1)
    assert out["sequences"]["cars1"]["n_frames"] == 2
    assert out["sequences"]["cars1"]["J"]["mean"] == pytest.approx(0.5)
    (results / "cars1" / "cars1_04.png").unlink()
    with pytest.raises(InputError, match=r"sequence 'cars1' frame\(s\) cars1_04"):
        evaluate("fbms59", root, results, workers=1)


# ---------------------------------------------------------------------------------------------------------------
# Generic frames folder + masks folder
# ---------------------------------------------------------------------------------------------------------------
def test_generic_folder_pair(tmp_path):
    frames_dir = tmp_path / "frames"
    frames_dir.mkdir()
    masks = moving_square(6, shape=(30, 40), size=8)
    for t in range(6):
        Image.fromarray(np.zeros((30, 40, 3), np.uint8)).save(frames_dir / f"img{t}.jpg")
    gt_dir = tmp_path / "gt"
    for t in (0, 2, 5):  # sparse ground truth
        save_mask(gt_dir / f"img{t}.png", masks[t], "grey01")
    ds = load_dataset("folders", gt_dir, frames=frames_dir)
    (seq,) = ds.sequences
    assert seq.name == "gt" and len(seq.frames) == 6 and seq.scored == ("img0", "img2", "img5")
    res = tmp_path / "out"
    for t in (0, 2, 5):
        save_mask(res / "masks" / f"img{t}.png", masks[t], "palette")
    out = evaluate("generic", gt_dir, res, frames=frames_dir, workers=1)
    assert out["overall"]["J"]["mean"] == 1.0 and out["overall"]["F"]["mean"] == 1.0
    save_mask(gt_dir / "img9.png", masks[0])
    with pytest.raises(InputError, match="img9.png: ground truth for frame 'img9', which is not among the frames"):
        load_dataset("folders", gt_dir, frames=frames_dir)


def test_nan_free_json_values(davis16, tmp_path):
    root, seqs = davis16
    out = evaluate("davis2016", root, write_results(tmp_path / "res", seqs), workers=1, compute_t=False)

    def walk(v):
        if isinstance(v, dict):
            for x in v.values():
                walk(x)
        elif isinstance(v, list):
            for x in v:
                walk(x)
        elif isinstance(v, float):
            assert math.isfinite(v)

    walk(out)
    assert out["overall"]["T"]["mean"] is None
