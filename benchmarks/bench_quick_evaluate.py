"""Whether `cnep evaluate --quick` tells the modes apart: its CNEP's and CNMP's mode accuracy per set and protocol.

Run on demand (the quick run's networks trained in this process, on one torch thread):
    python -m benchmarks.bench_quick_evaluate [--sets bimodal] [--steps 1500] [--out DIR]

Runs `cnep evaluate --quick --sets SETS --jobs 0 --no-figures` (its seeds, training steps and queries unless
`--steps` is given) into `--out` (default: a temporary folder), prints per protocol, row and set the MSE and the
mode accuracy (the share of queries answered in the demonstrated mode) of the CNEP, the CNMP and the nearest
demonstration, and exits 1 unless the CNEP and the CNMP answer every query in its mode (mode accuracy 1.0) on every
set and protocol. The quick run's claim is the bimodal set's: 1500 steps already tell its two modes apart.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

from cnep.pipeline.evaluate.constants import QUICK_SETS
from cnep.pipeline.evaluate.stage import EvaluateConfig, evaluate

PROTOCOLS = ("paper", "heldout")  # the comparison's protocols that score a mode
ROWS = ("CNEP", "CNMP", "Nearest demo")
SEPARATING = ("CNEP", "CNMP")  # the networks the claim is about


def quick_results(sets: tuple[str, ...], steps: int | None, out: Path) -> dict:
    """`cnep evaluate --quick` on `sets` (`steps` training steps, None: the quick run's) in this process, no figures:
    its comparison.json."""
    evaluate(EvaluateConfig(quick=True, sets=sets, steps=steps, out=out, jobs=0, figures=False, quiet=True))
    return json.loads((out / "comparison.json").read_text())


def rows(data: dict) -> list[tuple[str, str, str, float, float]]:
    """(protocol, row, set, MSE, mode accuracy) of every protocol, row of ROWS and set of `data` (comparison.json)."""
    return [
        (protocol, row, name, scores["mse"], scores["mode_accuracy"])
        for protocol in PROTOCOLS
        for row in ROWS
        for name, scores in data["results"][protocol][row].items()
    ]


def separated(data: dict) -> bool:
    """Whether the CNEP and the CNMP answer every query in its mode on every set and protocol of `data`."""
    return all(accuracy == 1.0 for _, row, _, _, accuracy in rows(data) if row in SEPARATING)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sets", nargs="+", choices=QUICK_SETS, default=["bimodal"])
    parser.add_argument("--steps", type=int, default=None, help="training steps (default: the quick run's)")
    parser.add_argument("--out", type=Path, default=None, help="folder for the run's tables (default: a temporary one)")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as temporary:
        start = time.perf_counter()
        data = quick_results(tuple(args.sets), args.steps, args.out or Path(temporary))
        seconds = time.perf_counter() - start
    settings = data["settings"]
    print(
        f"cnep evaluate --quick: {settings['seeds']} seed(s), steps {settings['steps']}, {settings['queries']} queries"
    )
    print("| protocol | row | set | MSE | mode accuracy |\n|---|---|---|---|---|")
    for protocol, row, name, mse, accuracy in rows(data):
        print(f"| {protocol} | {row} | {name} | {mse:.4f} | {accuracy:.2f} |")
    verdict = separated(data)
    print(f"\nthe CNEP and the CNMP {'tell' if verdict else 'do not tell'} every mode apart ({seconds:.0f} s)")
    return 0 if verdict else 1


if __name__ == "__main__":
    sys.exit(main())
