"""Training phases that mix several data sources, and RBSF-style sources with their own scene settings."""

import json
from pathlib import Path

import pytest
import yaml

from eponet.core.errors import SpecError
from eponet.training.base import data_line
from eponet.training.config import DataSource, Phase, parse_train_config
from eponet.synth import write_dataset
from eponet.training.trainer import MotionNetTrainer, ensure_pasted, ensure_rbsf

from .test_trainer import _config, easy_sequences


def _document(data) -> dict:
    return {"task": "motion_net", "model": {"inputs": "ed+flow"}, "phases": [{"name": "mix", "data": data, "epochs": 1}],
            "output": {"dir": "out"}}


def test_a_phase_mixes_a_list_of_sources_and_each_bad_one_is_named(tmp_path):
    (tmp_path / "davis" / "JPEGImages").mkdir(parents=True)
    scene = {"dynamic_texture_probability": 1.0, "num_boxes": [2, 6]}
    config = parse_train_config(_document([{"davis": {"root": "davis"}}, {"rbsf": {"dir": "syn", "scene": scene}}]),
                                base_dir=tmp_path)
    davis, rbsf = config.phases[0].data
    assert davis.kind == "davis" and davis.options["root"] == tmp_path / "davis"
    assert rbsf.kind == "rbsf" and rbsf.options["dir"] == tmp_path / "syn" and rbsf.options["scene"] == scene
    assert rbsf.options["sequences"] == 40 and rbsf.options["frames"] == 30  # the schema's defaults
    # one source stays one source
    assert isinstance(parse_train_config(_document({"rbsf": {"dir": "syn"}}), base_dir=tmp_path).phases[0].data,
                      DataSource)
    with pytest.raises(SpecError) as error:
        parse_train_config(_document([{"davis": {"root": "davis"}}, {"rbsf": {"dir": "syn", "frames": 2,
                                      "scene": {"num_boxs": 3, "fg_fraction": [0.5, 2]}}}, {"vimeo": {}}]),
                           base_dir=tmp_path)
    problems = "\n".join(error.value.problems)
    assert "phases[0].data[1].rbsf.frames: expected an integer >= 3, got 2" in problems
    assert "phases[0].data[1].rbsf.scene: num_boxs: unknown setting (did you mean 'num_boxes'?)" in problems
    assert "phases[0].data[1].rbsf.scene: fg_fraction: expected 0.01 <= min <= max <= 0.9, got [0.5, 2]" in problems
    assert "phases[0].data[2]: expected {davis: {root: ...}}, {rbsf: {dir: ...}} or {paste: {dir: ..., root: ...}}" in problems
    with pytest.raises(SpecError, match=r"phases\[0\].data: expected a source or a non-empty list of sources"):
        parse_train_config(_document([]), base_dir=tmp_path)
    with pytest.raises(SpecError, match=r"phases\[0\].data.rbsf: expected a mapping of settings, got 3"):
        parse_train_config(_document({"rbsf": 3}), base_dir=tmp_path)


def test_an_epoch_draws_from_every_source_of_the_phase(tmp_path):
    easy = easy_sequences()
    halves = {"a": easy[:2], "b": easy[2:]}
    config = _config(tmp_path)
    a, b = DataSource("davis", {"root": "a"}), DataSource("rbsf", {"dir": "b", "sequences": 2, "frames": 8,
                                                                    "size": "64x48", "seed": 0})
    config.phases = [Phase("mix", (a, b), 10)]
    config.validation = a
    trainer = MotionNetTrainer(config)
    loaded = []
    trainer.load_data = lambda source: loaded.append(source) or halves["a" if source is a else "b"]
    assert [s.name for s in trainer.data((a, b))] == ["easy0", "easy1", "easy2", "easy3"]
    trainer.data((a, b))
    assert loaded == [a, b]  # each source loaded once, kept for the run
    summary = trainer.run()
    assert summary["final"]["val_j"] > 0.8
    card = (tmp_path / "train" / "model-card.md").read_text()
    assert "mixed with RBSF-style synthetic clips (2 x 8 frames, 64x48, seed 0)" in card


