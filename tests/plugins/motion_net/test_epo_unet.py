import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from eponet.core.errors import MissingWeights, SpecError
from eponet.nets import EpoUNet
from eponet.plugins.motion_net.epo_unet import EpoUNetStage
from eponet.weights import sha256_of

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


def test_a_list_of_weights_averages_the_networks(tmp_path):
    torch.manual_seed(0)
    a = _save(tmp_path / "a.pt", depth=2, widths=(4, 8), head_channels=4)
    b = _save(tmp_path / "b.pt", depth=3, widths=(4, 8, 8), head_channels=8, ed_encoding="log")
    motion = np.random.default_rng(2).random((3, 3, 19, 30), dtype=np.float32) * 3 - 1
    pa, pb = (EpoUNetStage(weights=str(p), device="cpu").predict(motion) for p in (a, b))
    assert np.abs(pa - pb).max() > 1e-3
    both = EpoUNetStage(weights=[str(a), str(b)], device="cpu", batch_size=2)
    np.testing.assert_allclose(both.predict(motion), 0.5 * (pa + pb), atol=1e-6)
    assert both.sha256 == [sha256_of(a), sha256_of(b)]
    np.testing.assert_allclose(EpoUNetStage(weights=[str(a)], device="cpu").predict(motion), pa, atol=1e-6)
    # with flip, the mean of the four predictions
    fa, fb = (EpoUNetStage(weights=str(p), device="cpu", flip=True).predict(motion) for p in (a, b))
    np.testing.assert_allclose(EpoUNetStage(weights=[str(a), str(b)], device="cpu", flip=True).predict(motion),
                               0.5 * (fa + fb), atol=1e-6)
    # one checksum per file, checked in order
    EpoUNetStage(weights=[str(a), str(b)], sha256=[sha256_of(a), sha256_of(b)])
    with pytest.raises(MissingWeights, match=r"b\.pt: checksum mismatch"):
        EpoUNetStage(weights=[str(a), str(b)], sha256=[sha256_of(a), sha256_of(a)])
    with pytest.raises(SpecError, match="sha256: 1 checksum"):
        EpoUNetStage(weights=[str(a), str(b)], sha256=sha256_of(a))


def test_a_spec_lists_weights_relative_to_its_folder(tmp_path):
    from eponet.core.spec import parse_spec

    (tmp_path / "nets").mkdir()
    _save(tmp_path / "nets" / "a.pt", depth=2, widths=(4, 8), head_channels=4)
    frames = tmp_path / "frames"
    frames.mkdir()
    for t in range(3):
        cv2.imwrite(str(frames / f"{t:05d}.png"), np.zeros((24, 32, 3), np.uint8))
    doc = {"preset": "epo", "input": {"path": str(frames)}, "output": {"dir": str(tmp_path / "out")},
           "stages": {"motion_net": {"plugin": "epo_unet", "weights": ["epo-davis", "nets/a.pt"]}}}
    spec = parse_spec(doc, base_dir=tmp_path)
    assert spec.stages["motion_net"].params["weights"] == ["epo-davis", str(tmp_path / "nets" / "a.pt")]
    doc["stages"]["motion_net"]["weights"] = ["epo-davis", "nets/absent.pt"]
    with pytest.raises(SpecError, match=r"stages\.motion_net\.weights: .*absent\.pt: weights file not found"):
        parse_spec(doc, base_dir=tmp_path)
    doc["stages"]["motion_net"]["weights"] = ["epo-davis", "nets/a.pt"]
    doc["stages"]["motion_net"]["sha256"] = ["0" * 64]
    with pytest.raises(SpecError, match=r"stages\.motion_net\.sha256: 1 checksum\(s\) for 2 weights files"):
        parse_spec(doc, base_dir=tmp_path)
    del doc["stages"]["motion_net"]["sha256"]
    doc["stages"]["motion_net"]["weights"] = []
    with pytest.raises(SpecError, match=r"stages\.motion_net\.weights: expected a built-in weights name or a file "
                                        r"or a list of them, got \[\]"):
        parse_spec(doc, base_dir=tmp_path)


