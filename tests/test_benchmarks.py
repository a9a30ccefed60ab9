"""`python -m benchmarks` (what `make bench` runs) lists every benchmark and runs one by name."""

import subprocess
import sys
from pathlib import Path

from benchmarks.__main__ import benchmarks, main

ROOT = Path(__file__).resolve().parents[1]


def test_the_list_names_every_benchmark_with_its_first_docstring_line(capsys):
    assert main([]) == 0
    listed = capsys.readouterr().out
    files = sorted(p.stem.removeprefix("bench_") for p in (ROOT / "benchmarks").glob("bench_*.py"))
    assert sorted(benchmarks()) == files and all(benchmarks().values())
    for name, line in benchmarks().items():
        assert f"{name}" in listed and line in listed


def test_a_benchmark_runs_by_name_and_an_unknown_name_is_refused(capsys):
    done = subprocess.run(
        [sys.executable, "-m", "benchmarks", "recordings", "--help"], capture_output=True, text=True, cwd=ROOT
    )
    assert done.returncode == 0, done.stderr
    assert "== recordings: -m benchmarks.bench_recordings --help" in done.stdout and "usage:" in done.stdout
    assert main(["nothing"]) == 2
    assert "no benchmark 'nothing'" in capsys.readouterr().err
