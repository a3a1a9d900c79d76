"""Mean / Recall / Decay on hand-made sequences (DAVIS rules: strict recall, 4 overlapping bins, MATLAB round)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from eponet.evaluation.stats import davis2016_scored, decay, decay_bins, mean, recall, sequence_statistics


def test_decay_bins_ten_values():
    # linspace(1, 10, 5) = [1, 3.25, 5.5, 7.75, 10] -> round -> [1, 3, 6, 8, 10] -> ids [0, 2, 5, 7, 9]
    assert decay_bins(10) == [slice(0, 3), slice(2, 6), slice(5, 8), slice(7, 10)]


def test_decay_bins_round_half_up_like_matlab():
    # n = 3: linspace = [1, 1.5, 2, 2.5, 3] -> MATLAB round [1, 2, 2, 3, 3] (banker's rounding would give 2 at 2.5)
    assert decay_bins(3) == [slice(0, 2), slice(1, 2), slice(1, 3), slice(2, 3)]
    # n = 7: [1, 2.5, 4, 5.5, 7] -> [1, 3, 4, 6, 7] -> ids [0, 2, 3, 5, 6]
    assert decay_bins(7) == [slice(0, 3), slice(2, 4), slice(3, 6), slice(5, 7)]


def test_decay_hand_made_sequence():
    v = [0.9, 0.8, 0.7, 0.6, 0.5, 0.4, 0.3, 0.2, 0.1, 0.0]
    # bin 0 = v[0:3] -> 0.8 ; bin 3 = v[7:10] -> 0.1
    assert decay(v) == pytest.approx(0.7)
    v7 = [0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6]
    # bin 0 = v[0:3] -> 0.1 ; bin 3 = v[5:7] -> 0.55
    assert decay(v7) == pytest.approx(-0.45)


def test_decay_constant_is_zero_and_single_value():
    assert decay([0.7] * 12) == pytest.approx(0.0)
    assert decay([0.4]) == 0.0
    assert math.isnan(decay([]))


def test_recall_is_strictly_above_half():
    assert recall([0.5, 0.5, 0.51, 0.9]) == 0.5
    assert recall([0.2, float("nan"), 0.8, 0.6]) == 0.5  # NaN counts as a miss


def test_mean_ignores_nan():
    assert mean([0.2, float("nan"), 0.4]) == pytest.approx(0.3)
    assert math.isnan(mean([float("nan")]))


def test_davis2016_drops_first_and_last_frame():
    per_frame = np.array([0.0, 0.9, 0.8, 0.7, 0.6, 0.5, 0.4, 0.3, 0.2, 0.1, 0.0, 1.0])
    scored = per_frame[davis2016_scored(len(per_frame))]
    assert scored.tolist() == [0.9, 0.8, 0.7, 0.6, 0.5, 0.4, 0.3, 0.2, 0.1, 0.0]
    s = sequence_statistics(scored)
    assert s["mean"] == pytest.approx(0.45)
    assert s["recall"] == pytest.approx(0.4)  # 0.9, 0.8, 0.7, 0.6
    assert s["decay"] == pytest.approx(0.7)