@pytest.mark.parametrize("kind, name", [("motion_net", "epo-davis"), ("fusion", "epo-plus-davis-lite2")])
def test_a_wrong_sha256_with_a_builtin_name_is_one_spec_line(tmp_path, kind, name):
    """README: ``sha256`` is checked before loading, also with a built-in name (it was silently ignored)."""
    from eponet.core.spec import parse_spec
    from eponet.weights import builtin_weights

    frames = tmp_path / "frames"
    frames.mkdir()
    doc = {"preset": "epo+", "input": {"path": str(frames)}, "output": {"dir": str(tmp_path / "out")},
           "stages": {kind: {"weights": name, "sha256": "ab" * 32}}}
    with pytest.raises(SpecError) as caught:
        parse_spec(doc)
    expected = builtin_weights()[name].sha256
    assert caught.value.problems == [f"stages.{kind}.sha256: built-in weights {name!r}: expected sha256 {expected} "
                                     f"(the catalogue's), given {'ab' * 32}"]
    doc["stages"][kind]["sha256"] = expected
    assert parse_spec(doc).stages[kind].params["sha256"] == expected


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
    assert_shipped_weights("epo-davis-seed1", "motion_net")
    assert_shipped_weights("epo-davis-v3", "motion_net")
    EpoUNetStage()  # the default loads the built-in weights
    assert len(EpoUNetStage(weights=["epo-davis", "epo-davis-seed1"]).models) == 2  # the epo+ preset's pair
    assert_shipped_weights("epo-davis-centred", "motion_net")
    centred = EpoUNetStage(weights="epo-davis-centred").models[0]
    assert centred.flow_centring == "rigid" and centred.config["flow_centring"] == "rigid"
    assert_shipped_weights("epo-davis-distilled", "motion_net")
    assert len(EpoUNetStage(weights="epo-davis-distilled").models) == 1  # one network for the pair's cost of two
    assert_shipped_weights("epo-davis-v5", "motion_net")
    assert_shipped_weights("epo-davis-v5-seed1", "motion_net")
    assert len(EpoUNetStage(weights=["epo-davis-v5", "epo-davis-v5-seed1"]).models) == 2  # the pair the epo preset ran before 2026-12-06
    assert_shipped_weights("epo-davis-v5-centred", "motion_net")
    plain, centred = EpoUNetStage(weights=["epo-davis-v5", "epo-davis-v5-centred"]).models  # epo's pair until 2026-12-06
    assert (plain.flow_centring, centred.flow_centring) == ("none", "rigid")
    assert_shipped_weights("epo-davis-v5-spread", "motion_net")
    spread, centred = EpoUNetStage(weights=["epo-davis-v5-spread", "epo-davis-v5-centred"]).models  # the epo preset's
    assert (spread.flow_spread, spread.flow_centring, centred.flow_spread) == (9, "none", 0)
    assert spread.input_channels == 4 and spread.convs[0].shape[1] == 4  # first convolution: (dx, dy, ED, spread)


