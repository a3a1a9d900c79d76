import json

import numpy as np
import pytest
import torch
import yaml

from eponet.core.errors import SpecError
from eponet.core.io import write_mask_png
from eponet.training.config import load_train_config
from tests.conftest import textured_frames, write_frames


pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture
def davis(tmp_path):
    """A DAVIS-layout root with two 6-frame 48x64 sequences (textures translating; a square as foreground)."""
    root = tmp_path / "DAVIS"
    for s, name in enumerate(("alpha", "beta")):
        write_frames(root / "JPEGImages" / "240p" / name, textured_frames(6, (48, 64), shift=(1.0 + s, 0.5), seed=s),
                     suffix=".jpg")
        for t in range(6):
            mask = np.zeros((48, 64), np.uint8)
            mask[10 + t : 30 + t, 12 + 2 * t : 36 + 2 * t] = 1
            write_mask_png(root / "Annotations" / "240p" / name / f"{t:05d}.png", mask)
    return root


@pytest.fixture
def motion_weights(tmp_path):
    from eponet.nets import EpoUNet

    torch.manual_seed(0)
    model = EpoUNet(depth=2, widths=(4, 8), head_channels=4)
    torch.save({"config": model.config, "state_dict": model.state_dict()}, tmp_path / "motion.pt")
    return tmp_path / "motion.pt"


#: fast geometry for tiny clips (the trifocal RANSAC would dominate the test's time)
GEOMETRY = {"flow": {"plugin": "farneback"}, "rigidity": {"plugin": "homography", "max_trials": 50, "max_points": 500}}


def _spec(tmp_path, **changes):
    document = {
        "task": "fusion", "seed": 0,
        "model": {"bottleneck": 4, "hidden": 4, "kernel_size": 3},
        "geometry": {"scale": 1.0, "stages": GEOMETRY},
        "motion_net": {"weights": "motion.pt"},
        "appearance": {"plugin": "none"},
        "phases": [{"name": "davis", "data": {"davis": {"root": "DAVIS", "resolution": "240p", "exclude": ["beta"]}},
                    "epochs": 2}],
        "validation": {"davis": {"root": "DAVIS", "resolution": "240p", "sequences": ["beta"]}},
        "clips": {"length": 4},
        "augment": {"crop": [32, 48], "flip": True},
        "output": {"dir": "out"}, "cache": {"dir": "cache"}, "device": "cpu", "threads": 1,
        **changes,
    }
    path = tmp_path / "fusion.yaml"
    path.write_text(yaml.safe_dump(document))
    return path


def test_fusion_spec_is_validated_as_a_whole(tmp_path, davis, motion_weights):
    config = load_train_config(_spec(tmp_path))
    assert config.task == "fusion" and config.clips == {"length": 4}
    assert config.optimizer["name"] == "rmsprop" and config.optimizer["clip_gradients"] == 50.0
    assert config.optimizer["schedule"] == "linear" and config.input_dropout == {"probability": 0.2, "sequences": None}
    assert config.stages["motion_net"].plugin == "epo_unet" and config.stages["appearance"].plugin == "none"
    assert config.stages["motion_net"].params["weights"] == str(motion_weights)
    assert set(config.geometry.stages) == {"flow", "trajectories", "rigidity", "appearance"}  # no motion net
    assert config.loss == {"name": "bce", "iou_weight": 1.0}  # the paper's loss unless the spec says otherwise
    assert load_train_config(_spec(tmp_path, loss={"name": "bce+iou", "iou_weight": 0.5})).loss == {
        "name": "bce+iou", "iou_weight": 0.5}
    with pytest.raises(SpecError) as error:
        load_train_config(_spec(tmp_path, motion_net={"weights": "gone.pt"}, clips={"length": 1},
                                model={"kernel_size": 4}, input_dropot={}, loss={"name": "dice"},
                                validation={"rbsf": {"dir": "x"}}))
    problems = "\n".join(error.value.problems)
    assert "motion_net.weights: " in problems and "gone.pt" in problems
    assert "clips.length: expected an integer >= 2, got 1" in problems
    assert "model.kernel_size: expected an odd integer, got 4" in problems
    assert "input_dropot: unknown top-level key (did you mean 'input_dropout'?)" in problems
    assert 'loss.name: expected one of \'bce\', \'bce+iou\', got "dice"' in problems
    assert "validation: task fusion trains on DAVIS-layout data" in problems
    with pytest.raises(SpecError, match="task: expected one of 'motion_net', 'fusion', got 'fusoin'"):
        load_train_config(_spec(tmp_path, task="fusoin"))


