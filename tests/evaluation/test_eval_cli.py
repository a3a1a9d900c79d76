"""``python -m eponet.evaluate``: exit codes, one-line errors, JSON / CSV / chart outputs."""

from __future__ import annotations

import csv
import json
import subprocess
import sys

import numpy as np
import pytest

from .evalkit import make_davis2016, moving_square, write_results
from eponet.evaluate import main

INFO = {
    "attributes": ["AC", "DB", "FM", "MB", "OCC"],
    "sequences": [
        {"name": "alpha", "attributes": ["FM"], "eval_t": True, "set": "val"},
        {"name": "beta", "attributes": ["DB", "OCC"], "eval_t": False, "set": "val"},
    ],
}


@pytest.fixture
def setup(tmp_path):
    seqs = {"alpha": moving_square(7), "beta": moving_square(6, step=1, start=(20, 20))}
    root = make_davis2016(tmp_path / "DAVIS", seqs, INFO)
    res = {k: [np.roll(m, 1, axis=1) for m in v] for k, v in seqs.items()}
    results = write_results(tmp_path / "results", res)
    return root, results, tmp_path


def test_success_writes_json_csv_and_chart(setup, capsys):
    root, results, tmp = setup
    out_json = tmp / "eval" / "scores.json"
    code = main(["--dataset", "davis2016", "--root", str(root), "--results", str(results),
                 "--json", str(out_json), "--csv", str(tmp / "eval" / "scores.csv"), "--workers", "1"])
    assert code == 0
    printed = capsys.readouterr().out
    assert "J  Mean" in printed and "Recall" in printed and "Decay" in printed and "T  Mean" in printed
    assert "Attribute" in printed and "OCC" in printed
    data = json.loads(out_json.read_text())
    assert set(data) >= {"sequences", "overall", "attributes"}
    for seq in ("alpha", "beta"):
        entry = data["sequences"][seq]
        assert set(entry["J"]) == {"mean", "recall", "decay"}
        assert set(entry["F"]) == {"mean", "recall", "decay"}
        assert 0.5 < entry["J"]["mean"] < 1.0 and entry["F"]["mean"] == 1.0
        assert entry["frames_scored"] == entry["frames_in_ground_truth"] == entry["n_frames"]
    assert set(data["sequences"]["alpha"]["T"]) == {"mean"}
    assert data["sequences"]["beta"]["T"]["mean"] is None
    assert "eval_t" in data["sequences"]["beta"]["T"]["missing"]  # says why it has no T
    assert data["overall"]["T"]["mean"] is not None
    assert set(data["attributes"]["DB"]) == {"with", "without", "change", "n_with", "n_without"}
    rows = list(csv.reader((tmp / "eval" / "scores.csv").open()))
    assert rows[0][:4] == ["sequence", "J_mean", "J_recall", "J_decay"]
    assert [r[0] for r in rows[1:]] == ["alpha", "beta", "Average"]
    chart = tmp / "eval" / "scores.png"  # default: beside the JSON
    assert chart.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_sequences_option_chart_path_and_quiet(setup, capsys):
    root, results, tmp = setup
    code = main(["--dataset", "DAVIS-2016", "--root", str(root), "--results", str(results), "--sequences", "beta",
                 "--no-t", "--chart", str(tmp / "c.png"), "-q", "--workers", "1"])
    assert code == 0
    assert capsys.readouterr().out == ""
    assert (tmp / "c.png").is_file()


def test_missing_frame_is_exit_2_with_one_line_naming_it(setup, capsys):
    root, results, tmp = setup
    (results / "alpha" / "masks" / "00004.png").unlink()
    code = main(["--dataset", "davis2016", "--root", str(root), "--results", str(results), "--workers", "1"])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert "alpha" in err[0] and "00004" in err[0] and "Traceback" not in err[0]


