import subprocess
import sys
import textwrap

import pytest


def _run(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", *args], capture_output=True, text=True, cwd=cwd, timeout=300)


@pytest.fixture
def spec_file(tmp_path, frames_dir):
    path = tmp_path / "spec.yaml"
    path.write_text(textwrap.dedent(f"""
        preset: geometry
        input: {{path: {frames_dir}, scale: 1.0}}
        stages: {{trajectories: null, rigidity: null}}
        output: {{dir: {tmp_path / 'out'}, save: [flow]}}
        cache: {{enabled: false}}
    """))
    return path


def test_run_and_validate_succeed(spec_file, tmp_path):
    result = _run("eponet", "validate", str(spec_file))
    assert result.returncode == 0 and "valid (preset geometry; flow=dis; 1 sequence(s): clip)" in result.stdout
    result = _run("eponet.run", str(spec_file), "-q")
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "out" / "run.json").is_file()


def test_bad_spec_is_one_line_and_exit_2(spec_file):
    result = _run("eponet.run", str(spec_file), "--set", "stages.flow.preset=slow")
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in result.stderr
    assert lines[0].startswith(f"error: {spec_file}: stages.flow.preset: expected one of 'ultrafast', 'fast', 'medium'")


def test_several_problems_one_per_line(spec_file):
    result = _run("eponet", "validate", str(spec_file), "--set", "stages.flow.preset=slow", "--set", "bogus=1")
    assert result.returncode == 2
    assert result.stderr.splitlines()[0] == f"error: {spec_file}: 2 problems:"
    assert "Traceback" not in result.stderr


