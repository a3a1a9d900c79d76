import numpy as np
import pytest
import torch

from eponet.core.errors import MissingWeights, StageError
from eponet.fusion import ConvGRUFusion, video_logits, window_starts, window_weights
from eponet.plugins.fusion.convgru import ConvGRUStage


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _model(channels=6, seed=0, **kwargs):
    torch.manual_seed(seed)
    return ConvGRUFusion(channels, **{"bottleneck": 8, "hidden": 5, "kernel_size": 3, **kwargs}).eval()


def _inputs(frames=7, channels=6, size=(6, 9), seed=0):
    g = torch.Generator().manual_seed(seed)
    features = torch.randn(2, frames, channels, *size, generator=g)
    saliency = torch.rand(2, frames, 2 * size[0], 2 * size[1], generator=g)
    return features, saliency


def test_output_shapes_and_motion_only_variant():
    features, saliency = _inputs()
    with torch.no_grad():
        assert _model()(features, saliency).shape == (2, 7, 6, 9)
        none = _model(0)  # the `none` appearance stage: zero channels, no bottleneck
        assert none.bottleneck is None
        assert none(features[:, :, :0], saliency).shape == (2, 7, 6, 9)
    with pytest.raises(ValueError, match="expected \\(B, T, 6, h, w\\)"):
        _model()(features[:, :, :5], saliency)


def test_motion_residual_starts_from_the_motion_map_and_skips_dropped_frames():
    features, saliency = _inputs(frames=4)
    plain = _model()
    with torch.no_grad():
        logits = plain(features, saliency)[0]
        up = torch.nn.functional.interpolate(logits[:, None], size=saliency.shape[-2:], mode="bilinear",
                                             align_corners=False)[:, 0]
        assert torch.equal(plain.frame_logits(logits, saliency[0]), up)  # the paper's network: upsampling only
        residual = _model(motion_residual=True)
        assert residual.motion_weight == 1.0
        start = residual.frame_logits(residual(features, saliency)[0], saliency[0])
        # a fresh residual network predicts exactly the motion map (clipped to [1e-3, 1 - 1e-3])
        torch.testing.assert_close(torch.sigmoid(start), saliency[0].clamp(1e-3, 1 - 1e-3), atol=1e-6, rtol=0)
        # a frame whose motion map was zeroed (input-dropout) gets no residual
        dropped = saliency[0].clone()
        dropped[1] = 0
        out = residual.frame_logits(torch.zeros(4, 6, 9), dropped)
        assert torch.equal(out[1], torch.zeros_like(out[1])) and out[0].abs().min() > 0
        residual.motion.fill_(0.5)
        torch.testing.assert_close(residual.frame_logits(torch.zeros(4, 6, 9), saliency[0]),
                                   0.5 * torch.logit(saliency[0], eps=1e-3))


def test_feature_dropout_acts_in_training_only():
    features, saliency = _inputs(frames=3)
    model = _model(feature_dropout=0.5)
    with torch.no_grad():
        assert torch.equal(model(features, saliency), model(features, saliency))  # eval: deterministic
        model.train()
        torch.manual_seed(0)
        a = model(features, saliency)
        assert not torch.equal(a, model(features, saliency))


def test_update_gate_input_bias_starts_at_one_and_gru_weights_are_he():
    model = _model(channels=64, bottleneck=32, hidden=16)
    for cell in (model.forward_cell, model.backward_cell):
        biases = cell.gate_biases()
        assert torch.equal(biases["update"], torch.ones(16))
        assert torch.equal(biases["reset"], torch.zeros(16)) and torch.equal(biases["candidate"], torch.zeros(16))
        fan_in = cell.input_conv.weight[0].numel()  # He (MSR): std sqrt(2 / fan_in)
        assert cell.input_conv.weight.std().item() == pytest.approx((2 / fan_in) ** 0.5, rel=0.05)
    bound = (6 / (64 + 32)) ** 0.5  # Xavier uniform on the 1x1 bottleneck
    assert model.bottleneck.weight.abs().max().item() <= bound and model.bottleneck.weight.std().item() == pytest.approx(bound / 3 ** 0.5, rel=0.1)


