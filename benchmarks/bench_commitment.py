"""Commitment with the defaults a user gets: crossing-only queries on 2, 4 and 6 modes, two generators, several seeds.

Run on demand (one default model per cell, trained to the end of its schedule on one torch thread; minutes each):
    python -m benchmarks.bench_commitment [--modes 2 4 6] [--seeds 0 1 2 3 4] [--generators project paper]
        [--csv docs/results/commitment-defaults.csv] [--set NAME=VALUE ...]

Each cell trains `models.fit(demonstrations, CNEPConfig(n_experts=d), TrainConfig(seed=s))`, every other setting its
default (`fit` holds a fifth of the demonstrations out for validation; `--set` changes a TrainConfig field, for an
ablation), with d the commitment table's experts for that many modes (`pipeline.evaluate.constants.CNEP_EXPERTS`),
and scores the share of the commitment queries (one point that two or more modes share, nothing else:
`models.evaluation.shared_queries`) answered with a valid demonstrated mode (`models.evaluation.commitment`, on the
demonstrations it trained on). Generators: `project`, the training demonstrations of the bimodal, 4- and 6-mode sets
of `models.synthetic.make_set`; `paper`, `benchmarks.paper_sines` (written from the paper's description alone; 32
demonstrations per mode). Prints one line per cell, then the table: the valid share per seed and the lowest; each cell
is also a row of the CSV, rewritten whole after each cell (cells already there with the same settings are kept and
not trained again).
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import io
import json
import time
from pathlib import Path

import numpy as np

from benchmarks.paper_sines import paper_sines
from cnep.models import CNEPConfig, TrainConfig, fit
from cnep.models.evaluation import commitment, shared_queries
from cnep.models.synthetic import make_set
from cnep.models.train import VAL_FRACTION, split_validation
from cnep.outputs import write_atomically
from cnep.pipeline.evaluate.constants import CNEP_EXPERTS

SETS = {2: "bimodal", 4: "multimodal", 6: "multimodal6"}  # models.synthetic's set of each mode count
GENERATORS = ("project", "paper")
COLUMNS = ("generator", "modes", "experts", "seed", "settings", "valid", "queries", "steps", "seconds")


def demonstrations(generator: str, modes: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Every demonstration (N, T, 1) of `generator` for `modes` modes, and their mode labels (N,)."""
    if generator == "project":
        s = make_set(SETS[modes], seed)
        return s.train, s.train_modes
    return paper_sines(modes, seed)


def cell(generator: str, modes: int, seed: int, settings: dict) -> dict:
    """Train one default model and score its commitment on the demonstrations it trained on -> one CSV row."""
    demos, labels = demonstrations(generator, modes, seed)
    d = CNEP_EXPERTS[SETS[modes]]
    start = time.perf_counter()
    model, history = fit(list(demos), CNEPConfig(n_experts=d), TrainConfig(seed=seed, **settings), progress=False)
    seconds = time.perf_counter() - start
    trained, _ = split_validation(np.arange(len(demos)), VAL_FRACTION, seed)  # the ones `fit` did not hold out
    train, labels = demos[trained], labels[trained]
    queries = shared_queries(train, labels)
    scores = commitment(lambda t, y, q: model.generate(t, y, q).mean, queries, train, labels)
    return {
        "generator": generator,
        "modes": modes,
        "experts": d,
        "seed": seed,
        "settings": json.dumps(settings, sort_keys=True),
        "valid": f"{scores['valid']:.3f}",
        "queries": scores["queries"],
        "steps": history[-1]["step"],
        "seconds": f"{seconds:.0f}",
    }


def parse_settings(pairs: list[str]) -> dict:
    """`NAME=VALUE` pairs -> TrainConfig fields with their values (JSON, else the string)."""
    known = {f.name for f in dataclasses.fields(TrainConfig)}
    settings = {}
    for pair in pairs:
        name, _, value = pair.partition("=")
        if name not in known or not value:
            raise SystemExit(f"--set {pair!r}: expected NAME=VALUE with NAME a TrainConfig field ({sorted(known)})")
        try:
            settings[name] = json.loads(value)
        except json.JSONDecodeError:
            settings[name] = value
    return settings


def write_rows(path: Path, rows: list[dict]) -> None:
    text = io.StringIO()
    writer = csv.DictWriter(text, COLUMNS, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    write_atomically(path, text.getvalue().encode())


def table(rows: list[dict], settings: str) -> str:
    """Markdown: generator x modes, the valid share per seed and the lowest, for rows of `settings`."""
    lines = ["| generator | modes (experts) | valid share per seed | lowest |", "|---|---|---|---|"]
    cells: dict[tuple, list[dict]] = {}
    for row in rows:
        if row["settings"] == settings:
            cells.setdefault((row["generator"], int(row["modes"]), int(row["experts"])), []).append(row)
    for (generator, modes, d), found in sorted(cells.items()):
        shares = [float(r["valid"]) for r in sorted(found, key=lambda r: int(r["seed"]))]
        seeds = " / ".join(f"{s:.2f}" for s in shares)
        lines.append(f"| {generator} | {modes} ({d}) | {seeds} | {min(shares):.2f} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--modes", type=int, nargs="+", choices=sorted(SETS), default=sorted(SETS))
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    parser.add_argument("--generators", nargs="+", choices=GENERATORS, default=list(GENERATORS))
    parser.add_argument("--csv", type=Path, default=Path("docs/results/commitment-defaults.csv"))
    parser.add_argument("--set", nargs="*", default=[], metavar="NAME=VALUE", help="a TrainConfig field changed")
    args = parser.parse_args()
    settings = parse_settings(args.set)
    key = json.dumps(settings, sort_keys=True)
    rows = list(csv.DictReader(args.csv.open())) if args.csv.exists() else []
    done = {(r["generator"], int(r["modes"]), int(r["seed"]), r["settings"]) for r in rows}
    for generator in args.generators:
        for modes in args.modes:
            for seed in args.seeds:
                if (generator, modes, seed, key) in done:
                    continue
                row = cell(generator, modes, seed, settings)
                print(json.dumps(row), flush=True)
                rows.append(row)
                write_rows(args.csv, rows)
    print(table(rows, key))


if __name__ == "__main__":
    main()