def test_bad_input_exit_2_and_traceback_only_with_verbose(tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    spec = tmp_path / "s.yaml"
    spec.write_text(f"preset: geometry\ninput: {{path: {empty}}}\nstages: {{trajectories: null, rigidity: null}}\n"
                    f"output: {{dir: {tmp_path / 'o'}, save: [flow]}}\n")
    result = _run("eponet.run", str(spec))
    assert result.returncode == 2 and result.stderr.strip() == (f"error: {empty}: empty folder, expected image frames "
                                                             "(.jpg, .jpeg, .png, .bmp, .ppm, .pgm, .tif, .tiff)")
    verbose = _run("eponet.run", str(spec), "-v")
    assert verbose.returncode == 2 and "Traceback" in verbose.stderr


def test_missing_spec_file(tmp_path):
    result = _run("eponet.run", str(tmp_path / "nope.yaml"))
    assert result.returncode == 2 and "nope.yaml: cannot read spec" in result.stderr


def test_plugins_lists_kinds_parameters_and_presets():
    result = _run("eponet", "plugins")
    assert result.returncode == 0
    out = result.stdout
    for text in ("flow:", "dis  [eponet", "preset: one of 'ultrafast', 'fast', 'medium', default 'medium'",
                 "refiner:", "densecrf", "presets:", "epo+:"):
        assert text in out


def test_a_1x1_video_is_refused_before_anything_is_written(tmp_path):
    """It used to pass validation, then fail naming a temporary overlay path, leaving an empty output folder."""
    import cv2
    import numpy as np

    tiny = tmp_path / "tiny"
    tiny.mkdir()
    for t in range(3):
        cv2.imwrite(str(tiny / f"{t:05d}.png"), np.full((1, 1, 3), 40 * t, np.uint8))
    spec = tmp_path / "s.yaml"
    spec.write_text(f"preset: epo\ninput: {{path: {tiny}}}\nstages: {{refiner: {{plugin: threshold}}}}\n"
                    f"output: {{dir: {tmp_path / 'out'}, save: [masks, overlay]}}\n")
    expected = f"error: {tiny / '00000.png'}: frames are 1x1 px; the pipeline needs frames of at least 16x16 px"
    for command in ("eponet validate", "eponet.run"):
        result = _run(*command.split(), str(spec))
        assert result.returncode == 2 and result.stderr.strip() == expected, command
    assert not (tmp_path / "out").exists()


def test_validate_warns_about_the_memory_of_4000x3000_frames(tmp_path):
    """Frames of 4000x3000 px ran to a 7.5 GB peak with no word."""
    import cv2
    import numpy as np

    big = tmp_path / "big"
    big.mkdir()
    for t in range(25):
        cv2.imwrite(str(big / f"{t:05d}.png"), np.zeros((3000, 4000, 3), np.uint8))
    spec = tmp_path / "s.yaml"
    spec.write_text(f"input: {{path: {big}}}\noutput: {{dir: {tmp_path / 'out'}}}\n")
    result = _run("eponet", "validate", str(spec))
    assert result.returncode == 0, result.stderr
    assert result.stderr.splitlines() == [
        "eponet: WARNING: big: frames of 4000x3000 px (processed at 2000x1500) need about 9.2 GiB in the run loop "
        "(run.chunk 16, run.lag 30), above the 8 GiB warning bound; a lower input.scale, run.chunk or run.lag uses less"]


def test_a_corrupt_frame_mid_folder_is_one_line_exit_2_and_the_frames_before_it_are_kept(tmp_path):
    from tests.conftest import textured_frames, write_frames

    paths = write_frames(tmp_path / "clip", textured_frames(6))
    paths[4].write_bytes(b"not an image")
    spec = tmp_path / "s.yaml"
    spec.write_text(f"preset: geometry\ninput: {{path: {tmp_path / 'clip'}, scale: 1.0}}\n"
                    f"stages: {{trajectories: null, rigidity: null}}\n"
                    f"output: {{dir: {tmp_path / 'out'}, save: [flow]}}\ncache: {{enabled: false}}\n")
    result = _run("eponet", "validate", str(spec))
    assert result.returncode == 2 and result.stderr.splitlines() == [
        f"error: {paths[4]}: cannot read image (not an image or corrupt) (a run processes the 4 frames before it, "
        "then fails)"]
    result = _run("eponet.run", str(spec), "-q")
    assert result.returncode == 2 and result.stderr.splitlines() == [
        f"error: {paths[4]}: cannot read image (not an image or corrupt); the sequence ends there: its first 4 "
        "frames (00000 to 00003) were processed and their outputs kept"]
    assert len(list((tmp_path / "out" / "clip" / "flow" / "forward").iterdir())) == 3


def test_cache_info_and_prune_report_sizes_and_stages(tmp_path, capsys):
    import os
    import time

    import numpy as np

    from eponet.cli import main
    from eponet.core.cache import Cache

    cache = Cache(tmp_path / "cache")
    for k, (stage, age) in enumerate([("flow", 10 * 86400), ("flow", 60), ("rigidity", 30)]):
        cache.save(stage, f"{k}" * 64, {"x": np.zeros(2**20, dtype=np.uint8)})
        os.utime(cache._path(stage, f"{k}" * 64), (time.time() - age,) * 2)
    assert main(["cache", "info", "--cache-dir", str(tmp_path / "cache")]) == 0
    out = capsys.readouterr().out
    assert f"cache: {tmp_path / 'cache'}" in out and "in 3 entries" in out
    assert "flow 2 (2.0 MiB), rigidity 1 (1.0 MiB)" in out and "oldest: " in out and "newest: " in out
    assert main(["cache", "prune", "--older-than", "7d", "--cache-dir", str(tmp_path / "cache")]) == 0
    assert capsys.readouterr().out.startswith("freed 1.0 MiB: 1 entries (flow 1 (1.0 MiB)); 2.0 MiB in 2 entries left")
    assert main(["cache", "prune", "--max-size", "1.5M", "--cache-dir", str(tmp_path / "cache")]) == 0
    assert capsys.readouterr().out.startswith("freed 1.0 MiB: 1 entries (flow 1 (1.0 MiB)); 1.0 MiB in 1 entries")
    assert [e.stage for e in cache.entries()] == ["rigidity"]


@pytest.mark.parametrize("option, value, expected", [
    ("--max-size", "2Q", "error: --max-size: expected a size such as 500M or 2G, got '2Q'"),
    ("--older-than", "a week", "error: --older-than: expected a duration such as 12h or 7d, got 'a week'"),
])
def test_cache_prune_bad_values_are_one_line_and_exit_2(tmp_path, capsys, option, value, expected):
    from eponet.cli import main

    assert main(["cache", "prune", option, value, "--cache-dir", str(tmp_path)]) == 2
    assert capsys.readouterr().err.strip() == expected


def test_sizes_and_durations_parse():
    from eponet.cli import parse_duration, parse_size

    assert parse_size("-", "500M") == 500 * 2**20 and parse_size("-", "2g") == 2 * 2**30 and parse_size("-", "10") == 10
    assert parse_size("-", "1.5GiB") == int(1.5 * 2**30)
    assert parse_duration("-", "7d") == 7 * 86400 and parse_duration("-", "90") == 90 and parse_duration("-", "2h") == 7200


def test_run_json_records_the_command_line_and_the_cache_it_used(spec_file, tmp_path):
    import json

    from eponet.cli import main

    args = ["run", str(spec_file), "--set", "cache.enabled=true", "--set", "stages.flow.preset=fast", "--no-cache",
            "--cache-dir", str(tmp_path / "cache"), "-q"]
    assert main(args) == 0
    run = json.loads((tmp_path / "out" / "run.json").read_text())
    assert run["invocation"] == {"overrides": ["cache.enabled=true", "stages.flow.preset=fast"], "no_cache": True,
                                 "cache_dir": str(tmp_path / "cache")}
    assert run["spec"]["cache"] == {"enabled": False, "dir": str(tmp_path / "cache")}
    assert run["spec"]["stages"]["flow"]["preset"] == "fast" and "weights_sha256" in run
    assert not (tmp_path / "cache").exists()


def test_the_summary_says_how_many_frames_a_max_frames_run_scored(capsys, tmp_path):
    from eponet.cli import _print_summary

    evaluation = {"overall": {"J": {"mean": 0.5}}, "max_frames": 4,
                  "sequences": {"a": {"frames_scored": 3, "frames_in_ground_truth": 23},
                                "b": {"frames_scored": 3, "frames_in_ground_truth": 33}}}
    _print_summary({"sequences": {}, "evaluation": evaluation}, tmp_path, quiet=False)
    assert "J mean 0.500, 6 of 56 ground-truth frames scored (input.max_frames 4)" in capsys.readouterr().out


def _geometry_spec(path, source, out, **run):
    path.write_text(textwrap.dedent(f"""
        preset: geometry
        input: {{path: {source}, scale: 1.0}}
        stages: {{rigidity: {{max_points: 100}}}}
        output: {{dir: {out}, save: [ed, flow]}}
        run: {{workers: 1, chunk: 4, lag: 4}}
        cache: {{enabled: false}}
    """))
    return path


def test_off_a_terminal_a_long_sequence_logs_progress_lines_and_q_silences_them(frames_dir, tmp_path, capsys,
                                                                               monkeypatch):
    import re

    from eponet.cli import main
    from eponet.core import progress

    monkeypatch.setattr(progress, "PROGRESS_INTERVAL_S", 0.0)  # every sequence is "long": a line per frame
    spec = _geometry_spec(tmp_path / "s.yaml", frames_dir, tmp_path / "out")
    assert main(["run", str(spec)]) == 0
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if "frames/s" in line]
    assert len(lines) == 5, err
    assert re.fullmatch(r"eponet: INFO: clip: 1/5 frames, [\d.]+ frames/s, ETA \d+ s", lines[0]), lines[0]
    assert lines[-1].startswith("eponet: INFO: clip: 5/5 frames, ") and lines[-1].endswith(", ETA 0 s")
    assert any(re.match(r"eponet: INFO: clip: flow [\d.]+ s, trajectories .*; 5 frames in ", l) for l in err.splitlines())
    assert "\r" not in err and "%|" not in err  # no bar off a terminal

    assert main(["run", str(spec), "-q", "--set", f"output.dir={tmp_path / 'quiet'}"]) == 0
    assert capsys.readouterr().err == ""


