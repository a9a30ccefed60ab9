"""Hostile files cost bounded time and memory and are refused only with the project's errors: a few hundred mutated
MCAP, JSON and safetensors files (tests/fuzz.py), each family read in a child process of its own under a memory cap,
each case under a time limit. `python -m benchmarks fuzz` runs many more."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from tests.fuzz import FAMILIES

ROOT = Path(__file__).resolve().parents[1]
CASES = {"mcap": 200, "json": 300, "safetensors": 100}  # the safetensors child spends most of its time importing torch


@pytest.mark.slow
def test_mutated_files_are_refused_with_the_projects_errors_only():
    children = {  # the families run side by side: the suite waits for the slowest alone
        family: subprocess.Popen(
            [sys.executable, "-m", "tests.fuzz", "--family", family, "--cases", str(CASES[family]), "--seed", "0"],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            cwd=ROOT,
        )
        for family in FAMILIES
    }
    for family, child in children.items():
        out, err = child.communicate(timeout=300)
        lines = [json.loads(line) for line in out.splitlines() if line.startswith("{")]
        summary = {"family": family, "cases": CASES[family], "seed": 0, "findings": 0}
        assert lines and lines[-1] == summary and child.returncode == 0, out[-4000:] + err[-4000:]
