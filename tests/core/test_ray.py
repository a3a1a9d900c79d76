"""The ray executor (``run.executor: ray``) on a local Ray instance with 2 CPUs, started once for the module: the
same masks as the local executor, failures isolated, resume after a killed run, a killed actor retried."""

from __future__ import annotations

import importlib.util
import json
import logging
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from eponet.core.errors import SequenceFailures, SpecError
from eponet.core.pipeline import Pipeline
from eponet.core.ray_executor import await_release
from eponet.core.spec import parse_spec
from tests.conftest import REPO, textured_frames, write_frames

HAVE_RAY = importlib.util.find_spec("ray") is not None
needs_ray = pytest.mark.skipif(not HAVE_RAY, reason="ray is not installed (pip install -e '.[ray]')")
NAMES = ["s0", "s1", "s2", "s3"]


def moving_square_frames(count: int, seed: int) -> np.ndarray:
    """A textured background panning by (1, 0.5) px a frame and a textured square moving 2 px a frame across it (at most 16 frames)."""
    frames = textured_frames(count, (48, 64), shift=(1.0, 0.5), seed=seed).copy()
    square = textured_frames(count, (14, 14), shift=(0.0, 0.0), seed=seed + 100)
    for t in range(count):
        frames[t, 20:34, 4 + 2 * t: 18 + 2 * t] = square[t]
    return frames


def spec_document(path: Path, out: Path, executor: str, **run) -> dict:
    return {"preset": "epo", "input": {"path": str(path), "scale": 1.0},
            "stages": {"motion_net": {"weights": "epo-davis"}, "refiner": {"plugin": "threshold"}},
            "output": {"dir": str(out), "save": ["masks"]}, "cache": {"enabled": False},
            "run": {"executor": executor, "chunk": 4, "lag": 2, **({"workers": 1} if executor == "local" else {}), **run}}


def run(path: Path, out: Path, executor: str = "ray", **run_settings) -> dict:
    return Pipeline(parse_spec(spec_document(path, out, executor, **run_settings))).run()


def masks_of(out: Path, name: str) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted((out / name / "masks").iterdir())}


def partials(out: Path) -> list[str]:
    return [p.name for p in out.iterdir() if p.name.startswith(".")]


@pytest.fixture(scope="module")
def corpus(tmp_path_factory) -> Path:
    """Four 8-frame sequences (frame folders) and ``list.txt`` naming them."""
    root = tmp_path_factory.mktemp("corpus")
    for seed, name in enumerate(NAMES):
        write_frames(root / name, moving_square_frames(8, seed))
    (root / "list.txt").write_text("# the corpus\n" + "\n".join(NAMES) + "\n")
    return root / "list.txt"


@pytest.fixture(scope="module")
def reference(corpus, tmp_path_factory) -> Path:
    """The corpus run by the local executor (in this process)."""
    out = tmp_path_factory.mktemp("local")
    run(corpus, out, "local")
    return out


@pytest.fixture(scope="module")
def ray_instance():
    if not HAVE_RAY:
        pytest.skip("ray is not installed (pip install -e '.[ray]')")
    import ray

    ray.init(address="local", num_cpus=2, include_dashboard=False, logging_level=logging.WARNING)
    yield ray
    ray.shutdown()


@needs_ray
def test_masks_are_byte_identical_between_ray_and_local(corpus, reference, ray_instance, tmp_path):
    manifest = run(corpus, tmp_path)
    assert list(manifest["sequences"]) == NAMES and "failed" not in manifest
    for name in NAMES:
        local = masks_of(reference, name)
        assert len(local) == 8 and any(np.frombuffer(b, np.uint8).any() for b in local.values())
        assert masks_of(tmp_path, name) == local, name
    # 2 actors of one CPU each (the fixture's 2 CPUs), each with one torch/OpenCV thread; the 4 sequences ran on
    # those 2 processes, each of which built its pipeline once
    assert manifest["ray"] == {"actors": 2, "cpus_per_actor": 1, "address": None, "retries": 2}
    workers = [entry["worker"] for entry in manifest["sequences"].values()]
    assert {w["threads"] for w in workers} == {1} and len({w["pid"] for w in workers}) <= 2
    assert json.loads((tmp_path / "run.json").read_text())["spec"]["run"]["executor"] == "ray"
    assert partials(tmp_path) == []


