"""Soak: every stage killed at random moments (kill -9 or SIGTERM), round after round; each time the output holds
only complete files equal to an uninterrupted run's, and running the command again finishes with that result and
leaves no stray file. The test suite's tests/pipeline/test_faults.py kills at chosen calls; this kills anywhere.

Run on demand (minutes; say the machine's load when you quote it):
    python -m benchmarks.soak_faults [--rounds 10] [--seed 0] [--stages ingest extract train replay repair demo]

Per stage and round: start `cnep` in a fresh output, kill it after a random delay drawn (seeded) from zero to
the uninterrupted run's duration, with SIGKILL or SIGTERM (a coin flip); check what it left; run it again
(`--resume` for train when it left a state, `--force` where a complete output exists) and check the result.
Prints one row per stage (the killed runs' exit statuses: -9, 143 for SIGTERM, -15 or 0 when the signal came
before cnep started or after it ended) and every problem found; exits 1 if there was one.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from tests.pipeline.fault_driver import files, stray

TRAINING = ["--layout", "motion", "--steps", "200", "--val-every", "20", "--save-every", "20", "--warmup-steps", "20"]
TRAINING += ["--encoder-widths", "32", "--expert-widths", "32", "--batch-size", "8", "--seed", "1"]


def cnep(*argv, check: bool = True) -> subprocess.CompletedProcess:
    env = {**os.environ, "OMP_NUM_THREADS": "1", "CI": "1"}
    done = subprocess.run(
        [sys.executable, "-m", "cnep.pipeline", "-q", *map(str, argv)], env=env, capture_output=True, text=True
    )
    if check and done.returncode != 0:
        raise RuntimeError(f"cnep {' '.join(map(str, argv))}: {done.stderr.strip()}")
    return done


def make_inputs(root: Path) -> dict[str, Path]:
    """Sources (motion CSVs), a demonstration with frames cut short, and the uninterrupted runs' outputs."""
    from cnep.recordings import write_demonstration
    from tests.recordings.factories import demonstration_factory

    src = root / "src"
    src.mkdir()
    t = np.arange(200) * 0.02
    for k in range(8):
        rows = [[ti, 0.3 + 0.05 * k + 0.2 * ti, 0.1 * np.sin(ti + k), 0.2, 0, 0, 0, 1, 0.01 * k] for ti in t]
        text = "\n".join(["t,x,y,z,qx,qy,qz,qw,gripper", *(",".join(map(repr, map(float, r))) for r in rows)])
        (src / f"demo_{k}.csv").write_text(text + "\n")
    big = write_demonstration(root / "big.mcap", demonstration_factory(300, frames=True, frame_size=128))
    cut = root / "cut.mcap"
    cut.write_bytes(big.read_bytes()[: int(big.stat().st_size * 0.8)])
    return {"src": src, "cut": cut}


class Stage:
    """How to run one stage into an output, and what its complete result is."""

    def __init__(
        self, name: str, argv: Callable[[Path], list], out: Callable[[Path], Path], again: Callable[[Path], list]
    ):
        self.name, self.argv, self.out, self.again = name, argv, out, again
        self.reference: dict[str, bytes] = {}
        self.seconds = 0.0