def test_reversing_the_sequence_swaps_the_directions_exactly():
    model = _model()
    swapped = _model(seed=1)
    state = model.state_dict()
    mapping = {"forward_cell": "backward_cell", "backward_cell": "forward_cell",
               "head_forward": "head_backward", "head_backward": "head_forward"}
    swapped.load_state_dict({k: state[mapping.get(k.split(".")[0], k.split(".")[0]) + k[len(k.split(".")[0]):]]
                             for k in state})
    features, saliency = _inputs()
    with torch.no_grad():
        out = model(features, saliency)
        reversed_out = swapped(features.flip(1), saliency.flip(1))
        assert torch.equal(reversed_out, out.flip(1))
        # and it is not trivially symmetric: the unswapped model gives a different answer on the reversed input
        assert (model(features.flip(1), saliency.flip(1)) - out.flip(1)).abs().max() > 1e-3


def test_window_starts_and_weights():
    assert window_starts(10, None, 2) == [0] and window_starts(10, 12, 2) == [0]
    assert window_starts(10, 4, 1) == [0, 3, 6]
    assert window_starts(11, 4, 1) == [0, 3, 6, 7]
    linear = window_weights([0, 3], 5, 8, "linear")  # frames 3, 4 shared
    assert linear[0].tolist() == [5, 4, 3, 2, 1] and linear[1].tolist() == [1, 2, 3, 4, 5]  # frame 3: 2/3 + 1/3
    centre = window_weights([0, 3], 5, 8, "centre")
    assert centre[0].tolist() == [1, 1, 1, 1, 0] and centre[1].tolist() == [0, 1, 1, 1, 1]


def _fading_memory(model, update_bias=-2.0, scale=0.25):
    """Make the GRU forget within a few frames, as a trained one does; a fresh He-initialised GRU remembers for
    dozens of frames, so no window shorter than the video could reproduce it."""
    with torch.no_grad():
        for cell in (model.forward_cell, model.backward_cell):
            h = cell.hidden
            cell.input_conv.bias[h : 2 * h] = update_bias
            cell.input_conv.weight[h : 2 * h] *= 0.3
            cell.state_gates.weight *= scale
            cell.state_candidate.weight *= scale
    return model


def test_windowed_inference_matches_the_whole_video():
    model = _fading_memory(_model())
    features, saliency = _inputs(frames=30)
    f, s = features[0].numpy(), saliency[0].numpy()
    whole = video_logits(model, f, s, window=None)
    with torch.no_grad():
        assert torch.allclose(whole, model(features[:1], saliency[:1])[0], atol=1e-6)
    prob = torch.sigmoid(whole)
    error = {(blend, overlap): (torch.sigmoid(video_logits(model, f, s, window=16, overlap=overlap, blend=blend))
                                - prob).abs().max().item()
             for blend in ("linear", "centre") for overlap in (2, 8)}
    assert error["centre", 8] < 2e-3 and error["linear", 8] < 0.015
    assert error["centre", 8] < error["centre", 2] / 10 and error["linear", 8] < error["linear", 2] / 2


def _save_weights(path, model):
    torch.save({"config": model.config, "state_dict": model.state_dict()}, path)


def test_stage_fuses_at_the_saliency_size_and_checks_channels(tmp_path):
    model = _model()
    _save_weights(tmp_path / "fusion.pt", model)
    stage = ConvGRUStage(weights=str(tmp_path / "fusion.pt"), window=4, overlap=1, device="cpu")
    features, saliency = _inputs(frames=9)
    out = stage.fuse(features[0].numpy(), saliency[0, :, :10, :15].numpy())
    assert out.shape == (9, 10, 15) and out.dtype == np.float32 and 0 < out.min() and out.max() < 1
    with pytest.raises(StageError, match="expect 6 appearance channels"):
        stage.fuse(features[0, :, :4].numpy(), saliency[0].numpy())
    # weights with a motion residual keep it through saving and loading, and the stage applies it
    residual = _model(motion_residual=True)
    with torch.no_grad():
        residual.motion.fill_(0.7)
        residual.head_forward.weight.normal_()
    _save_weights(tmp_path / "residual.pt", residual)
    loaded = ConvGRUStage(weights=str(tmp_path / "residual.pt"), window=None, device="cpu")
    assert loaded.models[0].config["motion_residual"] and loaded.models[0].motion_weight == pytest.approx(0.7)
    with torch.no_grad():
        expected = torch.sigmoid(residual.frame_logits(residual(features[:1], saliency[:1])[0], saliency[0]))
    np.testing.assert_allclose(loaded.fuse(features[0].numpy(), saliency[0].numpy()), expected.numpy(), atol=1e-5)