@needs_ray
def test_a_failing_sequence_does_not_stop_the_others_and_a_rerun_redoes_only_it(corpus, reference, ray_instance,
                                                                                 tmp_path, caplog):
    bad = write_frames(tmp_path / "bad", moving_square_frames(8, 7))
    good = bad[2].read_bytes()
    bad[2].write_bytes(good[:60])  # its header reads, its pixels do not: the sequence fails in its actor (one of
    # the first three frames: a later one would end the sequence there, keeping the frames before it)
    listing = tmp_path / "corpus.txt"
    listing.write_text(f"{corpus.parent / 's0'}\nbad\n{corpus.parent / 's1'}\ngone\n")
    out = tmp_path / "out"
    with caplog.at_level(logging.ERROR), pytest.raises(SequenceFailures) as failure:
        run(listing, out)
    assert failure.value.exit_code == 2  # both are bad inputs
    message = str(failure.value)
    assert message.startswith("2 of 4 sequences failed") and "bad/00002.png" in message and "gone" in message
    assert "\n" not in message
    record = json.loads((out / "run.json").read_text())
    assert list(record["sequences"]) == ["s0", "s1"]
    assert set(record["failed"]) == {"bad", "gone"}
    assert "line 4" in record["failed"]["gone"]["reason"] and "does not exist" in record["failed"]["gone"]["reason"]
    assert "bad: failed:" in caplog.text and "gone: failed:" in caplog.text
    assert sorted(p.name for p in out.iterdir()) == ["run.json", "s0", "s1"]  # nothing half-written
    for name in ("s0", "s1"):
        assert masks_of(out, name) == masks_of(reference, name)
    # repaired, and the missing entry dropped: the re-run processes only the failed sequence
    bad[2].write_bytes(good)
    listing.write_text(f"{corpus.parent / 's0'}\nbad\n{corpus.parent / 's1'}\n")
    again = run(listing, out)
    assert {n: e.get("resumed", False) for n, e in again["sequences"].items()} == {"s0": True, "bad": False, "s1": True}
    assert "failed" not in again and len(masks_of(out, "bad")) == 8


def _cli(spec: dict, folder: Path, *overrides: str) -> subprocess.Popen:
    path = folder / "spec.yaml"
    path.write_text(yaml.safe_dump(spec))
    log = open(folder / "cli.log", "w")
    return subprocess.Popen([sys.executable, "-m", "eponet.run", str(path), "-q",
                             *[f"--set={o}" for o in overrides]], cwd=REPO, stdout=log, stderr=subprocess.STDOUT)


@needs_ray
def test_resume_after_a_killed_run(corpus, reference, ray_instance, tmp_path):
    out = tmp_path / "out"
    address = ray_instance.get_runtime_context().gcs_address  # the driver joins the module's Ray instance
    process = _cli(spec_document(corpus, out, "ray", address=address), tmp_path)
    record = out / "run.json"
    deadline = time.time() + 240
    try:
        while time.time() < deadline and process.poll() is None:
            if record.is_file() and json.loads(record.read_text()).get("sequences"):
                break
            time.sleep(0.02)
        assert process.poll() is None, (tmp_path / "cli.log").read_text()[-2000:]
        process.send_signal(signal.SIGKILL)  # the driver: its actors go with it
    finally:
        process.kill()
        process.wait()
    done = list(json.loads(record.read_text())["sequences"])
    assert 1 <= len(done) < len(NAMES)
    manifest = run(corpus, out)
    assert {n for n, e in manifest["sequences"].items() if e.get("resumed")} == set(done)
    assert list(manifest["sequences"]) == NAMES
    for name in NAMES:
        assert masks_of(out, name) == masks_of(reference, name), name
    assert partials(out) == []  # the killed run's half-written folders are gone


