import cv2
import numpy as np
import pytest

from eponet.core.errors import InputError
from eponet.core.inputs import discover_sequences, iter_frames, load_video
from tests.conftest import textured_frames, write_frames, write_video


def test_frames_folder_natural_order_and_scale(tmp_path):
    frames = textured_frames(count=4, size=(40, 60))
    folder = tmp_path / "seq"
    folder.mkdir()
    for t, name in enumerate(["f1", "f2", "f10", "f11"]):
        cv2.imwrite(str(folder / f"{name}.png"), cv2.cvtColor(frames[t], cv2.COLOR_RGB2BGR))
    (source,) = discover_sequences(folder)
    assert source.name == "seq" and source.stems == ["f1", "f2", "f10", "f11"] and source.size == (40, 60)
    video = load_video(source, scale=0.5)
    assert video.frames.shape == (4, 20, 30, 3) and video.full_frames.shape == (4, 40, 60, 3)
    np.testing.assert_array_equal(video.full_frames[2], frames[2])


def test_video_file(tmp_path):
    frames = textured_frames(count=6, size=(48, 64))
    path = write_video(tmp_path / "clip.avi", frames)
    (source,) = discover_sequences(path)
    video = load_video(source, scale=1.0)
    assert video.name == "clip" and video.num_frames == 6 and video.stems[:2] == ["00000", "00001"]
    assert np.abs(video.frames.astype(int) - frames.astype(int)).mean() < 8  # MJPG is lossy


def test_davis_root_with_sequences(tmp_path):
    for name in ("bear", "car"):
        write_frames(tmp_path / "JPEGImages" / "480p" / name, textured_frames(3), suffix=".jpg")
    assert [s.name for s in discover_sequences(tmp_path)] == ["bear", "car"]
    assert [s.name for s in discover_sequences(tmp_path, sequences=["car"])] == ["car"]
    with pytest.raises(InputError, match=r"no sequence 'cat' in .* \(did you mean 'car'\?\)"):
        discover_sequences(tmp_path, sequences=["cat"])
    with pytest.raises(InputError, match=r"input.resolution: .*240p does not exist; resolutions here: 480p"):
        discover_sequences(tmp_path, resolution="240p")


def test_max_frames(frames_dir):
    (source,) = discover_sequences(frames_dir, max_frames=3)
    assert source.count == 3 and load_video(source, scale=1.0, max_frames=3).num_frames == 3


@pytest.mark.parametrize("case", ["empty", "two_frames", "corrupt", "sizes", "not_video", "single_image"])
def test_bad_inputs_name_the_problem(tmp_path, case):
    folder = tmp_path / "seq"
    folder.mkdir()
    if case == "empty":
        path, pattern = folder, r"seq: empty folder"
    elif case == "two_frames":
        write_frames(folder, textured_frames(2))
        path, pattern = folder, r"seq: 2 frame\(s\), the pipeline needs at least 3"
    elif case == "corrupt":
        write_frames(folder, textured_frames(3))
        (folder / "00001.png").write_bytes(b"\x89PNG garbage")
        path, pattern = folder, r"00001.png: cannot read image"
    elif case == "sizes":
        write_frames(folder, textured_frames(3))
        write_frames(folder, textured_frames(1, size=(30, 30)), start=3)
        path, pattern = folder, r"00003.png: frame is 30x30 but the first frame 00000.png is 64x48"
    elif case == "not_video":
        path = tmp_path / "notes.mp4"
        path.write_text("this is not a video")
        pattern = r"notes.mp4: not a readable video"
    else:
        path = write_frames(folder, textured_frames(1))[0]
        pattern = r"a single image"
    with pytest.raises(InputError, match=pattern):
        discover_sequences(path)


