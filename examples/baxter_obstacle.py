"""The authors' Baxter obstacle-avoidance recordings through CNEP and CNMP (pipeline.evaluate.baxter).

    python examples/baxter_obstacle.py PATH/TO/data/baxter/first [--goal] [--steps N] [--seed N] [--nll-beta B]

PATH holds `start_end/*.csv` (the two demonstrations) and the test recordings `0.csv` ... `6.csv`;
it is only read. Trains a CNMP and a 2-expert CNEP per loss assignment (paper, mixture, annealed, bounded), and prints,
per test start point and model (CNMP, CNEP and CNEP-MoE of each assignment), the generated path's
distance to the nearest demonstration and whether the generated path / the path executed by the
paper's PID controller from the real start enters the box x in [0.71, 0.95] m, y in [-0.36, -0.24] m.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    from cnep.models.config import TrainConfig  # no torch

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", help="the folder with start_end/*.csv and the test CSVs (read only)")
    parser.add_argument(
        "--goal", action="store_true", help="also condition on each test recording's last sample at t = 1"
    )
    parser.add_argument(
        "--steps", type=int, default=None, help="training steps per model (default: the training schedule's, 4000 here)"
    )
    parser.add_argument("--seed", type=int, default=0, help="training seed (default 0)")
    default = TrainConfig().nll_beta
    parser.add_argument(
        "--nll-beta", type=float, default=default, help=f"the loss's beta-NLL power (default {default:g})"
    )
    parser.add_argument("--work", default=None, help="keep the ingested files in this folder (default: temporary)")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bars")
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.WARNING if args.quiet else logging.INFO, format="%(levelname)s %(name)s: %(message)s"
    )

    import torch

    from cnep.pipeline.errors import USER_ERRORS
    from cnep.pipeline.evaluate.baxter import BaxterConfig, format_table, run_baxter

    torch.set_num_threads(1)  # small networks: one thread is fastest and leaves the other core free
    config = BaxterConfig(
        data=Path(args.data),
        work=Path(args.work) if args.work else None,
        steps=args.steps,
        seed=args.seed,
        nll_beta=args.nll_beta,
        goal=args.goal,
        quiet=args.quiet,
    )
    try:
        results = run_baxter(config)
    except USER_ERRORS as exc:
        print(f"baxter_obstacle: error: {exc}", file=sys.stderr)
        return 2
    conditioned = "start (t = 0) and goal (t = 1)" if args.goal else "start (t = 0)"
    steps = "the schedule's steps" if args.steps is None else f"{args.steps} steps"
    print(
        f"conditioned on each test recording's {conditioned}; {steps}, beta-NLL {config.nll_beta:g}, seed {config.seed}"
    )
    print(format_table(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