def comparable(stage: str, found: dict[str, bytes]) -> dict:
    """What must equal the uninterrupted run: replay's .rrd files carry a run id, so their names and the decisions
    are compared; a checkpoint's config records the run's time and paths, so its weights are compared."""
    if stage == "replay":
        return {k: (json.loads(v)["recordings"] if k.endswith(".json") else None) for k, v in found.items()}
    if stage == "train":
        return {k: v for k, v in found.items() if k.endswith(".safetensors")}
    if stage == "demo":
        return {k: None for k in found if not k.endswith((".rrd", "summary.json", ".jsonl", "config.json"))}
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=10)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--stages", nargs="+", default=["ingest", "extract", "train", "replay", "repair"])
    args = parser.parse_args()
    rng = random.Random(args.seed)
    problems: list[str] = []
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        inputs = make_inputs(root)
        demos, trajs, ckpt = root / "ref" / "demos", root / "ref" / "trajs", root / "ref" / "ckpt"
        stages = {
            "ingest": Stage(
                "ingest", lambda o: ["ingest", inputs["src"], "--out", o / "out"], lambda o: o / "out", lambda o: []
            ),
            "extract": Stage(
                "extract", lambda o: ["extract", demos, "--out", o / "out"], lambda o: o / "out", lambda o: []
            ),
            "train": Stage(
                "train",
                lambda o: ["train", trajs, "--out", o / "out", *TRAINING],
                lambda o: o / "out",
                lambda o: (
                    ["--resume"]
                    if (o / ".out.partial" / "state.pt").exists()
                    else ["--force"]
                    if (o / "out").exists()
                    else []
                ),
            ),
            "replay": Stage(
                "replay",
                lambda o: ["replay", ckpt, *sorted(trajs.glob("*.mcap")), "--out", o / "out" / "r.rrd", "--no-live"],
                lambda o: o / "out",
                lambda o: ["--force"] if files(o / "out") else [],
            ),
            "repair": Stage(
                "repair",
                lambda o: ["repair", inputs["cut"], o / "out" / "fixed.mcap"],
                lambda o: o / "out",
                lambda o: ["--force"] if files(o / "out") else [],
            ),
            "demo": Stage(
                "demo",
                lambda o: ["demo", "--quick", "--out", o / "out"],
                lambda o: o / "out",
                lambda o: ["--force"] if files(o / "out") else [],
            ),
        }
        for name in ("ingest", "extract", "train", "replay", "repair", "demo"):  # references, in pipeline order
            if name not in args.stages and name not in ("ingest", "extract", "train"):
                continue
            stage, folder = stages[name], root / "ref" / name
            folder.mkdir(parents=True)
            start = time.perf_counter()
            cnep(*stage.argv(folder))
            stage.seconds = time.perf_counter() - start
            stage.reference = comparable(name, files(stage.out(folder)))
            if name in ("ingest", "extract", "train"):
                shutil.copytree(stage.out(folder), {"ingest": demos, "extract": trajs, "train": ckpt}[name])
        rows = []
        for name in args.stages:
            stage, statuses = stages[name], []
            for r in range(args.rounds):
                folder = root / "soak" / name / str(r)
                folder.mkdir(parents=True)
                signum = rng.choice([signal.SIGKILL, signal.SIGTERM])
                delay = rng.uniform(0, stage.seconds)
                env = {**os.environ, "OMP_NUM_THREADS": "1", "CI": "1"}
                proc = subprocess.Popen(
                    [sys.executable, "-m", "cnep.pipeline", "-q", *map(str, stage.argv(folder))],
                    env=env,
                    stdout=subprocess.DEVNULL,
                    stderr=subprocess.PIPE,
                    text=True,
                )
                time.sleep(delay)
                proc.send_signal(signum)
                _, err = proc.communicate()
                statuses.append(proc.returncode)  # -9, 143, or -15 / 0: the signal came before cnep started / after it
                where = f"{name} round {r} ({signal.Signals(signum).name} after {delay:.2f} s, exit {proc.returncode})"
                left = comparable(name, files(stage.out(folder)))
                if name in ("ingest", "extract") and not left.items() <= stage.reference.items():
                    problems.append(f"{where}: a file differs from the uninterrupted run's")
                if name in ("replay", "train", "repair") and left and left != stage.reference:
                    problems.append(f"{where}: left an output that is not the complete one")
                if proc.returncode == 143 and (len(err.strip().splitlines()) != 1 or stray(folder)):
                    problems.append(f"{where}: SIGTERM left {stray(folder)} / said {err.strip().splitlines()}")
                again = cnep(*stage.argv(folder), *stage.again(folder), check=False)
                if again.returncode != 0:
                    problems.append(f"{where}: the re-run failed: {again.stderr.strip()}")
                elif comparable(name, files(stage.out(folder))) != stage.reference:
                    problems.append(f"{where}: the re-run's result differs from the uninterrupted run's")
                elif stray(folder) or [p for p in folder.iterdir() if p.name.startswith(".")]:
                    problems.append(f"{where}: stray files after the re-run: {stray(folder)}")
            rows.append((name, statuses, stage.seconds))
    print(
        f"soak of {', '.join(args.stages)}: {args.rounds} round(s) each, seed {args.seed}, load average "
        f"{os.getloadavg()[0]:.2f}"
    )
    print("| stage | runs | exit statuses of the killed runs | uninterrupted run (s) |")
    print("|---|---|---|---|")
    for name, statuses, seconds in rows:
        print(f"| {name} | {len(statuses)} | {' '.join(map(str, statuses))} | {seconds:.1f} |")
    print(f"{len(problems)} problem(s)")
    for problem in problems:
        print(" -", problem)
    sys.exit(1 if problems else 0)


if __name__ == "__main__":
    main()