def test_a_list_of_weights_averages_the_fusions_probabilities_before_selftraining(tmp_path):
    """An ensemble: the mean of each fusion's probability (the self-training then sees that mean); one name in a
    list is the stage with that name; checksums pair with the files in order; fusions on different appearance
    channels cannot be averaged."""
    from eponet.core.errors import SpecError
    from eponet.weights import sha256_of

    for seed in (0, 1):
        _save_weights(tmp_path / f"fusion{seed}.pt", _model(seed=seed))
    paths = [str(tmp_path / f"fusion{seed}.pt") for seed in (0, 1)]
    features, saliency = _inputs(frames=5)
    f, s = features[0].numpy(), saliency[0].numpy()
    alone = [ConvGRUStage(weights=p, window=None, device="cpu").fuse(f, s) for p in paths]
    assert np.abs(alone[0] - alone[1]).max() > 0.01  # two different networks
    pair = ConvGRUStage(weights=paths, sha256=[sha256_of(p) for p in paths], window=None, device="cpu")
    assert pair.sha256 == [sha256_of(p) for p in paths]
    np.testing.assert_allclose(pair.fuse(f, s), (alone[0] + alone[1]) / 2, atol=1e-6)
    np.testing.assert_array_equal(ConvGRUStage(weights=paths[:1], window=None, device="cpu").fuse(f, s), alone[0])
    mixed = ConvGRUStage(weights=paths, window=None, device="cpu", selftrain=0.5)
    from eponet.fusion.selftrain import self_trained_probability

    np.testing.assert_allclose(mixed.fuse(f, s), self_trained_probability(f, (alone[0] + alone[1]) / 2, motion=s,
                                                                          **mixed.selftrain), atol=1e-6)
    with pytest.raises(MissingWeights, match="checksum mismatch"):
        ConvGRUStage(weights=paths, sha256=[sha256_of(paths[0]), "0" * 64])
    with pytest.raises(SpecError, match="1 checksum\\(s\\) for 2 weights files"):
        ConvGRUStage(weights=paths, sha256=sha256_of(paths[0]))
    _save_weights(tmp_path / "other.pt", _model(channels=4))
    with pytest.raises(StageError, match="different appearance channels \\(\\[4, 6\\]\\)"):
        ConvGRUStage(weights=[paths[0], str(tmp_path / "other.pt")])
    from eponet.core.registry import get_registry

    spec = get_registry().get("fusion", "convgru")
    params = {p.name: p.default for p in spec.params}
    assert spec.check({**params, "weights": paths}) == []
    assert spec.check({**params, "weights": paths, "sha256": ["0" * 64]}) == [
        "sha256: 1 checksum(s) for 2 weights files; give one per file, in the same order, or none"]


def test_selftrain_mixes_an_appearance_classifier_fitted_on_the_fused_map(tmp_path):
    """``selftrain`` self-trains on the fusion's own confident pixels: where the fused map marks the object and a
    distractor of background appearance, the object is kept and the distractor mostly dropped."""
    from eponet.fusion.selftrain import self_trained_probability

    _save_weights(tmp_path / "fusion.pt", _model(motion_residual=True))  # fresh: fuses to the motion map itself
    rng = np.random.default_rng(0)
    features = rng.normal(size=(4, 6, 12, 16)).astype(np.float32)
    features[:, :2, 3:9, 4:10] += 3.0  # the object's appearance (grid rows 3-8, columns 4-9)
    saliency = np.full((4, 24, 32), 0.01, np.float32)
    saliency[:, 6:18, 8:20] = 0.95  # the object
    saliency[:, 0:6, 24:32] = 0.95  # a moving background patch of background appearance
    plain = ConvGRUStage(weights=str(tmp_path / "fusion.pt"), window=None, device="cpu")
    mixed = ConvGRUStage(weights=str(tmp_path / "fusion.pt"), window=None, device="cpu", selftrain=1.0)
    fused = plain.fuse(features, saliency)
    np.testing.assert_allclose(fused, saliency, atol=1e-5)
    out = mixed.fuse(features, saliency)
    np.testing.assert_allclose(out, self_trained_probability(features, fused, weight=1.0), atol=1e-6)
    assert out[:, 6:18, 8:20].mean() > 0.8 and out[:, 0:6, 24:32].mean() < 0.3
    half = ConvGRUStage(weights=str(tmp_path / "fusion.pt"), window=None, device="cpu", selftrain=0.5)
    np.testing.assert_allclose(half.fuse(features, saliency), 0.5 * fused + 0.5 * out, atol=1e-5)


