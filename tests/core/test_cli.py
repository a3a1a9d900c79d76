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
