"""Hostile input, the long run: thousands of mutated MCAP, JSON and safetensors files through cnep's readers.

Run on demand:
    python -m benchmarks.bench_fuzz [--cases 5000] [--seed 1] [--family mcap json safetensors]

The same seeded generator and harness as tests/test_fuzz.py (tests/fuzz.py), with many more cases: each
family runs in a child process under a memory cap, each case under a time limit. Prints every finding (a
reader that raised anything but the project's error for it, or hung) as a JSON line, then per family the
cases, the findings and the cases per second; exits 1 if there was any finding.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

from tests.fuzz import FAMILIES

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=5000, help="mutated files per family")
    parser.add_argument("--seed", type=int, default=1, help="the generator's seed (the suite runs seed 0)")
    parser.add_argument("--family", nargs="+", choices=FAMILIES, default=list(FAMILIES))
    args = parser.parse_args(argv)
    found = 0
    for family in args.family:
        start = time.perf_counter()
        command = [sys.executable, "-m", "tests.fuzz", "--family", family, "--cases", str(args.cases)]
        done = subprocess.run([*command, "--seed", str(args.seed)], capture_output=True, text=True, cwd=ROOT)
        seconds = time.perf_counter() - start
        lines = done.stdout.splitlines()
        summary = json.loads(lines[-1]) if lines and lines[-1].startswith("{") else None
        if summary is None:
            print(f"{family}: the fuzzing process failed (exit {done.returncode}):\n{done.stderr[-2000:]}")
            found += 1
            continue
        for finding in lines[:-1]:
            print(finding)
        found += summary["findings"]
        print(f"{family}: {summary['cases']} cases, {summary['findings']} findings, {summary['cases'] / seconds:.0f}/s")
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
