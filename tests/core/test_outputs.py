"""Output files: permissions the umask gives (not tempfile's 0700 / 0600), overlay.mp4 as H.264 at the input's
frame rate, panels of titled tiles with ED in absolute pixels."""

import os
import stat
import subprocess
import sys

import av
import numpy as np
import pytest

from eponet.core.errors import OutputError, SpecError
from eponet.core.outputs import ED_PANEL_FLOOR_PX, OVERLAY_FPS, PANEL_HEIGHT, TITLE_HEIGHT, SequenceWriter, panel
from eponet.core.pipeline import Pipeline
from eponet.core.spec import parse_spec
from eponet.core.stream import FrameItem
from tests.conftest import textured_frames, write_video


def test_outputs_honour_the_umask(tmp_path, frames_dir):
    spec = tmp_path / "spec.yaml"
    spec.write_text(f"preset: geometry\ninput: {{path: {frames_dir}, scale: 1.0}}\n"
                    "stages: {trajectories: null, rigidity: null}\n"
                    f"output: {{dir: {tmp_path / 'out'}, save: [flow, panels]}}\ncache: {{enabled: false}}\n")
    result = subprocess.run([sys.executable, "-m", "eponet.run", str(spec), "-q"], capture_output=True, text=True,
                            timeout=300, preexec_fn=lambda: os.umask(0o022))
    assert result.returncode == 0, result.stderr
    modes = {p.relative_to(tmp_path).as_posix(): stat.S_IMODE(p.stat().st_mode) for p in (tmp_path / "out").rglob("*")}
    assert modes["out/clip"] == 0o755 and modes["out/run.json"] == 0o644
    assert {m for p, m in modes.items() if (tmp_path / p).is_dir()} == {0o755}
    assert {m for p, m in modes.items() if (tmp_path / p).is_file()} == {0o644}


# -- overlay.mp4: H.264 at the input's frame rate; panels: titled tiles, ED in absolute pixels -----------------



def _decoded(path):
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        frames = [f.to_ndarray(format="rgb24") for f in container.decode(stream)]
        return stream.codec_context.name, stream.codec_context.pix_fmt, float(stream.average_rate), frames


def test_a_10_fps_video_gives_a_10_fps_h264_overlay(tmp_path):
    frames = textured_frames(count=5, size=(48, 64))
    video = write_video(tmp_path / "clip.avi", frames)
    spec = parse_spec({"preset": "epo", "input": {"path": str(video), "scale": 0.5},
                       "stages": {"refiner": {"plugin": "threshold"}},
                       "output": {"dir": str(tmp_path / "out"), "save": ["overlay"]}, "cache": {"enabled": False}})
    Pipeline(spec).run()
    codec, pix_fmt, fps, decoded = _decoded(tmp_path / "out" / "clip" / "overlay.mp4")
    assert (codec, pix_fmt, fps, len(decoded)) == ("h264", "yuv420p", 10.0, 5)
    assert decoded[0].shape == (48, 64, 3)
    assert not (tmp_path / "out" / "clip" / ".overlay.tmp.mp4").exists()


def test_pyav_is_imported_only_for_an_overlay(tmp_path, monkeypatch):
    """A run without overlay.mp4 does not load FFmpeg (~70 ms of start-up); a failing encoder is still one line."""
    code = "import sys, eponet.run, eponet.core.outputs; print('av' in sys.modules)"
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip() == "False"
    frames = textured_frames(count=3, size=(48, 64))

    def broken(*args, **kwargs):
        raise av.FFmpegError(28, "No space left on device")

    monkeypatch.setattr(av, "open", broken)
    writer = SequenceWriter(tmp_path / "out", "clip", ("overlay",), (48, 64), (48, 64), fps=10.0)
    with pytest.raises(OutputError, match="no space left on the output disk \\(writing clip frame 00000\\)"):
        writer.write(_item(0, frames[0], np.zeros((48, 64), bool)))
    writer.abort()
    assert list((tmp_path / "out").iterdir()) == []


def _item(t, frame, mask):
    item = FrameItem(t, f"{t:05d}", frame)
    item.mask = mask
    return item


