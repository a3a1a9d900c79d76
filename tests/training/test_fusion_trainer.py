import csv

import numpy as np
import pytest
import torch

from eponet.training.augment import drop_motion_maps, random_clip_crop_flip
from eponet.training.config import DataSource, Phase, TrainConfig
from eponet.training.fusion import FusionSequence, FusionTrainer
from eponet.training.trainer import sequence_j


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def easy_fusion_set(count=3, frames=10, size=(32, 48), channels=4, seed=0):
    """A moving square: the appearance features mark it (channel 0, stride 8, noisy), the motion map is right
    on the even frames and blank on the odd ones (as if the motion net failed there)."""
    rng = np.random.default_rng(seed)
    h, w = size[0] // 8, size[1] // 8
    out = []
    for s in range(count):
        masks = np.zeros((frames, *size), np.uint8)
        for t in range(frames):
            y, x = (4 + s * 3 + t) % 12, (6 + s * 5 + 2 * t) % 24
            masks[t, y : y + 16, x : x + 16] = 1
        cells = masks.reshape(frames, h, 8, w, 8).mean(axis=(2, 4))
        features = rng.normal(0, 0.3, (frames, channels, h, w))
        features[:, 0] += 2 * cells
        saliency = masks * 0.9 + rng.uniform(0, 0.1, masks.shape)
        saliency[1::2] = 0
        out.append(FusionSequence(f"easy{s}", features.astype(np.float16), saliency.astype(np.float16), masks))
    return out


def _config(tmp_path, epochs=6, samples=16, **optimizer):
    source = DataSource("davis", {"root": tmp_path})
    return TrainConfig(
        task="fusion", seed=0, model={"bottleneck": 8, "hidden": 8, "kernel_size": 3}, geometry=None,
        phases=[Phase("easy", source, epochs, samples)], validation=source,
        optimizer={"name": "rmsprop", "lr": 1e-2, "schedule": "linear", "step_epochs": 5, "gamma": 0.1,
                   "momentum": 0.0, "weight_decay": 0.0, "batch_size": 2, "clip_gradients": 50.0, **optimizer},
        input_dropout={"probability": 0.2, "sequences": None}, augment={"crop": [24, 40], "flip": True},
        output_dir=tmp_path / "train", cache_enabled=False, threads=1, clips={"length": 6},
        document={"note": "test"},
    )


def _trainer(config, data):
    trainer = FusionTrainer(config, appearance_channels=4)
    trainer.data = lambda source: data
    return trainer


def test_short_fusion_training_lowers_the_loss(tmp_path):
    data = easy_fusion_set()
    summary = _trainer(_config(tmp_path), data).run()
    with open(tmp_path / "train" / "history.csv") as handle:
        rows = list(csv.DictReader(handle))
    losses = [float(r["train_loss"]) for r in rows]
    assert len(rows) == 6 and losses[-1] < 0.5 * losses[0]
    assert float(rows[-1]["val_j"]) > 0.6 and float(rows[-1]["val_loss"]) < 0.6 * float(rows[0]["val_loss"])
    assert [float(r["lr"]) for r in rows[:3]] == pytest.approx([1e-2, 1e-2 * 5 / 6, 1e-2 * 4 / 6])  # linear decay
    assert (tmp_path / "train" / "curves.png").stat().st_size > 1000
    card = (tmp_path / "train" / "model-card.md").read_text()
    assert summary["sha256"] in card and "| 6 | easy |" in card and "clipped to [-50, 50]" in card
    # the exported weights load through the fusion plugin (checksum verified) and reproduce the validation J
    from eponet.plugins.fusion.convgru import ConvGRUStage

    stage = ConvGRUStage(weights=summary["weights"], sha256=summary["sha256"], window=None, device="cpu")
    j = np.mean([sequence_j(stage.fuse(s.features.astype(np.float32), s.saliency.astype(np.float32)) >= 0.5,
                            s.masks.astype(bool)) for s in data])
    assert abs(j - float(rows[-1]["val_j"])) < 1e-3


