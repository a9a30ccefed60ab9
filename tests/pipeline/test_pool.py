"""pipeline.evaluate.pool: calls run here or on a cluster give their results under their labels, and one bar counts the
episodes their parts report (the closed loop's, the selection's and `cnep sim grid`'s units)."""

import io
from functools import partial

import pytest

import cnep.pipeline.evaluate.pool as pool
from cnep.pipeline.progress import progress_bar


def two_parts(episodes: int, bar) -> int:
    """A call whose episodes go to two parts of its bar, `episodes` and one; returns ten times `episodes`."""
    bar.part("first").update(episodes, final=True)
    bar.part("second").update(1, final=True)
    return 10 * episodes


@pytest.fixture
def bar_lines(monkeypatch) -> io.StringIO:
    """The pool's bar, written to the returned stream as whole lines."""
    stream = io.StringIO()
    monkeypatch.setattr(pool, "progress_bar", partial(progress_bar, stream=stream))
    return stream


def test_calls_in_this_process_give_their_results_in_order_and_the_bar_their_episodes(bar_lines):
    calls = {"b": partial(two_parts, 3), "a": partial(two_parts, 2)}
    assert list(pool.run_counted(calls, 7, "grid", workers=0, quiet=False, unit="episode").items()) == [
        ("b", 30),
        ("a", 20),
    ]
    last = bar_lines.getvalue().splitlines()[-1]
    assert "7/7" in last and "2/2 done, last a" in last and "episode" in last


def test_calls_on_a_cluster_report_their_episodes_with_their_results(bar_lines):
    distributed = pytest.importorskip("distributed")
    calls = {"b": partial(two_parts, 3), "a": partial(two_parts, 2)}
    with distributed.LocalCluster(
        n_workers=1, processes=False, protocol="tcp", host="127.0.0.1", dashboard_address=None
    ) as cluster:
        done = dict(pool.as_finished(calls, 7, "grid", 1, False, "dask", cluster.scheduler_address, unit="episode"))
    assert done == {"b": 30, "a": 20}
    assert "7/7" in bar_lines.getvalue().splitlines()[-1]


def test_calls_in_this_process_move_the_bar_as_they_report(monkeypatch):
    bars = []

    def kept_bar(**options):
        bars.append(progress_bar(**options, stream=io.StringIO()))
        return bars[-1]

    def seen_by_the_bar(n: int, seen: list[float], bar) -> None:
        bar.update(n, final=True)
        seen.append(bars[0].n)  # while the call still runs

    monkeypatch.setattr(pool, "progress_bar", kept_bar)
    seen = []
    calls = {"a": partial(seen_by_the_bar, 2, seen), "b": partial(seen_by_the_bar, 3, seen)}
    pool.run_counted(calls, 5, "evaluate", workers=0, quiet=False, unit="step")
    assert seen == [2, 5]
