import csv

import numpy as np
import pytest
import torch

from eponet.training.config import DataSource, Phase, TrainConfig
from eponet.training.data import SequenceData
from eponet.training.trainer import MotionNetTrainer, sequence_j


def easy_sequences(count=4, frames=8, size=(48, 64), seed=0):
    """Motion images whose ED is high on a moving rectangle (the foreground), with noisy flow everywhere."""
    rng = np.random.default_rng(seed)
    out = []
    for s in range(count):
        motion = rng.normal(0, 0.1, (frames, 3, *size)).astype(np.float32)
        masks = np.zeros((frames, *size), np.uint8)
        for t in range(frames):
            y, x = 8 + (s * 3 + t) % 12, 10 + (s * 5 + 2 * t) % 20
            masks[t, y : y + 20, x : x + 24] = 1
        motion[:, 2] = np.abs(rng.normal(0.05, 0.03, (frames, *size))) + 0.8 * masks
        out.append(SequenceData(f"easy{s}", motion.astype(np.float16), masks, np.zeros((frames, *size, 3), np.uint8)))
    return out


def _config(tmp_path, epochs=10, **optimizer):
    source = DataSource("davis", {"root": tmp_path})
    return TrainConfig(
        task="motion_net", seed=0,
        model={"inputs": "ed+flow", "depth": 3, "widths": [8, 16, 16], "head_channels": 16},
        geometry=None, phases=[Phase("easy", source, epochs)], validation=source,
        optimizer={"name": "adam", "lr": 3e-3, "momentum": 0.9, "weight_decay": 0.0, "batch_size": 8,
                   "step_epochs": 100, "gamma": 0.1, **optimizer},
        input_dropout={"probability": 0.0, "zero_epochs": 0, "then": "noise", "noise_std": 0.05},
        augment={"crop": [32, 48], "flip": True}, output_dir=tmp_path / "train", cache_enabled=False,
        document={"note": "test"},
    )


def _trainer(config, data):
    trainer = MotionNetTrainer(config)
    trainer.data = lambda source: data
    return trainer


def test_short_training_lowers_the_loss_and_segments_the_easy_set(tmp_path):
    data = easy_sequences()
    summary = _trainer(_config(tmp_path), data).run()
    with open(tmp_path / "train" / "history.csv") as handle:
        rows = list(csv.DictReader(handle))
    losses = [float(r["train_loss"]) for r in rows]
    assert len(rows) == 10 and losses[-1] < 0.6 * losses[0]
    assert float(rows[-1]["val_j"]) > 0.8
    assert (tmp_path / "train" / "curves.png").stat().st_size > 1000
    card = (tmp_path / "train" / "model-card.md").read_text()
    assert summary["sha256"] in card and "| 10 | easy |" in card and "ED encoding clip" in card
    # the exported weights load through the plugin, checksum verified, and reproduce the validation score
    from eponet.plugins.motion_net.epo_unet import EpoUNetStage

    stage = EpoUNetStage(weights=summary["weights"], sha256=summary["sha256"], batch_size=4, device="cpu")
    j = np.mean([sequence_j(stage.predict(s.motion.astype(np.float32)) >= 0.5, s.masks.astype(bool)) for s in data])
    assert abs(j - float(rows[-1]["val_j"])) < 1e-3


def test_the_ed_encoding_is_trained_exported_and_loaded(tmp_path):
    data = easy_sequences(count=2, frames=6)
    for s in data:
        s.motion[:, 2] *= 30  # unsaturated ED: the clip would make the foreground and the noise's top alike
    config = _config(tmp_path, epochs=1)
    config.model["ed_encoding"] = "log"
    summary = _trainer(config, data).run()
    assert torch.load(summary["weights"], weights_only=True)["config"]["ed_encoding"] == "log"
    assert "ED encoding log" in (tmp_path / "train" / "model-card.md").read_text()
    from eponet.plugins.motion_net.epo_unet import EpoUNetStage

    assert EpoUNetStage(weights=summary["weights"], device="cpu").models[0].ed_encoding == "log"


def test_a_network_with_flow_spread_is_trained_exported_and_loaded(tmp_path):
    from eponet.core.errors import SpecError
    from eponet.plugins.motion_net.epo_unet import EpoUNetStage
    from eponet.training.config import parse_train_config

    data = easy_sequences(count=2, frames=6)
    config = _config(tmp_path, epochs=1)
    config.model["flow_spread"] = 5
    summary = _trainer(config, data).run()
    assert torch.load(summary["weights"], weights_only=True)["config"]["flow_spread"] == 5
    assert "flow spread over 5 px" in (tmp_path / "train" / "model-card.md").read_text()
    stage = EpoUNetStage(weights=summary["weights"], device="cpu")
    assert stage.models[0].flow_spread == 5
    assert stage.predict(data[0].motion.astype(np.float32)).shape == data[0].masks.shape
    document = {"task": "motion_net", "model": {"flow_spread": 4}, "phases": [{"name": "a", "data": {"davis": {
        "root": "."}}, "epochs": 1}], "output": {"dir": "out"}}
    with pytest.raises(SpecError, match=r"model.flow_spread: expected 0 \(off\) or an odd window of at least 3"):
        parse_train_config(document, base_dir=tmp_path)