def test_a_video_cut_short_says_the_frame_it_stopped_at(tmp_path):
    """A file truncated mid-way (or with a corrupt frame) ends decoding early; the header still announces
    every frame. The sequence ends there, not silently: ``stopped`` names the frame (the run fails with it
    after writing the frames before), and a tool that needs the whole video gets it as an error."""
    whole = write_video(tmp_path / "whole.avi", textured_frames(20, (48, 64)))
    cut = tmp_path / "cut.avi"
    cut.write_bytes(whole.read_bytes()[: whole.stat().st_size // 2])
    complete = discover_sequences(whole)[0]
    assert sum(1 for _ in iter_frames(complete, scale=1.0)) == 20 and complete.stopped is None
    source = discover_sequences(cut)[0]
    decoded = sum(1 for _ in iter_frames(source, scale=1.0))
    assert source.count == 20 and 3 <= decoded < 18
    assert source.stopped == (f"{cut}: the decoder stopped at frame {decoded} of the 20 the header announces "
                              "(a corrupt or truncated file?)")
    with pytest.raises(InputError, match="the decoder stopped at frame"):
        load_video(discover_sequences(cut)[0], scale=1.0)


def test_a_corrupt_frame_after_the_first_three_cuts_the_folder_there(tmp_path):
    paths = write_frames(tmp_path / "seq", textured_frames(6))
    paths[4].write_bytes(paths[4].read_bytes()[:60])  # the header reads, the body does not
    source = discover_sequences(tmp_path / "seq")[0]
    assert source.count == 6 and source.stopped is None  # found when decoding
    assert [stem for stem, _, _ in iter_frames(source, scale=1.0)] == ["00000", "00001", "00002", "00003"]
    assert source.stopped.startswith(f"{paths[4]}: cannot read image")
    paths[4].write_bytes(b"garbage")  # found when the folder is checked
    source = discover_sequences(tmp_path / "seq")[0]
    assert source.count == 4 and source.stopped == f"{paths[4]}: cannot read image (not an image or corrupt)"
    assert len(list(iter_frames(source, scale=1.0))) == 4


def test_a_folder_without_image_frames_says_so_and_what_is_accepted(tmp_path):
    for name in ("b.txt", "a.txt", "notes10.txt", "notes2.txt"):
        (tmp_path / name).write_text("x")
    with pytest.raises(InputError) as caught:
        discover_sequences(tmp_path)
    assert str(caught.value) == (f"{tmp_path}: no image frames (it holds a.txt, b.txt, notes2.txt and 1 more); "
                                 "accepted extensions: .jpg, .jpeg, .png, .bmp, .ppm, .pgm, .tif, .tiff")


def test_frames_smaller_than_the_minimum_are_refused_naming_the_input(tmp_path):
    paths = write_frames(tmp_path / "tiny", np.zeros((3, 1, 1, 3), np.uint8))
    with pytest.raises(InputError) as caught:
        discover_sequences(tmp_path / "tiny")
    assert str(caught.value) == f"{paths[0]}: frames are 1x1 px; the pipeline needs frames of at least 16x16 px"
    video = write_video(tmp_path / "small.avi", textured_frames(3, size=(8, 32)))
    with pytest.raises(InputError, match=r"small.avi: frames are 32x8 px; the pipeline needs frames of at least 16x16"):
        discover_sequences(video)


def _corpus(tmp_path):
    """Frame folders ``a`` and ``b`` and a video ``clips/c.avi`` under ``tmp_path/data``."""
    data = tmp_path / "data"
    write_frames(data / "a", textured_frames(3))
    write_frames(data / "b", textured_frames(4))
    (data / "clips").mkdir()
    write_video(data / "clips" / "c.avi", textured_frames(5))
    return data


def test_a_list_file_names_videos_and_frame_folders_relative_to_itself(tmp_path):
    data = _corpus(tmp_path)
    listing = data / "corpus.txt"
    listing.write_text("# comments and blank lines are skipped\n\nclips/c.avi\n  a  \n" f"{data / 'b'}\n")
    sources = discover_sequences(listing)
    assert [(s.name, s.count, s.error) for s in sources] == [("c", 5, None), ("a", 3, None), ("b", 4, None)]
    assert sources[0].video == data / "clips" / "c.avi" and sources[1].files[0].parent == data / "a"
    assert [s.name for s in discover_sequences(listing, sequences=["b", "c"])] == ["b", "c"]
    with pytest.raises(InputError, match=r"input.sequences: no sequence 'bb' in the corpus \(did you mean 'b'\?\)"):
        discover_sequences(listing, sequences=["bb"])


def test_a_missing_or_bad_list_entry_is_named_and_with_isolate_the_others_stay(tmp_path):
    data = _corpus(tmp_path)
    write_frames(data / "short", textured_frames(2))
    listing = data / "corpus.txt"
    listing.write_text("a\nmissing/d.mp4\nshort\nb\n")
    with pytest.raises(InputError, match=r"corpus.txt: line 2: .*missing/d.mp4 does not exist"):
        discover_sequences(listing)
    sources = discover_sequences(listing, isolate=True)
    assert [s.name for s in sources] == ["a", "d", "short", "b"]
    assert [s.error is None for s in sources] == [True, False, False, True]
    assert "line 2" in sources[1].error and "2 frame(s), the pipeline needs at least 3" in sources[2].error


def test_a_glob_matches_videos_and_frame_folders_in_natural_order(tmp_path):
    data = _corpus(tmp_path)
    write_frames(data / "a10", textured_frames(3))
    write_frames(data / "a2", textured_frames(3))
    assert [s.name for s in discover_sequences(data / "a*")] == ["a", "a2", "a10"]
    assert [s.name for s in discover_sequences(data / "**" / "*.avi")] == ["c"]
    with pytest.raises(InputError, match=r"input.path: no file or folder matches .*\*.mp4"):
        discover_sequences(data / "*.mp4")


def test_two_corpus_entries_with_one_name_are_refused(tmp_path):
    data = _corpus(tmp_path)
    write_frames(data / "other" / "a", textured_frames(3))
    listing = data / "corpus.txt"
    listing.write_text("a\nother/a\n")
    with pytest.raises(InputError, match=r"line 2: .*other/a and .*data/a would both be sequence 'a'"):
        discover_sequences(listing)
    (data / "empty.txt").write_text("# nothing\n")
    with pytest.raises(InputError, match=r"empty.txt lists no videos or frame folders"):
        discover_sequences(data / "empty.txt")