def test_overlay_of_frames_is_at_the_default_or_the_given_rate_odd_sides_padded(tmp_path):
    frames = textured_frames(count=4, size=(49, 65))  # odd sides: yuv420p needs even ones
    mask = np.zeros((49, 65), np.uint8)
    mask[10:30, 20:40] = 1
    for fps, expected in ((None, OVERLAY_FPS), (12.5, 12.5)):
        writer = SequenceWriter(tmp_path, f"seq{fps}", ("overlay",), (49, 65), (49, 65), fps=fps)
        for t, frame in enumerate(frames):
            writer.write(_item(t, frame, mask))
        codec, _, rate, decoded = _decoded(writer.close() / "overlay.mp4")
        # padded by one row and one column
        assert (codec, rate, len(decoded), decoded[0].shape) == ("h264", expected, 4, (50, 66, 3))
        # the mask is tinted red in the decoded video, the background is not
        red, green = decoded[1][..., 0].astype(int), decoded[1][..., 1].astype(int)
        assert red[20, 30] - green[20, 30] > 60 > abs(red[40, 5] - green[40, 5])


def test_output_fps_is_validated_with_its_yaml_path(tmp_path, frames_dir):
    with pytest.raises(SpecError) as error:
        parse_spec({"preset": "geometry", "input": {"path": str(frames_dir)},
                    "output": {"dir": str(tmp_path / "o"), "save": ["flow"], "fps": 0}})
    assert str(error.value) == "output.fps: expected a number > 0 or null, got 0"
    spec = parse_spec({"preset": "geometry", "input": {"path": str(frames_dir)},
                       "output": {"dir": str(tmp_path / "o"), "save": ["flow"], "fps": 12.5}})
    assert spec.output.fps == 12.5 and spec.document["output"]["fps"] == 12.5


def _panel_item(ed, ed_scale=None):
    frame = textured_frames(count=1, size=(48, 64))[0]
    item = FrameItem(0, "00000", frame)
    item.motion_flow = np.full((48, 64, 2), 3.0, np.float32)
    item.ed, item.ed_scale = ed.astype(np.float32), ed_scale
    item.probability = np.linspace(0, 1, 48 * 64, dtype=np.float32).reshape(48, 64)
    item.mask = (item.probability > 0.5).astype(np.uint8)
    return item


def test_panel_tiles_carry_titles_and_colour_bars():
    item = _panel_item(np.zeros((48, 64)))
    image = panel(item, factor=2.0)
    width = 320  # 64 x 48 px tiles at PANEL_HEIGHT = 240
    assert image.shape == (TITLE_HEIGHT + PANEL_HEIGHT, 5 * width, 3)
    for k in range(5):
        strip, tile = image[:TITLE_HEIGHT, k * width:(k + 1) * width], image[TITLE_HEIGHT:, k * width:(k + 1) * width]
        text = (strip.min(axis=2) > 200).sum()  # white title text on black
        assert text > 30 and not np.array_equal(strip, tile[:TITLE_HEIGHT]), k
    bars = [image[15:20, k * width + 10:(k + 1) * width - 10].astype(int) for k in range(5)]
    colourful = [bool((np.ptp(bar, axis=2) > 40).any()) for bar in bars]
    assert colourful == [False, False, True, True, False]  # colour bars on the ED and saliency tiles
    # the flow title names its scale in input px (3 px at the processing size, factor 2): "flow max 6.0 px"
    assert not np.array_equal(panel(item, factor=2.0)[:TITLE_HEIGHT, width:2 * width],
                              panel(item, factor=1.0)[:TITLE_HEIGHT, width:2 * width])


def _ed_tile(item):
    return panel(item)[TITLE_HEIGHT:, 2 * 320:3 * 320].max(axis=2)  # brightness of the ED tile


def test_the_ed_tile_is_in_absolute_pixels_static_dark_moving_bright():
    rng = np.random.default_rng(0)
    noise = rng.uniform(0.0, 1.0, (48, 64))  # a static clip: ED is flow noise below 1 px
    scale = float(np.percentile(noise, 95))
    static = _ed_tile(_panel_item(noise, ed_scale=scale))
    assert static.mean() < 90 and np.percentile(static, 99) < 150  # dark, not stretched to the noise's range
    assert ED_PANEL_FLOOR_PX == 3.0
    moving = noise.copy()
    moving[12:36, 16:48] = 6.0  # an object moving on its own: 6 px off the camera's epipolar lines
    tile = _ed_tile(_panel_item(moving, ed_scale=float(np.percentile(moving, 95))))
    assert tile[80:160, 100:220].min() > 200 and tile[:40, :40].mean() < 90  # bright object, dark background