def _running_actor() -> int | None:
    """The pid of a Ray worker process running a sequence (Ray titles it ``ray::SequenceWorker.run``)."""
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                if (entry / "cmdline").read_bytes().startswith(b"ray::SequenceWorker.run"):
                    return int(entry.name)
            except OSError:
                continue
    return None


@needs_ray
@pytest.mark.skipif(not Path("/proc").is_dir(), reason="finds the actor's process in /proc")
def test_an_actor_killed_mid_sequence_gets_its_sequence_retried(ray_instance, tmp_path):
    # the actors of an earlier test's killed driver are released by Ray asynchronously: this test wants one actor
    # with both CPUs
    await_release(ray_instance, 2, timeout_s=60)
    write_frames(tmp_path / "long", moving_square_frames(16, 3))
    out = tmp_path / "out"
    killed = {}

    def kill_mid_sequence():
        deadline = time.time() + 240
        while time.time() < deadline and not killed:
            for folder in out.glob(".long.*.partial") if out.is_dir() else []:
                written = len(list((folder / "masks").glob("*.png"))) if (folder / "masks").is_dir() else 0
                pid = _running_actor()
                if 1 <= written < 16 and pid is not None:
                    os.kill(pid, signal.SIGKILL)
                    killed.update(pid=pid, written=written, partial=folder.name)
            time.sleep(0.005)

    killer = threading.Thread(target=kill_mid_sequence, daemon=True)
    killer.start()
    manifest = run(tmp_path / "long", out, workers=1)  # one actor (with both CPUs): the one running is killed
    killer.join()
    assert killed, "the sequence finished before its actor could be killed"
    entry = manifest["sequences"]["long"]
    assert entry["worker"]["pid"] != killed["pid"] and entry["worker"]["threads"] == 2 and entry["frames"] == 16
    assert partials(out) == []  # the killed attempt's folder is gone
    reference = tmp_path / "local"
    run(tmp_path / "long", reference, "local")
    assert masks_of(out, "long") == masks_of(reference, "long")


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@needs_ray
def test_an_address_that_cannot_be_reached_is_one_line_and_exit_code_2(corpus, tmp_path):
    port = _free_port()  # nothing listens there
    started = time.time()
    process = _cli(spec_document(corpus, tmp_path / "out", "ray", address=f"ray://127.0.0.1:{port}"), tmp_path)
    assert process.wait(timeout=120) == 2
    lines = (tmp_path / "cli.log").read_text().strip().splitlines()
    assert lines[-1] == f"error: run.address: cannot reach the Ray cluster at ray://127.0.0.1:{port} (Connection " \
                        f"refused; waited at most 10 s)", lines
    assert time.time() - started < 60
    assert not (tmp_path / "out").exists()


def test_executor_ray_without_ray_installed_is_one_line_at_validation(corpus, tmp_path, monkeypatch):
    from eponet.core import ray_executor

    real = importlib.util.find_spec
    monkeypatch.setattr(ray_executor.importlib.util, "find_spec", lambda name, *a: None if name == "ray" else real(name, *a))
    with pytest.raises(SpecError) as error:
        parse_spec(spec_document(corpus, tmp_path, "ray"))
    assert error.value.problems == ["run.executor: ray is not installed; install eponet's ray extra: "
                                    "pip install -e '.[ray]'"]
    parse_spec(spec_document(corpus, tmp_path, "local"))  # the local executor does not need it


@pytest.mark.parametrize("address", ["nohost", "ray://host", "host:99999", "http://host:10001"])
def test_a_malformed_address_is_a_validation_error(corpus, tmp_path, address):
    with pytest.raises(SpecError, match=r"run.address: expected null, 'auto', 'ray://host:port' or 'host:port'"):
        parse_spec(spec_document(corpus, tmp_path, "local", address=address))
    for good in (None, "auto", "ray://head.example:10001", "10.0.0.1:6379"):
        parse_spec(spec_document(corpus, tmp_path, "local", address=good))
