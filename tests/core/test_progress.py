"""Progress: bars on a terminal (one per sequence and one for the run), periodic lines in a log, nothing when quiet."""

import io
import logging

import pytest

from eponet.core import progress
from eponet.core.progress import RunProgress, format_eta


@pytest.fixture(autouse=True)
def _not_quiet(monkeypatch):
    monkeypatch.setattr(progress, "_QUIET", False)  # an in-process `eponet run -q` of another test leaves it set


class _Clock:
    def __init__(self):
        self.now = 100.0

    def __call__(self):
        return self.now


def test_off_a_terminal_a_long_sequence_logs_a_line_per_interval(caplog):
    clock = _Clock()
    report = RunProgress(200, bars=False, interval=30, clock=clock)
    with caplog.at_level(logging.INFO, logger="eponet.core.progress"):
        report.start("bear", 200)
        for _ in range(40):  # 4 frames/s for 10 s: shorter than the interval, no line
            clock.now += 0.25
            report.advance("bear")
        assert caplog.messages == []
        for _ in range(100):  # one line at 30 s (120 frames), then none until 60 s
            clock.now += 0.25
            report.advance("bear")
        report.finish("bear")
    assert caplog.messages == ["bear: 120/200 frames, 4.0 frames/s, ETA 20 s"]


def test_a_line_without_a_known_frame_count_has_no_eta():
    clock = _Clock()
    report = RunProgress(None, bars=False, clock=clock)
    report.start("clip", 0)
    clock.now += 10
    report.advance("clip", 25)
    assert report.line("clip") == "clip: 25 frames, 2.5 frames/s"


def test_quiet_logs_no_line(caplog):
    clock = _Clock()
    report = RunProgress(10, bars=False, interval=0, clock=clock)
    progress.set_quiet(True)
    with caplog.at_level(logging.INFO, logger="eponet.core.progress"):
        report.start("clip", 10)
        clock.now += 1
        report.advance("clip")
    assert caplog.messages == []


def test_on_a_terminal_one_bar_per_sequence_and_one_for_the_run():
    out = io.StringIO()
    report = RunProgress(20, bars=True, file=out)
    with report.active():
        assert progress.current() is report
        report.start("a", 10)
        report.start("b", 10)
        assert [s.position for s in report.sequences.values()] == [1, 2]
        report.advance("a", 4)
        report.advance("b", 6)
        report.finish("a")
        report.start("c", 5)  # takes the free row
        assert report.sequences["c"].position == 1
        assert report.overall.n == 10
    text = out.getvalue()
    assert "all:" in text and "a:" in text and "b:" in text and "frame/s" in text and "/20" in text
    assert progress.current() is not report


def test_worker_reports_reach_the_parents_bars():
    import queue

    channel = queue.Queue()
    report = RunProgress(12, bars=False)
    with report.active(), progress.listening(channel):
        worker = progress._Forward(channel)  # what forward_to installs in a worker process
        worker.start("a", 12)
        worker.advance("a", 5)
        for _ in range(100):
            if report.sequences.get("a") is not None and report.sequences["a"].done == 5:
                break
            import time

            time.sleep(0.01)
        assert report.sequences["a"].done == 5
        worker.finish("a")


@pytest.mark.parametrize("seconds, text", [(0.4, "0 s"), (59.6, "1 min 00 s"), (3599, "59 min 59 s"), (3600, "1 h 00 min")])
def test_eta_format(seconds, text):
    assert format_eta(seconds) == text