def _two_sequences(root):
    from tests.conftest import textured_frames, write_frames

    for k, name in enumerate(("a", "b")):
        write_frames(root / "JPEGImages" / "480p" / name, textured_frames(6, seed=k))
    return root


def _files(folder):
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.mark.parametrize("quiet", [True, False])
def test_a_full_output_disk_is_one_line_exit_2_and_keeps_the_finished_sequences(tmp_path, capsys, monkeypatch, quiet):
    """The disk fills up while the second sequence is written: one line naming output.dir, exit code 2, no temp
    file or partial folder left, the first sequence's outputs and record intact; the next run does the rest."""
    import contextlib
    import errno
    import json
    import os

    from eponet.cli import main
    from eponet.core import io, outputs

    root = _two_sequences(tmp_path / "davis")
    out = tmp_path / "out"
    assert main(["run", str(_geometry_spec(tmp_path / "clean.yaml", root, tmp_path / "clean")), "-q"]) == 0
    real = io.atomic_path

    @contextlib.contextmanager
    def full_disk(path):
        with real(path) as tmp:
            yield tmp  # the bytes are written, then the disk is full
            if os.sep + ".b." in str(path):  # inside b's partial folder
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), tmp)

    monkeypatch.setattr(io, "atomic_path", full_disk)
    monkeypatch.setattr(outputs, "atomic_path", full_disk)
    spec = _geometry_spec(tmp_path / "s.yaml", root, out)
    assert main(["run", str(spec), *(["-q"] if quiet else [])]) == 2
    err = capsys.readouterr().err.splitlines()
    errors = [line for line in err if line.startswith("error:")]
    assert errors == [f"error: {out}: no space left on the output disk (writing b frame 00000); free some space or "
                      "set output.dir to another disk and run again (finished sequences are kept and skipped)"]
    if quiet:
        assert err == errors
    assert "Traceback" not in "\n".join(err)
    assert sorted(p.name for p in out.iterdir()) == ["a", "run.json"]  # no partial folder, no temp file
    assert not [p for p in out.rglob("*") if p.name.startswith(".")]
    assert list(json.loads((out / "run.json").read_text())["sequences"]) == ["a"]
    clean = _files(tmp_path / "clean" / "a")
    assert clean and _files(out / "a") == clean

    monkeypatch.setattr(io, "atomic_path", real)
    monkeypatch.setattr(outputs, "atomic_path", real)
    assert main(["run", str(spec), "-q"]) == 0
    run = json.loads((out / "run.json").read_text())
    assert run["sequences"]["a"]["resumed"] is True and "resumed" not in run["sequences"]["b"]
    assert _files(out / "b") == _files(tmp_path / "clean" / "b")


def test_a_frame_whose_size_changes_in_the_middle_of_a_folder_is_one_line_and_exit_2(tmp_path):
    from tests.conftest import textured_frames, write_frames

    clip = tmp_path / "clip"
    write_frames(clip, textured_frames(3, size=(48, 64)))
    write_frames(clip, textured_frames(1, size=(40, 64)), start=3)
    write_frames(clip, textured_frames(2, size=(48, 64)), start=4)
    spec = _geometry_spec(tmp_path / "s.yaml", clip, tmp_path / "out")
    expected = f"error: {clip / '00003.png'}: frame is 64x40 but the first frame 00000.png is 64x48"
    for command in ("eponet validate", "eponet.run"):
        result = _run(*command.split(), str(spec))
        assert result.returncode == 2 and result.stderr.strip() == expected, (command, result.stderr)
    assert not (tmp_path / "out").exists()