def test_rbsf_scene_settings_reach_the_generator_and_its_marker(tmp_path):
    options = {"dir": tmp_path / "syn", "sequences": 1, "frames": 3, "size": "64x48", "seed": 2,
               "scene": {"dynamic_texture_probability": 1.0, "num_boxes": [3, 3]}}
    root, resolution = ensure_rbsf(options)
    assert (root, resolution) == (tmp_path / "syn", "48p")
    info = yaml.safe_load((root / "db_info.yml").read_text())
    assert info["generator"]["config"]["dynamic_texture_probability"] == 1.0
    assert info["generator"]["config"]["num_boxes"] == [3, 3]
    marker = root / "eponet-rbsf.json"
    assert json.loads(marker.read_text())["scene"] == options["scene"]
    frame = root / "JPEGImages" / "48p" / "rbsf-0000" / "00000.jpg"
    written = frame.stat().st_mtime_ns
    ensure_rbsf(options)  # the same recipe: reused, not written again
    assert frame.stat().st_mtime_ns == written
    other = {**options, "scene": {"dynamic_texture_probability": 0.0, "num_boxes": [3, 3]}}
    ensure_rbsf(other)  # other settings: generated again
    assert json.loads(marker.read_text())["scene"] == other["scene"]
    assert yaml.safe_load((root / "db_info.yml").read_text())["generator"]["config"]["dynamic_texture_probability"] == 0.0
    # without scene settings the marker is as before (data sets generated earlier stay valid)
    plain = Path(ensure_rbsf({k: v for k, v in options.items() if k != "scene"})[0]) / "eponet-rbsf.json"
    assert json.loads(plain.read_text()) == {"sequences": 1, "frames": 3, "size": "64x48", "seed": 2}
    # a regeneration with fewer clips or frames leaves none of the earlier ones behind
    ensure_rbsf({**options, "sequences": 2, "frames": 4})
    ensure_rbsf(options)
    assert sorted(p.name for p in (root / "JPEGImages" / "48p").iterdir()) == ["rbsf-0000"]
    assert len(list((root / "JPEGImages" / "48p" / "rbsf-0000").iterdir())) == 3


def test_a_paste_source_is_checked_with_the_spec(tmp_path):
    (tmp_path / "davis" / "JPEGImages").mkdir(parents=True)
    config = parse_train_config(_document([{"davis": {"root": "davis"}}, {"paste": {"dir": "p", "root": "davis",
                                                                                    "exclude": ["bear"]}}]),
                                base_dir=tmp_path)
    paste = config.phases[0].data[1]
    assert paste.kind == "paste" and paste.options["dir"] == tmp_path / "p" and paste.options["root"] == tmp_path / "davis"
    assert (paste.options["clips"], paste.options["frames"], paste.options["object_area"]) == (24, 30, [0.02, 0.25])
    assert data_line(paste) == ("24 clips x 30 frames of objects pasted over other sequences (seed 0, object area "
                                "[0.02, 0.25] of the frame, speed [0.5, 4.0] px per frame) from DAVIS-layout root "
                                "`davis` 240p: all sequences except bear")
    with pytest.raises(SpecError) as error:
        parse_train_config(_document([{"paste": {"dir": "p", "root": "nowhere", "object_area": [0.3, 0.1]}},
                                      {"paste": {"dir": "p", "root": "davis", "speed": [1, "fast"], "clip": 3}}]),
                           base_dir=tmp_path)
    problems = "\n".join(error.value.problems)
    assert f"phases[0].data[0].paste.root: {tmp_path / 'nowhere'} is not a DAVIS-layout root (no JPEGImages/)" in problems
    assert "phases[0].data[0].paste.object_area: expected [low, high] with 0 < low <= high <= 1, got [0.3, 0.1]" in problems
    assert "phases[0].data[1].paste.speed: expected [low, high] with 0 < low <= high, got [1, 'fast']" in problems
    assert "phases[0].data[1].paste.clip: unknown" in problems


def test_pasted_clips_use_only_the_sequences_left_in_and_are_rewritten_when_the_recipe_changes(tmp_path):
    davis = tmp_path / "davis"
    write_dataset(davis, 4, 6, (64, 48), seed=1, flow=False, depth=False, progress=False)
    options = {"dir": tmp_path / "p", "root": davis, "resolution": "48p", "sequences": None,
               "exclude": ["rbsf-0001"], "clips": 3, "frames": 5, "seed": 0, "object_area": [0.05, 0.1],
               "speed": [1.0, 2.0]}
    root, resolution = ensure_pasted(options)
    assert (root, resolution) == (tmp_path / "p", "48p")
    info = yaml.safe_load((root / "db_info.yml").read_text())
    used = {e[k] for e in info["sequences"] for k in ("background", "object")}
    assert used <= {"rbsf-0000", "rbsf-0002", "rbsf-0003"}  # never the excluded one
    marker = json.loads((root / "eponet-paste.json").read_text())
    assert marker["sequences"] == ["rbsf-0000", "rbsf-0002", "rbsf-0003"] and marker["clips"] == 3
    frame = root / "JPEGImages" / "48p" / "paste-0000" / "00000.jpg"
    written = frame.stat().st_mtime_ns
    ensure_pasted(options)  # the same recipe: reused
    assert frame.stat().st_mtime_ns == written
    ensure_pasted({**options, "clips": 1})  # another recipe: the earlier clips are gone
    assert sorted(p.name for p in (root / "JPEGImages" / "48p").iterdir()) == ["paste-0000"]
    with pytest.raises(Exception, match="at least two sequences"):
        ensure_pasted({**options, "exclude": ["rbsf-0000", "rbsf-0001", "rbsf-0002"]})