def test_selftrain_thresholds_are_checked():
    from eponet.core.registry import get_registry

    spec = get_registry().get("fusion", "convgru")
    params = {p.name: p.default for p in spec.params}
    assert spec.check({**params, "selftrain_foreground": 0.5, "selftrain_background": 0.6}) == [
        "selftrain_background: expected a threshold below selftrain_foreground (0.5), got 0.6"]
    assert spec.check({**params, "selftrain_foreground_share": 0.03, "selftrain_foreground_floor": 0.05}) == [
        "selftrain_foreground_floor: expected a threshold above selftrain_background (0.05), got 0.05"]
    assert spec.check({**params, "selftrain_foreground_floor": 0.05}) == []  # no share: the floor is unused


def test_a_fusion_with_another_appearance_stage_than_its_weights_is_a_spec_error(tmp_path):
    """Checked with the whole spec, before anything runs: the weights record the appearance stage they were trained
    on, and another one's features would reach the network (or fail deep in the run on their channel count)."""
    from eponet.core.errors import SpecError
    from eponet.core.spec import parse_spec

    frames = tmp_path / "frames"
    frames.mkdir()
    doc = {"preset": "epo+", "input": {"path": str(frames)}, "output": {"dir": str(tmp_path / "out")},
           "stages": {"appearance": {"plugin": "none"}, "fusion": {"weights": "epo-plus-davis"}}}
    with pytest.raises(SpecError) as caught:
        parse_spec(doc)
    assert caught.value.problems == [
        "stages.fusion.weights: 'epo-plus-davis' was trained on efficientnet_lite0 features (472 channels), not on "
        "stages.appearance's none: set stages.appearance.plugin to efficientnet_lite0 or train a fusion on none"]
    doc["stages"]["appearance"] = {"plugin": "efficientnet_lite0"}
    assert parse_spec(doc).stages["fusion"].params["weights"] == "epo-plus-davis"
    doc["stages"]["fusion"]["weights"] = ["epo-plus-davis", "epo-plus-davis-lite2"]  # every member is checked
    with pytest.raises(SpecError) as caught:
        parse_spec(doc)
    assert caught.value.problems == [
        "stages.fusion.weights: 'epo-plus-davis-lite2' was trained on efficientnet_lite2 features (520 channels), not "
        "on stages.appearance's efficientnet_lite0: set stages.appearance.plugin to efficientnet_lite2 or train a "
        "fusion on efficientnet_lite0"]


def test_shipped_fusion_weights_match_their_catalogue_checksum_and_stay_small():
    from eponet.weights import builtin_weights
    from tests.conftest import assert_shipped_weights

    assert_shipped_weights("epo-plus-davis", "fusion")
    assert_shipped_weights("epo-plus-davis-v1", "fusion")
    assert_shipped_weights("epo-plus-davis-lite2", "fusion")
    assert_shipped_weights("epo-plus-davis-lite2-pair", "fusion")
    assert_shipped_weights("epo-plus-davis-lite2-pair-fine", "fusion")
    stage = ConvGRUStage()  # the default loads the built-in weights: the epo+ preset's, on Lite2 features
    assert stage.models[0].appearance_channels == 520 and stage.models[0].config["motion_residual"]
    assert stage.sha256 == builtin_weights()["epo-plus-davis-lite2-pair"].sha256
    assert ConvGRUStage(weights="epo-plus-davis").models[0].appearance_channels == 472  # Lite0's


def test_missing_builtin_weights_is_a_clear_error(tmp_path):
    with pytest.raises(MissingWeights, match="'epo-plus-davos': neither a built-in name \\(did you mean 'epo-plus-davis'\\?\\)"):
        ConvGRUStage(weights="epo-plus-davos")
    with pytest.raises(MissingWeights, match="neither a built-in name \\(built-in: epo-plus-davis-lite2-pair, epo-plus-davis-lite2-pair-fine, epo-plus-davis-lite2, "):
        ConvGRUStage(weights="zzz")  # nothing near: no hint
    _save_weights(tmp_path / "fusion.pt", _model())
    with pytest.raises(MissingWeights, match="checksum mismatch"):
        ConvGRUStage(weights=str(tmp_path / "fusion.pt"), sha256="0" * 64)