def test_the_epo_preset_runs_the_networks_trained_on_its_ed():
    """v5 was trained on shrunk means (``prior_groups`` 4, the recipe's), which the epo and epo-st presets paint;
    they average the v5 recipe with one more channel (the flow's local spread) and v5's flow-centred twin (held out
    better than v5 with that twin, which was better than v5 alone, where two v5 seeds were not). epo+ runs that
    pair too (held out better than v5 alone under the same fusions), with a fusion (epo-plus-davis-lite2-pair) trained on
    the pair's maps of the shrunk means, with GRIC and no border prior."""

    from eponet.core.registry import get_registry
    from eponet.weights import builtin_weights

    registry = get_registry()
    epo = registry.resolve_preset("epo")
    assert epo["motion_net"]["weights"] == ["epo-davis-v5-spread", "epo-davis-v5-centred"]
    assert epo["rigidity"]["prior_groups"] == 4
    for name in ("epo-davis-v5", "epo-davis-v5-seed1", "epo-davis-v5-centred", "epo-davis-v5-spread"):
        saved = torch.load(builtin_weights()[name].file, map_location="cpu", weights_only=False)
        assert saved["meta"]["spec"]["geometry"]["stages"]["rigidity"]["prior_groups"] == 4
    selftrained = registry.resolve_preset("epo-st")
    assert selftrained["motion_net"] == epo["motion_net"]  # epo's network and precision, as measured held out
    assert selftrained["rigidity"] == {"plugin": "trifocal", "prior_groups": 4}  # epo's ED (the stage's defaults)
    assert epo["rigidity"] == selftrained["rigidity"]
    fused = registry.resolve_preset("epo+")
    # epo's pair and precision (bfloat16 where the CPU has it: held out under the fusion, the same J as float32)
    assert fused["motion_net"] == epo["motion_net"] == {
        "plugin": "epo_unet", "weights": ["epo-davis-v5-spread", "epo-davis-v5-centred"], "precision": "auto"}
    assert fused["rigidity"] == {"plugin": "trifocal", "degeneracy": "gric", "border_prior": 0.0, "prior_groups": 4}
    meta = torch.load(builtin_weights()[fused["fusion"]["weights"]].file, map_location="cpu", weights_only=True)["meta"]
    # the maps it was trained on: the pair's, the ones the preset feeds it
    assert meta["motion_net"]["params"]["weights"] == fused["motion_net"]["weights"]
    assert meta["appearance"]["plugin"] == fused["appearance"]["plugin"] == "efficientnet_lite2"
    # the authors' CRF weights, on the box around the object only (held out: the same J, 39% less CRF time), on the
    # fused map averaged along the flow (held out: T 0.223 -> 0.191 at equal J)
    assert fused["refiner"] == {"plugin": "densecrf", "max_size": 427, "crop_margin": 3.0, "temporal": 1}
    assert fused["fusion"]["motion_support"] == 0.7  # chosen per fold on the other folds (the card)


def test_epo_preset_on_the_embedded_demo_reaches_the_target_j(tmp_path):
    out = tmp_path / "demo"
    result = subprocess.run(
        [sys.executable, "-m", "eponet.run", str(ROOT / "examples" / "demo.yaml"), "-q", "--set", f"output.dir={out}",
         "--set", f"cache.dir={tmp_path / 'cache'}"], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    manifest = json.loads((out / "run.json").read_text())
    assert manifest["plugins"]["motion_net"]["plugin"] == "epo_unet"
    assert manifest["evaluation"]["overall"]["J"]["mean"] >= 0.6


def test_bfloat16_precision_stays_close_to_float32():
    motion = np.random.default_rng(3).random((2, 3, 48, 80), dtype=np.float32) * 2 - 0.5
    full = EpoUNetStage(weights="epo-davis", device="cpu").predict(motion)
    half = EpoUNetStage(weights="epo-davis", device="cpu", precision="bfloat16").predict(motion)
    assert half.dtype == np.float32 and half.shape == full.shape
    assert 0 < np.abs(half - full).max() < 0.1  # bfloat16 has 8 bits of mantissa: close, not equal
    assert np.mean((half > 0.5) != (full > 0.5)) < 0.01


def test_auto_precision_is_what_the_cpu_does_natively_and_is_recorded(monkeypatch):
    import eponet.core.devices as devices

    motion = np.random.default_rng(3).random((2, 3, 48, 80), dtype=np.float32) * 2 - 0.5
    for native, expected in ((True, "bfloat16"), (False, "float32")):
        monkeypatch.setattr(devices, "native_bfloat16", lambda native=native: native)
        auto = EpoUNetStage(weights="epo-davis", device="cpu", precision="auto")
        assert auto.resolved == {"device": "cpu", "precision": expected}
        same = EpoUNetStage(weights="epo-davis", device="cpu", precision=expected)
        np.testing.assert_array_equal(auto.predict(motion), same.predict(motion))
