"""Ownership on random histories, the long run: many more seeded histories of tests/pipeline/ownership_machine.py.

Run on demand:
    python -m benchmarks.bench_ownership [--examples 200] [--steps 12] [--demo]

A user's files beside and inside cnep's outputs, commands with and without --force, some stopped by a signal at a
chosen point of their writing and run again; after every step every byte of the user's is there and every output is
complete or absent. Runs tests/pipeline/test_ownership_state.py with that many histories (CNEP_OWNERSHIP_EXAMPLES,
CNEP_OWNERSHIP_STEPS; with --demo the quick demo runs whole where a history asks for it, CNEP_OWNERSHIP_DEMO=1),
prints how each command ended and the histories per minute, and exits with pytest's status (1: a history that
breaks the property, printed shrunk).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TEST = "tests/pipeline/test_ownership_state.py"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--examples", type=int, default=200, help="histories (the suite runs 8)")
    parser.add_argument("--steps", type=int, default=12, help="steps per history at most (the suite's: 8)")
    parser.add_argument("--demo", action="store_true", help="let the quick demo run whole (about 20 s each time)")
    args = parser.parse_args(argv)
    env = {**os.environ, "CI": "1", "CNEP_OWNERSHIP_EXAMPLES": str(args.examples)}
    env |= {"CNEP_OWNERSHIP_STEPS": str(args.steps), "CNEP_OWNERSHIP_DEMO": "1" if args.demo else "0"}
    start = time.perf_counter()
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-s", "-p", "no:cacheprovider", TEST], env=env, cwd=ROOT
    )
    minutes = (time.perf_counter() - start) / 60
    if done.returncode == 0:
        rate = args.examples / minutes
        print(f"{args.examples} histories of up to {args.steps} steps in {minutes:.1f} min ({rate:.1f} per minute)")
    return done.returncode


if __name__ == "__main__":
    sys.exit(main())