def test_epo_plus_fine_runs_a_fusion_trained_on_its_grid():
    """``epo+fine`` is ``epo+`` with the backbone on the frames at 1.5x, under a fusion trained on that grid from
    the maps of the pair the preset runs, whose lost middles of moving objects it gives back (``motion_fill``);
    everything else is epo+'s."""
    from eponet.core.registry import get_registry
    from eponet.weights import builtin_weights

    registry = get_registry()
    plus, fine = registry.resolve_preset("epo+"), registry.resolve_preset("epo+fine")
    assert fine["appearance"] == {**plus["appearance"], "scale": 1.5}
    assert plus["appearance"] == {"plugin": "efficientnet_lite2", "precision": "auto"}
    assert {k: v for k, v in fine["fusion"].items() if k != "weights"} == {
        **{k: v for k, v in plus["fusion"].items() if k != "weights"}, "motion_fill": 0.9}
    assert "motion_fill" not in plus["fusion"]
    assert {k: v for k, v in fine.items() if k not in ("appearance", "fusion")} == {
        k: v for k, v in plus.items() if k not in ("appearance", "fusion")}
    meta = torch.load(builtin_weights()[fine["fusion"]["weights"]].file, map_location="cpu", weights_only=True)["meta"]
    assert meta["appearance"]["plugin"] == "efficientnet_lite2" and meta["appearance"]["params"]["scale"] == 1.5
    assert meta["motion_net"]["params"]["weights"] == fine["motion_net"]["weights"]
    assert meta["spec"]["phases"][0]["data"]["davis"]["exclude"] == []  # all 30 train sequences


