"""Progress output: a bar on a terminal, whole lines now and then elsewhere, nothing when quiet."""

import io
import logging
import queue
import re
import time

import pytest
from tqdm.contrib.logging import logging_redirect_tqdm

import cnep.pipeline.progress as progress
from cnep.pipeline.cli.main import main
from cnep.recordings import write_demonstration
from tests.recordings.factories import demonstration_factory


class Terminal(io.StringIO):
    def isatty(self):
        return True


def test_a_log_file_gets_a_line_at_the_start_and_one_at_the_end_and_no_carriage_returns():
    stream = io.StringIO()
    with progress.progress_bar(total=300, desc="extract train", unit="frame", stream=stream) as bar:
        for _ in range(300):
            bar.update(1)
    lines = stream.getvalue().splitlines()
    assert "\r" not in stream.getvalue() and len(lines) == 2
    assert lines[0].startswith("extract train:   0%") and "0/300" in lines[0]  # what is about to happen, how much
    assert lines[1].startswith("extract train: 100%") and "300/300" in lines[1]


def test_a_worker_reports_to_its_parents_bar():
    reports, stream = queue.Queue(), io.StringIO()
    remote = progress.RemoteBar(reports, "CNEP")
    for step in range(1, 11):
        remote.update(step, final=step == 10, val="0.5")  # within REPORT_INTERVAL_S: the first and the last only
    assert reports.qsize() == 2
    with progress.progress_bar(total=10, desc="train CNEP", unit="step", stream=stream) as bar:
        progress.follow_reports(reports, {"CNEP": bar})
        assert bar.n == 10 and bar.postfix == "val=0.5"


def test_a_job_in_this_process_moves_its_bar_as_it_reports():
    stream = io.StringIO()
    with progress.progress_bar(total=10, desc="train CNEP", unit="step", stream=stream) as bar:
        remote = progress.RemoteBar(progress.BarQueue(bar), "CNEP")
        remote.update(4, val="0.7")
        assert bar.n == 4 and bar.postfix == "val=0.7"  # at once: nothing has to follow the reports
        remote.update(5, val="0.6")  # within REPORT_INTERVAL_S of the last: not reported
        assert bar.n == 4
        remote.update(10, final=True, val="0.5")
        assert bar.n == 10 and bar.postfix == "val=0.5"


def test_a_log_file_gets_a_line_per_interval(monkeypatch):
    monkeypatch.setattr(progress, "LINE_INTERVAL_S", 0.0)
    stream = io.StringIO()
    for _ in progress.progress_bar(range(3), desc="ingest", unit="demo", stream=stream):
        pass
    lines = stream.getvalue().splitlines()
    assert "\r" not in stream.getvalue() and len(lines) >= 2 and lines[-1].startswith("ingest: 100%")
    assert len(set(lines)) == len(lines)  # an unchanged bar is not repeated


def test_a_terminal_gets_a_bar_redrawn_in_place():
    stream = Terminal()
    for _ in progress.progress_bar(range(3), desc="ingest", unit="demo", stream=stream, mininterval=0):
        pass
    assert "\r" in stream.getvalue()


def test_quiet_prints_nothing():
    stream = Terminal()
    assert list(progress.progress_bar(range(3), desc="ingest", unit="demo", quiet=True, stream=stream)) == [0, 1, 2]
    assert stream.getvalue() == ""


def test_a_long_step_without_a_bar_says_what_it_does_and_for_how_long(monkeypatch):
    monkeypatch.setattr(progress, "LINE_INTERVAL_S", 0.05)
    stream = io.StringIO()
    with progress.heartbeat("loading torch", stream=stream):
        deadline = time.monotonic() + 10  # a busy machine may print late, never not at all
        while len(stream.getvalue().splitlines()) < 3 and time.monotonic() < deadline:
            time.sleep(0.05)
    lines = stream.getvalue().splitlines()
    assert len(lines) >= 3 and all(re.fullmatch(r"loading torch \.\.\. \d+ s", line) for line in lines), lines
    with progress.heartbeat("loading torch", stream=stream):
        pass  # done within the first interval: nothing more
    assert stream.getvalue().splitlines() == lines
    quiet = io.StringIO()
    with progress.heartbeat("loading torch", quiet=True, stream=quiet):
        time.sleep(0.2)
    assert quiet.getvalue() == ""


def test_a_bar_that_nothing_updates_still_shows_its_clock(monkeypatch):
    monkeypatch.setattr(progress, "LINE_INTERVAL_S", 0.2)
    stream = io.StringIO()
    with progress.progress_bar(total=2, desc="calibrating", unit="frame", stream=stream) as bar:
        deadline = time.monotonic() + 10  # one long batch; a busy machine may redraw late, never not at all
        while "0/2 [00:02<" not in stream.getvalue() and time.monotonic() < deadline:
            time.sleep(0.05)
        bar.update(2)
    lines = stream.getvalue().splitlines()
    assert [line for line in lines if "0/2 [00:00<" in line] and [line for line in lines if "0/2 [00:02<" in line]
    assert lines[-1].startswith("calibrating: 100%")
    written = stream.getvalue()
    time.sleep(0.5)
    assert stream.getvalue() == written  # a closed bar is left alone


def test_log_messages_stay_whole_lines_beside_the_bar():
    stream = io.StringIO()
    logger = logging.getLogger("test_progress")
    handler = logging.StreamHandler(stream)
    logger.addHandler(handler)
    try:
        with (
            logging_redirect_tqdm(loggers=[logger]),
            progress.progress_bar(total=2, desc="x", unit="f", stream=stream) as bar,
        ):
            for k in range(2):
                logger.warning("file %d done", k)
                bar.update(1)
    finally:
        logger.removeHandler(handler)
    lines = stream.getvalue().splitlines()
    assert lines[0].startswith("x:   0%") and lines[1:3] == ["file 0 done", "file 1 done"]
    assert "\r" not in stream.getvalue()


@pytest.mark.parametrize("quiet", [True, False])
def test_cnep_extract_in_a_log(tmp_path, capfd, quiet):
    demo = write_demonstration(tmp_path / "d.mcap", demonstration_factory(5))
    args = [
        "extract",
        str(demo),
        "--out",
        str(tmp_path / "out"),
        "--weights",
        "random",
        "--backend",
        "eager",
        "--threads",
        "1",
    ]
    assert main(["-q", *args] if quiet else args) == 0
    err = capfd.readouterr().err
    assert "\r" not in err
    assert ("extract out: 100%" in err and "5/5" in err) != quiet
