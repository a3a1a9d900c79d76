import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from eponet.core.errors import MissingWeights
from eponet.nets import EpoUNet
from eponet.plugins.motion_net.epo_unet import EpoUNetStage

ROOT = Path(__file__).resolve().parents[3]


def _save(path: Path, **config) -> Path:
    model = EpoUNet(**config)
    torch.save({"config": model.config, "state_dict": model.state_dict(), "meta": {}}, path)
    return path


def test_batched_inference_at_odd_sizes_gives_probabilities(tmp_path):
    path = _save(tmp_path / "w.pt", depth=3, widths=(4, 8, 8), head_channels=8)
    stage = EpoUNetStage(weights=str(path), batch_size=2, device="cpu")
    motion = np.random.default_rng(0).random((5, 3, 37, 53), dtype=np.float32)
    out = stage.predict(motion)
    assert out.shape == (5, 37, 53) and out.dtype == np.float32
    assert 0 <= out.min() and out.max() <= 1
    # batching does not change the answer (BatchNorm in eval mode)
    single = EpoUNetStage(weights=str(path), batch_size=1, device="cpu").predict(motion)
    np.testing.assert_allclose(out, single, atol=1e-5)


def test_flip_averages_with_the_mirrored_video_and_is_mirror_symmetric(tmp_path):
    path = _save(tmp_path / "w.pt", depth=2, widths=(4, 8), head_channels=4)
    motion = np.random.default_rng(1).random((3, 3, 21, 34), dtype=np.float32) - 0.5
    plain = EpoUNetStage(weights=str(path), device="cpu").predict(motion)
    flip = EpoUNetStage(weights=str(path), device="cpu", flip=True)
    mirrored = motion[..., ::-1].copy()
    mirrored[:, 0] *= -1  # the motion images of the mirrored video: columns reversed, dx negated
    on_mirror = EpoUNetStage(weights=str(path), device="cpu").predict(mirrored)
    np.testing.assert_allclose(flip.predict(motion), 0.5 * (plain + on_mirror[..., ::-1]), atol=1e-6)
    # the averaged prediction of the mirrored video is the mirror of the averaged prediction
    np.testing.assert_allclose(flip.predict(mirrored), flip.predict(motion)[..., ::-1], atol=1e-6)
    assert np.abs(plain - on_mirror[..., ::-1]).max() > 1e-3  # the untrained network is not symmetric by itself


def test_checksum_mismatch_and_missing_file_are_clear_errors(tmp_path):
    path = _save(tmp_path / "w.pt", depth=2, widths=(4, 8), head_channels=4)
    with pytest.raises(MissingWeights, match="checksum mismatch"):
        EpoUNetStage(weights=str(path), sha256="0" * 64)
    with pytest.raises(MissingWeights, match="not found"):
        EpoUNetStage(weights=str(tmp_path / "absent.pt"))
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(MissingWeights, match="not EpO U-Net weights"):
        EpoUNetStage(weights=str(tmp_path / "junk.pt"))


def test_shipped_weights_match_their_catalogue_checksum_and_stay_small():
    from tests.conftest import assert_shipped_weights

    assert_shipped_weights("epo-davis", "motion_net")
    assert_shipped_weights("epo-davis-v3", "motion_net")
    EpoUNetStage()  # the default loads the built-in weights


def test_epo_preset_on_the_embedded_demo_reaches_the_target_j(tmp_path):
    out = tmp_path / "demo"
    result = subprocess.run(
        [sys.executable, "-m", "eponet.run", str(ROOT / "examples" / "demo.yaml"), "-q", "--set", f"output.dir={out}",
         "--set", f"cache.dir={tmp_path / 'cache'}"], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    manifest = json.loads((out / "run.json").read_text())
    assert manifest["plugins"]["motion_net"]["plugin"] == "epo_unet"
    assert manifest["evaluation"]["overall"]["J"]["mean"] >= 0.6