@pytest.mark.parametrize("preset", ["epo+", "epo+fine"])
def test_epo_plus_preset_with_the_shipped_weights_on_real_davis_frames(tmp_path, shared_data, preset):
    """The ``epo+`` presets end to end on the two real 480p DAVIS sequences of the shared data, processed at scale
    0.5 as in the paper. Both are training sequences of the shipped weights, so this checks the integration
    (weights, feature scale and normalisation, motion maps, windows, CRF), not generalisation: the v4 pair alone
    scored 0.80 J here, epo+ 0.84 (0.82 with the v4 pair and the Lite0 fusion until 2026-12-06), epo+fine 0.85."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[3]
    out = tmp_path / "davis"
    result = subprocess.run(
        [sys.executable, "-m", "eponet.run", str(root / "examples" / "demo.yaml"), "-q", "--set", f"preset={preset}",
         "--set", f"input.path={shared_data / 'davis2016-train' / 'DAVIS'}", "--set", "input.resolution=480p",
         "--set", "input.sequences=[rollerblade,motorbike]", "--set", "input.scale=0.5",
         "--set", f"output.dir={out}", "--set", "output.save=[masks]", "--set", f"cache.dir={tmp_path / 'cache'}"],
        capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    manifest = json.loads((out / "run.json").read_text())
    assert manifest["plugins"]["fusion"]["plugin"] == "convgru"
    assert manifest["plugins"]["appearance"]["plugin"] == "efficientnet_lite2"
    assert manifest["evaluation"]["overall"]["J"]["mean"] >= 0.80  # the motion nets alone: 0.80


def test_motion_support_drops_a_look_alike_that_does_not_move(tmp_path):
    """Two regions of one appearance in the fused map, only one of them moving: ``motion_support`` keeps the moving
    one exactly and lowers the other to the motion map; a frame where nothing has support keeps its fused map; the
    stage applies it after the fusion (and its self-training)."""
    from eponet.fusion.support import motion_supported

    fused = np.full((3, 12, 16), 0.02, np.float32)
    fused[:, 2:6, 2:6] = 0.9  # the moving object
    fused[:, 6:10, 10:14] = 0.8  # a look-alike standing still
    motion = np.full_like(fused, 0.01)
    motion[:2, 3:5, 3:5] = 0.7  # frames 0 and 1: the object moves; frame 2: the motion map misses it
    motion[:, 7, 11] = 0.3  # some weak motion on the look-alike
    out = motion_supported(fused, motion, support=0.5)
    np.testing.assert_array_equal(out[:2, 2:6, 2:6], fused[:2, 2:6, 2:6])
    np.testing.assert_array_equal(out[:2, 6:10, 10:14], motion[:2, 6:10, 10:14])
    np.testing.assert_array_equal(out[2], fused[2])
    outside = np.ones(fused.shape, bool)
    outside[:, 6:10, 10:14] = False
    np.testing.assert_array_equal(out[outside], fused[outside])
    low = motion_supported(fused, motion, support=0.25)  # 0.3 supports the look-alike too
    np.testing.assert_array_equal(low[:2], fused[:2])
    np.testing.assert_array_equal(low[2, 2:6, 2:6], motion[2, 2:6, 2:6])  # and only it in frame 2
    with pytest.raises(ValueError, match="must both be"):
        motion_supported(fused, motion[:, :6], support=0.5)

    _save_weights(tmp_path / "fusion.pt", _model(motion_residual=True))  # fresh: fuses to the motion map itself
    features = np.zeros((3, 6, 6, 8), np.float32)
    plain = ConvGRUStage(weights=str(tmp_path / "fusion.pt"), window=None, device="cpu")
    gated = ConvGRUStage(weights=str(tmp_path / "fusion.pt"), window=None, device="cpu", motion_support=0.5)
    maps = motion.copy()
    maps[:2, 2:6, 2:6] = 0.9  # the fresh fusion returns the motion map: one supported region in frames 0 and 1
    np.testing.assert_allclose(plain.fuse(features, maps), maps, atol=1e-5)
    np.testing.assert_allclose(gated.fuse(features, maps), motion_supported(plain.fuse(features, maps), maps, 0.5),
                               atol=1e-6)


def test_motion_fill_gives_back_the_middle_of_a_moving_object(tmp_path):
    """A fused object with its middle lost, open to the background below (a bear's flank between its legs), while
    the motion map holds the whole object: ``motion_filled`` raises the lost middle to the motion map inside the
    region's convex hull, and leaves alone motion foreground outside every hull (spray beside the object), a
    region without motion support, the pixels the motion map calls background or holds below the fill level, and
    an object that lost less than ``share`` of its size; the stage applies it last."""
    from eponet.fusion.support import motion_filled

    fused = np.full((2, 20, 30), 0.05, np.float32)
    fused[:, 2:12, 2:14] = 0.9
    fused[:, 5:12, 5:11] = 0.2  # the lost middle, open at the bottom: no hole to fill
    fused[:, 14:18, 20:26] = 0.8  # a region the motion map does not support
    motion = np.full_like(fused, 0.02)
    motion[:, 2:12, 2:14] = 0.85  # the whole object moves
    motion[:, 6:8, 6:8] = 0.3  # ... but for a patch the motion map calls background
    motion[:, 2:8, 22:28] = 0.9  # spray, away from the object
    motion[1] = 0.02  # frame 1: nothing moves, nothing is supported
    out = motion_filled(fused, motion, support=0.7, fill=0.5)
    middle = np.zeros(fused.shape[1:], bool)
    middle[5:12, 5:11] = True
    middle[6:8, 6:8] = False
    np.testing.assert_array_equal(out[0][middle], motion[0][middle])
    untouched = ~middle
    np.testing.assert_array_equal(out[0][untouched], fused[0][untouched])
    np.testing.assert_array_equal(out[1], fused[1])
    strict = motion_filled(fused, motion, support=0.7, fill=0.9)  # the middle's 0.85 is below the fill level
    np.testing.assert_array_equal(strict, fused)
    lost = middle.sum() / (fused[0, 2:12, 2:14] > 0.5).sum()  # the lost pixels per pixel of the region: 38 / 78
    np.testing.assert_array_equal(motion_filled(fused, motion, support=0.7, fill=0.5, share=lost + 0.01), fused)
    np.testing.assert_array_equal(motion_filled(fused, motion, support=0.7, fill=0.5, share=lost - 0.01), out)
    none_supported = motion_filled(fused, motion, support=0.95, fill=0.5)  # no region reaches 0.95: nothing is an object
    np.testing.assert_array_equal(none_supported, fused)
    with pytest.raises(ValueError, match="must both be"):
        motion_filled(fused, motion[:, :6], support=0.5, fill=0.5)

    _save_weights(tmp_path / "fusion.pt", _model(motion_residual=True))  # fresh: fuses to the motion map itself
    features = np.zeros((2, 6, 10, 15), np.float32)
    plain = ConvGRUStage(weights=str(tmp_path / "fusion.pt"), window=None, device="cpu", motion_support=0.7)
    filled = ConvGRUStage(weights=str(tmp_path / "fusion.pt"), window=None, device="cpu", motion_support=0.7,
                          motion_fill=0.5)
    fused_plain = plain.fuse(features, motion)
    np.testing.assert_allclose(filled.fuse(features, motion), motion_filled(fused_plain, motion, 0.7, 0.5), atol=1e-6)