def test_missing_sequence_root_and_unknown_dataset(setup, capsys):
    root, results, tmp = setup
    import shutil

    shutil.rmtree(results / "beta")
    assert main(["--dataset", "davis2016", "--root", str(root), "--results", str(results)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "'beta'" in err[0]
    assert main(["--dataset", "davis2016", "--root", str(tmp / "nope"), "--results", str(results)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nope" in err[0] and "does not exist" in err[0]
    assert main(["--dataset", "kitti", "--root", str(root), "--results", str(results)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unknown dataset 'kitti'" in err[0] and "davis2016" in err[0]


def test_usage_error_is_one_line_exit_2(capsys):
    with pytest.raises(SystemExit) as info:
        main(["--dataset", "davis2016"])
    assert info.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--root" in err[0]


def test_verbose_shows_traceback(setup, capsys):
    root, results, tmp = setup
    assert main(["--dataset", "davis2016", "--root", str(tmp / "nope"), "--results", str(results), "-v"]) == 2
    assert "Traceback" in capsys.readouterr().err


def test_module_entry_point(setup):
    root, results, tmp = setup
    proc = subprocess.run([sys.executable, "-m", "eponet.evaluate", "--dataset", "davis2016", "--root", str(root),
                           "--results", str(tmp / "missing"), "-q"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.strip().count("\n") == 0 and "results folder does not exist" in proc.stderr


def test_a_run_with_max_frames_scores_the_frames_it_processed(tmp_path, capsys):
    seqs = {"alpha": moving_square(7), "beta": moving_square(6, step=1, start=(20, 20))}
    root = make_davis2016(tmp_path / "DAVIS", seqs, INFO)
    results = write_results(tmp_path / "results", {k: v[:4] for k, v in seqs.items()})  # input.max_frames 4
    args = ["--dataset", "davis2016", "--root", str(root), "--results", str(results), "--workers", "1",
            "--json", str(tmp_path / "scores.json")]
    assert main(args) == 2 and "scored frames missing" in capsys.readouterr().err  # no record of the limit
    (results / "run.json").write_text(json.dumps({"spec": {"input": {"max_frames": 4}}}))
    assert main(args) == 0
    err = capsys.readouterr().err
    assert "first 4 frames of each sequence (input.max_frames)" in err and "6 of 9 scored ground-truth frames" in err
    data = json.loads((tmp_path / "scores.json").read_text())
    alpha = data["sequences"]["alpha"]
    assert (alpha["frames_scored"], alpha["frames_in_ground_truth"], alpha["n_frames"]) == (3, 5, 3)
    assert alpha["J"]["mean"] == 1.0 and data["max_frames"] == 4
    assert main(args + ["--max-frames", "2"]) == 0  # the flag wins over run.json; one scored frame: no T
    data = json.loads((tmp_path / "scores.json").read_text())
    assert data["sequences"]["alpha"]["frames_scored"] == 1
    assert "too few frames" in data["sequences"]["alpha"]["T"]["missing"]


def test_a_sequence_typo_suggests_the_nearest_name(setup, capsys):
    root, results, _ = setup
    code = main(["--dataset", "davis2016", "--root", str(root), "--results", str(results), "--sequences", "alpah"])
    err = capsys.readouterr().err
    assert code == 2 and "did you mean 'alpha'" in err and len(err.strip().splitlines()) == 1


def test_the_run_evaluation_scores_the_frames_of_input_max_frames(tmp_path):
    from types import SimpleNamespace

    from eponet.plugins.evaluate import eponet_evaluate

    seqs = {"alpha": moving_square(7)}
    root = make_davis2016(tmp_path / "DAVIS", seqs, INFO)
    results = write_results(tmp_path / "results", {"alpha": seqs["alpha"][:5]})
    spec = SimpleNamespace(evaluate={"dataset": "davis2016", "root": root, "t": True}, output=SimpleNamespace(dir=results),
                           input=SimpleNamespace(path=root, resolution="480p", max_frames=5))
    result = eponet_evaluate(spec=spec, sequences=["alpha"])
    alpha = result["sequences"]["alpha"]
    assert (alpha["frames_scored"], alpha["frames_in_ground_truth"]) == (4, 5) and alpha["T"]["mean"] is not None
