"""The closed-loop results as one CSV: a row per demonstration set, model, training seed and protocol.

    python examples/closed_loop_csv.py RUN [RUN ...] --csv OUT

Each RUN is a folder written by `cnep sim obstacle` (its summary.json holds every model and training seed) or by
`cnep sim eval` (one policy: its model and seed are read from the policy folder's name, `cnep-seed0`, as
`cnep sim obstacle` names them; the demonstrations' seed and training steps from the summary of the `cnep sim
obstacle` run found in a folder above RUN, if any). A row: the run's folder, the demonstrations' seed (`set`), the
environments' version (0 for a summary that names none), the cue variant, the first expert's rule (`own`: the
policy's, as trained), the training steps, model, training seed, protocol, episodes, the rates (success, collision,
left, switching, followed_cue; the switching while nothing had changed and, with a cue shown during the motion, the
switch to the cue's side within 5 steps of it: empty in a summary without them), the Wilson 95% intervals of
success, switching and the switching while nothing had changed (`_lo`, `_hi`), the behaviour entropy of the side
passed (empty where it is not defined: with a cue) and the smallest gripper-box distance (cm); `usage`: the experts'
shares of the training samples at the last step (the last line of training_log.jsonl in the checkpoint
`checkpoints/NAME` beside the policy's folder `policies/NAME`, as `cnep sim obstacle` lays them out), `/`-separated.
"""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path

COLUMNS = (
    "run", "set", "env_version", "cue", "first_expert", "train_steps", "model", "train_seed", "protocol", "episodes",
    "success", "success_lo", "success_hi", "collision", "left", "switching", "switching_lo", "switching_hi",
    "switched_unchanged", "switched_unchanged_lo", "switched_unchanged_hi", "switched_within_5", "followed_cue",
    "entropy", "min_gap_cm", "usage",
)  # fmt: skip


def first_expert(settings: dict) -> str:
    """The first expert's rule the run gave its policies ("own": each policy's own, as trained); a summary written
    before the conditioning settings were grouped holds it at the top."""
    given = settings["first_expert"] if "first_expert" in settings else settings["conditioning"]["first_expert"]
    return given or "own"


def usage(checkpoint: Path) -> str:
    """The experts' shares at the last logged step of `checkpoint` ("" without a training log)."""
    log = checkpoint / "training_log.jsonl"
    if not log.is_file():
        return ""
    last = json.loads(log.read_text().splitlines()[-1])
    return "/".join(f"{share:.2f}" for share in last["usage"])


def bounds(rates: dict, key: str) -> dict:
    """The Wilson interval of the rate under `key` as `KEY_lo` and `KEY_hi` (empty where the rates hold none)."""
    lo, hi = rates.get(f"{key}_ci") or ("", "")
    return {f"{key}_lo": lo, f"{key}_hi": hi}


def _blank(value: object) -> object:
    """`value`, or empty where it is None (not defined, or not in the summary)."""
    return "" if value is None else value


def obstacle_run(run: Path) -> dict:
    """The summary of the `cnep sim obstacle` run in a folder above `run` ({} when there is none)."""
    for folder in run.resolve().parents:
        found = folder / "summary.json"
        if found.is_file() and "models" in (summary := json.loads(found.read_text())):
            return summary
    return {}


def rows_of(run: Path) -> list[dict]:
    """The CSV rows of one run folder (module docstring)."""
    summary = json.loads((run / "summary.json").read_text())
    settings = summary["settings"]
    if "models" in summary:  # cnep sim obstacle
        results = [(m, s, p, run / "checkpoints" / f"{m.lower()}-seed{s}") for m, seeds in summary["models"].items()
                   for s, p in seeds.items()]  # fmt: skip
        made = settings
    else:  # cnep sim eval: one policy, named MODEL-seedN
        policy = Path(settings["policy"])
        model, _, seed = policy.name.partition("-seed")
        results = [(model.upper(), seed, summary["results"], policy.parent.parent / "checkpoints" / policy.name)]
        made = obstacle_run(run).get("settings", {})
    rows = []
    for model, seed, protocols, checkpoint in results:
        for protocol, r in protocols.items():
            rows.append(
                {
                    "run": run.name, "set": made.get("seed", ""), "env_version": settings.get("env_version", 0),
                    "cue": settings["cue"],
                    "first_expert": first_expert(settings), "train_steps": made.get("train_steps", ""),
                    "model": model, "train_seed": seed, "protocol": protocol, "episodes": r["episodes"],
                    "success": r["success"], **bounds(r, "success"), "collision": r["collision"], "left": r["left"],
                    "switching": r["switching"], **bounds(r, "switching"),
                    "switched_unchanged": _blank(r.get("switched_unchanged")), **bounds(r, "switched_unchanged"),
                    "switched_within_5": _blank(r.get("switched_within")),
                    "followed_cue": _blank(r["followed_cue"]), "entropy": _blank(r.get("entropy")),
                    "min_gap_cm": round(r["min_clearance_m"] * 100, 1), "usage": usage(checkpoint),
                }
            )  # fmt: skip
    return rows


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path, help="folders holding a summary.json")
    parser.add_argument("--csv", type=Path, required=True, help="the CSV file to write")
    args = parser.parse_args(argv)
    rows = [row for run in args.runs for row in rows_of(run)]
    with args.csv.open("w", newline="") as f:
        writer = csv.DictWriter(f, COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    print(f"{len(rows)} rows -> {args.csv}")
    return rows


if __name__ == "__main__":
    main()