def test_zoom_trains_records_itself_and_is_validated(tmp_path):
    from eponet.core.errors import SpecError
    from eponet.training.config import parse_train_config

    data = easy_sequences()
    config = _config(tmp_path, epochs=6)
    config.augment["zoom"] = [0.8, 1.25]
    _trainer(config, data).run()
    with open(tmp_path / "train" / "history.csv") as handle:
        rows = list(csv.DictReader(handle))
    assert float(rows[-1]["val_j"]) > 0.7  # the zoomed samples keep the masks on the objects
    assert "zoom 0.8-1.25x" in (tmp_path / "train" / "model-card.md").read_text()

    def problems(augment):
        document = {"task": "motion_net", "augment": augment, "phases": [{"name": "a", "data": {"davis": {
            "root": "."}}, "epochs": 1}], "output": {"dir": "out"}}
        with pytest.raises(SpecError) as error:
            parse_train_config(document, base_dir=tmp_path)
        return str(error.value)

    assert "augment.zoom: expected [low, high] with 0 < low <= high, or null, got [1.4, 0.7]" in problems(
        {"zoom": [1.4, 0.7]})
    assert "augment.zoom: expected [low, high]" in problems({"zoom": [0, 1]})
    assert "augment.zoom: needs augment.crop" in problems({"crop": None, "zoom": [0.7, 1.4]})


def test_resume_continues_exactly(tmp_path):
    data = easy_sequences(count=2, frames=6)
    straight = _trainer(_config(tmp_path / "a", epochs=3), data)
    straight.run()
    interrupted = _trainer(_config(tmp_path / "b", epochs=2), data)
    interrupted.run()
    resumed = _trainer(_config(tmp_path / "b", epochs=3), data)
    resumed.run(resume=True)
    for (name, a), b in zip(straight.model.state_dict().items(), resumed.model.state_dict().values()):
        assert torch.equal(a, b), name


def test_weight_average_is_validated_exported_and_resumed(tmp_path):
    data = easy_sequences(count=2, frames=6)
    trainer = _trainer(_config(tmp_path / "a", epochs=3, ema=0.9), data)
    summary = trainer.run()
    raw, average = trainer.model.state_dict(), trainer.ema.module.state_dict()
    assert any(not torch.equal(raw[k], average[k]) for k in raw)  # the average is not the last step's weights
    exported = torch.load(summary["weights"], weights_only=False)["state_dict"]
    for name, value in average.items():
        assert torch.equal(exported[name], value), name  # BatchNorm statistics included
    interrupted = _trainer(_config(tmp_path / "b", epochs=2, ema=0.9), data)
    interrupted.run()
    resumed = _trainer(_config(tmp_path / "b", epochs=3, ema=0.9), data)
    resumed.run(resume=True)
    for name, value in trainer.ema.module.state_dict().items():
        assert torch.equal(value, resumed.ema.module.state_dict()[name]), name


def test_a_student_learns_from_its_teachers_where_the_ground_truth_says_nothing(tmp_path):
    data = easy_sequences()
    teacher = _trainer(_config(tmp_path / "teacher"), data).run()
    # the student's training masks are empty: with share 1 all it learns comes from the teachers' probability
    blind = [SequenceData(s.name, s.motion, np.zeros_like(s.masks), s.frames) for s in data]
    config = _config(tmp_path / "student")
    config.phases = [Phase("blind", DataSource("davis", {"root": tmp_path / "blind"}), 10)]
    config.teacher = {"weights": [teacher["weights"], teacher["weights"]], "share": 1.0}
    student = MotionNetTrainer(config)
    student.data = lambda source: blind if source is config.phases[0].data else data
    summary = student.run()
    from eponet.plugins.motion_net.epo_unet import EpoUNetStage

    stage = EpoUNetStage(weights=teacher["weights"], device="cpu")
    images = data[0].motion.astype(np.float32)
    np.testing.assert_allclose(student.teacher_probability(torch.from_numpy(images))[:, 0].numpy(),
                               stage.predict(images), atol=1e-5)
    with open(tmp_path / "student" / "train" / "history.csv") as handle:
        assert float(list(csv.DictReader(handle))[-1]["val_j"]) > 0.7  # against the true masks
    card = (tmp_path / "student" / "train" / "model-card.md").read_text()
    assert "distilled: target (1 - 1.0) x ground truth + 1.0 x the mean probability of 2 teacher" in card
    assert card.count(teacher["sha256"]) == 2
    meta = torch.load(summary["weights"], weights_only=False)["meta"]
    assert meta["teacher"]["sha256"] == [teacher["sha256"]] * 2 and meta["teacher"]["share"] == 1.0
    # without teachers, the same blind data teaches nothing
    config = _config(tmp_path / "alone")
    config.phases = [Phase("blind", DataSource("davis", {"root": tmp_path / "blind"}), 3)]
    alone = MotionNetTrainer(config)
    alone.data = lambda source: blind if source is config.phases[0].data else data
    alone.run()
    with open(tmp_path / "alone" / "train" / "history.csv") as handle:
        assert float(list(csv.DictReader(handle))[-1]["val_j"]) < 0.3


def test_sequence_j_drops_first_and_last_frame():
    gt = np.zeros((4, 2, 2), bool)
    gt[:, 0, 0] = True
    pred = gt.copy()
    pred[0] = False  # first frame wrong: ignored
    pred[2, 0, 1] = True  # IoU 1/2 on an evaluated frame
    assert sequence_j(pred, gt) == pytest.approx(0.75)
