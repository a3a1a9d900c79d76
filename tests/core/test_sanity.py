"""The per-sequence warnings for what the method cannot segment: nothing moving, a mask over the whole frame."""

import json
import logging

import numpy as np

from eponet.core.pipeline import Pipeline
from eponet.core.sanity import COVER_FRACTION, STILL_FLOW_PX, SequenceChecks, frame_ranges
from eponet.core.spec import parse_spec
from tests.conftest import textured_frames, write_frames


def test_frame_ranges_known_answers():
    assert frame_ranges([]) == ""
    assert frame_ranges([4]) == "4"
    assert frame_ranges([0, 1, 2, 5, 7, 8]) == "0-2, 5, 7-8"


def test_checks_name_the_still_and_the_covered_frames(caplog):
    checks = SequenceChecks("clip")
    still = np.zeros((20, 30, 2), np.float32)
    moving = np.full((20, 30, 2), 2.0, np.float32)
    full = np.ones((40, 60), np.uint8)
    half = np.zeros((40, 60), np.uint8)
    half[:, :30] = 255
    for t in range(6):
        checks.observe(t, still if t in (1, 2) else moving, full if t >= 4 else half)
    # a frame just over the flow threshold at its 99th percentile is not still
    barely = np.zeros((20, 30, 2), np.float32)
    barely[:, :3, 0] = 2 * STILL_FLOW_PX  # 10% of the pixels move
    checks.observe(6, barely, half)
    with caplog.at_level(logging.WARNING):
        record = checks.finish()
    assert record["still_frames"] == [1, 2]
    assert record["covered_frames"] == [4, 5]
    assert record["mask_coverage"] == round((2 * 1.0 + 5 * 0.5) / 7, 4)
    assert "clip: frames 1-2: nothing moves" in caplog.text
    assert f"clip: frames 4-5: the mask covers more than {round(100 * COVER_FRACTION)}%" in caplog.text


def test_checks_are_silent_on_an_ordinary_sequence(caplog):
    checks = SequenceChecks("clip")
    mask = np.zeros((40, 60), np.uint8)
    mask[10:20, 10:20] = 255
    with caplog.at_level(logging.WARNING):
        checks.observe(0, np.full((20, 30, 2), 1.0, np.float32), mask)
        assert checks.finish() == {"mask_coverage": round(100 / 2400, 4)}
    assert caplog.text == ""


def test_a_video_where_nothing_moves_gives_empty_masks_finite_maps_and_a_warning(tmp_path, caplog):
    frames = np.repeat(textured_frames(1, size=(64, 96)), 6, axis=0)
    write_frames(tmp_path / "still", frames)
    spec = parse_spec({"preset": "epo", "input": {"path": str(tmp_path / "still")},
                       "output": {"dir": str(tmp_path / "out"), "save": ["masks", "ed", "saliency"]},
                       "cache": {"enabled": False}})
    with caplog.at_level(logging.WARNING):
        Pipeline(spec).run()
    entry = json.loads((tmp_path / "out" / "run.json").read_text())["sequences"]["still"]
    assert entry["still_frames"] == list(range(6)), entry
    assert entry["mask_coverage"] < 0.005, entry  # (a stray pixel of the CRF at most)
    assert entry["triplets"]["models"] == {"static": entry["triplets"]["count"]}
    assert "still: frames 0-5: nothing moves" in caplog.text
    seq = tmp_path / "out" / "still"
    for t in range(6):
        ed = np.load(seq / "ed" / f"{t:05d}.npy")
        assert np.isfinite(ed).all() and ed.max() < 0.1