def test_fusion_resume_continues_exactly(tmp_path):
    data = easy_fusion_set(count=2, frames=8)
    straight = _trainer(_config(tmp_path / "a", epochs=3, samples=4), data)
    straight.run()
    interrupted = _trainer(_config(tmp_path / "b", epochs=3, samples=4), data)
    train_epoch = interrupted.train_epoch

    def stop_in_third_epoch(data, optimizer, epoch, samples):
        if epoch == 2:
            raise KeyboardInterrupt
        return train_epoch(data, optimizer, epoch, samples)

    interrupted.train_epoch = stop_in_third_epoch
    with pytest.raises(KeyboardInterrupt):
        interrupted.run()
    resumed = _trainer(_config(tmp_path / "b", epochs=3, samples=4), data)
    resumed.run(resume=True)
    for (name, a), b in zip(straight.model.state_dict().items(), resumed.model.state_dict().values()):
        assert torch.equal(a, b), name


def test_clips_cover_each_sequence_from_a_random_offset(tmp_path):
    trainer = _trainer(_config(tmp_path), [])
    data = easy_fusion_set(count=2, frames=20)[:1] + easy_fusion_set(count=1, frames=4)
    clips = trainer.clips(data, np.random.default_rng(3))
    long = [c for c in clips if c[0] == 0]
    assert all(length == 6 for _, _, length in long) and len(long) in (2, 3)
    assert [t for _, t, _ in long] == list(range(long[0][1], 15, 6)) and long[0][1] < 6
    assert (1, 0, 4) in clips  # a sequence shorter than a clip is one clip


def test_clip_crop_and_flip_are_consistent_over_the_clip():
    rng = np.random.default_rng(0)
    features = np.arange(3 * 2 * 4 * 6, dtype=np.float32).reshape(3, 2, 4, 6)
    saliency = np.repeat(np.repeat(features[:, 0], 8, axis=1), 8, axis=2)  # each cell's value on its 8x8 pixels
    masks = (saliency % 2).astype(np.uint8)
    for _ in range(10):
        f, s, m = random_clip_crop_flip(features, saliency, masks, (16, 24), True, rng)
        assert f.shape == (3, 2, 2, 3) and s.shape == m.shape == (3, 16, 24)
        assert np.array_equal(np.repeat(np.repeat(f[:, 0], 8, axis=1), 8, axis=2), s)  # still aligned
        assert np.array_equal((s % 2).astype(np.uint8), m)
    dropped, chosen = drop_motion_maps(np.ones((2, 500, 3, 3), np.float32), 0.2, np.random.default_rng(1))
    assert chosen.shape == (2, 500) and 0.15 < chosen.mean() < 0.25
    assert (dropped[chosen] == 0).all() and (dropped[~chosen] == 1).all()


def test_fusion_weight_average_is_what_validation_and_the_plugin_see(tmp_path):
    data = easy_fusion_set(count=2)
    trainer = _trainer(_config(tmp_path, epochs=3, ema=0.8), data)
    summary = trainer.run()
    raw, average = trainer.model.state_dict(), trainer.ema.module.state_dict()
    assert any(not torch.equal(raw[k], average[k]) for k in raw)
    with open(tmp_path / "train" / "history.csv") as handle:
        last = list(csv.DictReader(handle))[-1]
    from eponet.plugins.fusion.convgru import ConvGRUStage

    stage = ConvGRUStage(weights=summary["weights"], sha256=summary["sha256"], window=None, device="cpu")
    j = np.mean([sequence_j(stage.fuse(s.features.astype(np.float32), s.saliency.astype(np.float32)) >= 0.5,
                            s.masks.astype(bool)) for s in data])
    assert abs(j - float(last["val_j"])) < 1e-3  # validation scored the average, and the average was exported
