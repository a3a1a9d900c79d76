"""The DAVIS-layout writer and the ``eponet make-rbsf`` command."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import yaml

from eponet.core.io import read_flo, read_image, read_mask
from eponet.synth import generate_clip, write_dataset
from eponet.synth.cli import main
from eponet.synth.writer import sequence_seed

SIZE = (160, 96)


def _digest(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(root.rglob("*")) if p.is_file()}


def test_davis_layout_is_written_and_reads_back(tmp_path):
    out = tmp_path / "rbsf"
    entries = write_dataset(out, 2, 4, SIZE, seed=5, progress=False)
    assert [e["name"] for e in entries] == ["rbsf-0000", "rbsf-0001"]
    for listing in ("all.txt", "train.txt"):
        assert (out / "ImageSets" / listing).read_text().split() == ["rbsf-0000", "rbsf-0001"]
    info = yaml.safe_load((out / "db_info.yml").read_text())
    assert [s["name"] for s in info["sequences"]] == ["rbsf-0000", "rbsf-0001"]
    assert all(s["num_frames"] == 4 and set(s["attributes"]) <= set(info["attributes"]) for s in info["sequences"])

    for index, name in enumerate(["rbsf-0000", "rbsf-0001"]):
        clip = generate_clip(sequence_seed(5, index), 4, SIZE)
        for t in range(4):
            stem = f"{t:05d}"
            frame = read_image(out / "JPEGImages" / "96p" / name / f"{stem}.jpg")
            assert frame.shape == (96, 160, 3)
            mse = np.mean((frame.astype(float) - clip.frames[t]) ** 2)
            assert 10 * np.log10(255**2 / mse) > 28  # JPEG quality 90
            assert np.array_equal(read_mask(out / "Annotations" / "96p" / name / f"{stem}.png"), clip.masks[t])
            ids = read_mask(out / "Annotations_unsupervised" / "96p" / name / f"{stem}.png", keep_labels=True)
            assert np.array_equal(ids, clip.object_ids[t])
            if t < 3:
                flow_dir = out / "Flow" / "96p" / name
                assert np.array_equal(read_flo(flow_dir / "forward" / f"{stem}.flo", (96, 160)), clip.forward[t])
                assert np.array_equal(read_flo(flow_dir / "backward" / f"{stem}.flo", (96, 160)), clip.backward[t])
        assert not (out / "Flow" / "96p" / name / "forward" / "00003.flo").exists()
        occ = np.load(out / "Flow" / "96p" / name / "occlusions.npz")
        assert np.array_equal(occ["forward"], clip.occlusion_forward) and np.array_equal(occ["backward"], clip.occlusion_backward)
        cams = np.load(out / "Cameras" / "96p" / f"{name}.npz")
        for key in ("K", "R", "t", "depth"):
            assert np.array_equal(cams[key], getattr(clip, key)), key
        assert bool(cams["static_camera"]) == clip.static_camera


def test_same_seed_writes_bit_identical_files(tmp_path):
    write_dataset(tmp_path / "a", 1, 3, SIZE, seed=11, progress=False)
    write_dataset(tmp_path / "b", 1, 3, SIZE, seed=11, progress=False)
    write_dataset(tmp_path / "c", 1, 3, SIZE, seed=12, progress=False)
    a, b, c = (_digest(tmp_path / x) for x in "abc")
    assert len(a) > 10 and a == b
    assert a["JPEGImages/96p/rbsf-0000/00000.jpg"] != c["JPEGImages/96p/rbsf-0000/00000.jpg"]


def _run(capsys, *args) -> tuple[int, str]:
    code = main([str(a) for a in args])
    return code, capsys.readouterr().err


def test_cli_success_and_one_line_errors(tmp_path, capsys):
    out = tmp_path / "out"
    common = ["--sequences", 1, "--frames", 3, "--seed", 1, "-q"]
    code, err = _run(capsys, "--out", out, "--size", "96x64", *common)
    assert code == 0, err
    assert len(list((out / "JPEGImages" / "64p" / "rbsf-0000").glob("*.jpg"))) == 3

    for bad_size in ("96", "96x", "8x8", "axb"):
        code, err = _run(capsys, "--out", out, "--size", bad_size, *common)
        assert code == 2 and len(err.strip().splitlines()) == 1 and "--size" in err, (bad_size, err)

    a_file = tmp_path / "file"
    a_file.write_text("x")
    code, err = _run(capsys, "--out", a_file / "sub", "--size", "96x64", *common)
    assert code == 2 and len(err.strip().splitlines()) == 1 and str(a_file) in err, err

    empty = tmp_path / "empty"
    empty.mkdir()
    code, err = _run(capsys, "--out", out, "--size", "96x64", "--backgrounds", empty, *common)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "no images" in err, err


def test_cli_uses_the_backgrounds_folder(tmp_path, capsys):
    import cv2

    photos = tmp_path / "photos"
    photos.mkdir()
    red = np.zeros((64, 64, 3), np.uint8)
    red[..., 2] = 230  # BGR: pure red
    cv2.imwrite(str(photos / "red.png"), red)
    config = tmp_path / "scene.yaml"
    config.write_text("dynamic_texture_probability: 0\nnum_objects: [1, 1]\n")
    out = tmp_path / "out"
    code, err = _run(capsys, "--out", out, "--size", "96x64", "--sequences", 1, "--frames", 3, "--seed", 2,
                     "--backgrounds", photos, "--config", config, "-q", "--no-flow", "--no-depth")
    assert code == 0, err
    frame = read_image(out / "JPEGImages" / "64p" / "rbsf-0000" / "00000.jpg").astype(float)
    background = read_mask(out / "Annotations" / "64p" / "rbsf-0000" / "00000.png") == 0
    assert frame[..., 0][background].mean() > 150 and frame[..., 1][background].mean() < 40
    assert not (out / "Flow").exists()
    assert "depth" not in np.load(out / "Cameras" / "64p" / "rbsf-0000.npz")