def test_eponet_train_fusion_end_to_end_then_run_epo_plus(tmp_path, davis, motion_weights):
    from eponet.core.pipeline import Pipeline
    from eponet.core.spec import parse_spec
    from eponet.train import main

    appearance = {"plugin": "efficientnet_lite0", "device": "cpu"}
    assert main([str(_spec(tmp_path, appearance=appearance)), "-q"]) == 0
    out = tmp_path / "out"
    summary = json.loads((out / "summary.json").read_text())
    assert summary["epochs"] == 2 and (out / "history.csv").read_text().count("\n") == 3
    assert "# Model card: EpO+ fusion" in (out / "model-card.md").read_text()
    meta = torch.load(out / "weights.pt", weights_only=True)["meta"]
    assert meta["appearance"]["plugin"] == "efficientnet_lite0" and len(meta["motion_net"]["sha256"]) == 64
    assert torch.load(out / "weights.pt", weights_only=True)["config"]["appearance_channels"] == 472
    assert len(list((tmp_path / "cache" / "appearance").rglob("*.npz"))) == 2  # features cached per sequence
    # the trained fusion runs in the epo+ composition, weights verified by checksum
    spec = parse_spec({
        "preset": "epo+", "input": {"path": str(davis), "resolution": "240p", "scale": 1.0},
        "stages": {**GEOMETRY, "motion_net": {"weights": str(motion_weights)},
                   "appearance": appearance,
                   "fusion": {"weights": summary["weights"], "sha256": summary["sha256"], "window": 4, "overlap": 2},
                   "refiner": {"plugin": "threshold"}},
        "output": {"dir": str(tmp_path / "run"), "save": ["masks", "saliency"]}, "cache": {"dir": str(tmp_path / "cache")},
    })
    manifest = Pipeline(spec).run()
    assert manifest["sequences"]["beta"]["cached"] == ["flow", "trajectories", "rigidity", "appearance"]  # from training
    assert len(list((tmp_path / "run" / "alpha" / "masks").iterdir())) == 6


def test_motion_maps_give_the_named_sequences_another_networks_maps(tmp_path, davis, motion_weights):
    """``motion_maps`` (out-of-fold maps for stacking): a named sequence's training map is exactly what the network
    given for it predicts, not the spec's motion net's; bad entries are reported with the spec's other problems."""
    from eponet.nets import EpoUNet
    from eponet.training.data import load_motion_sequences
    from eponet.training.fusion import FusionTrainer
    from eponet.weights import sha256_of

    torch.manual_seed(1)
    other = EpoUNet(depth=2, widths=(4, 8), head_channels=4)
    torch.nn.init.constant_(other.classifier.bias, 2.0)  # sure of foreground everywhere: not the spec's net's ~0.5
    torch.save({"config": other.config, "state_dict": other.state_dict()}, tmp_path / "other.pt")
    config = load_train_config(_spec(tmp_path, motion_maps=[{"weights": "other.pt", "sequences": ["alpha"]}]))
    assert config.motion_maps == {"alpha": str(tmp_path / "other.pt")}
    trainer = FusionTrainer(config, appearance_channels=0)
    [alpha] = trainer.load_data(config.phases[0].data)
    named, spec_net = trainer.motion_stage("alpha"), trainer.motion_stage()
    assert named.sha256 == sha256_of(tmp_path / "other.pt") and spec_net.sha256 == sha256_of(motion_weights)
    [seq] = load_motion_sequences(config.geometry, davis, resolution="240p", sequences=["alpha"], cache=trainer.cache,
                                  features=True)
    motion = seq.motion.astype(np.float32)
    np.testing.assert_allclose(alpha.saliency.astype(np.float32), named.predict(motion), atol=2e-3)
    assert np.abs(spec_net.predict(motion) - named.predict(motion)).min() > 0.3
    assert trainer.weights_meta()["motion_maps"]["alpha"]["sha256"] == sha256_of(tmp_path / "other.pt")

    with pytest.raises(SpecError) as error:
        load_train_config(_spec(tmp_path, motion_maps=[{"weights": "gone.pt", "sequences": ["alpha"]},
                                                       {"weights": "other.pt", "sequences": ["alpha", "beta"]},
                                                       {"weights": "other.pt"}], clips={"length": 1}))
    problems = "\n".join(error.value.problems)
    assert "motion_maps[0].weights: " in problems and "gone.pt" in problems
    assert "motion_maps[1].sequences: 'alpha' is given a motion net twice" in problems
    assert "motion_maps[2]: expected {weights: ..., sequences: [...]}" in problems
    assert "clips.length: expected an integer >= 2, got 1" in problems  # validated as a whole
    with pytest.raises(SpecError, match="motion_maps: expected a list of"):
        load_train_config(_spec(tmp_path, motion_maps={"alpha": "other.pt"}))
