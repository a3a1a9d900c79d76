"""Fixtures for the evaluation tests: the real DAVIS-2016 train data (skipped when absent)."""

from __future__ import annotations

from pathlib import Path

import pytest


@pytest.fixture
def shared_davis(shared_data: Path) -> Path:
    """``<shared data>/davis2016-train/DAVIS`` (``$EPONET_SHARED_DATA`` overrides the shared data folder)."""
    root = shared_data / "davis2016-train" / "DAVIS"
    if not (root / "Annotations" / "480p").is_dir():
        pytest.skip(f"real DAVIS-2016 data not found at {root} (set EPONET_SHARED_DATA to the shared data folder)")
    return root
