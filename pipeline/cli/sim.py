"""`cnep sim obstacle --out DIR` and `cnep sim eval POLICY`: policies in closed loop in the simulator (the `sim`
extra)."""

from __future__ import annotations

import argparse

from cnep.pipeline.cli.fields import default_of, field_of, help_of
from cnep.pipeline.sim.config import PROTOCOLS, TASKS, EvalConfig, LoopSettings, SimConfig

HELP = "closed loop in a simulator: `obstacle` from nothing to the table, `eval` a given policy (the `sim` extra)"
OBSTACLE_HELP = (
    "generate demonstrations in the simulator, ingest, extract, train the CNEP and the matched CNMP, export, run "
    "them in closed loop and print the table"
)
EVAL_HELP = "run a policy (exported folder or checkpoint) in closed loop in the simulator and print its rates"


def _csv(kind):
    def parse(text: str) -> tuple:
        try:
            return tuple(kind(part) for part in text.split(",") if part)
        except ValueError:
            raise argparse.ArgumentTypeError(f"a comma-separated list, got {text!r}") from None

    return parse


def _loop_arguments(parser: argparse.ArgumentParser, config: type) -> None:
    """The options of every closed-loop evaluation (LoopSettings' fields), with `config`'s defaults."""
    parser.add_argument("--task", choices=TASKS, default=default_of(config, "task"), help=help_of(config, "task"))
    parser.add_argument("--cue", action="store_true", help=field_of(LoopSettings, "cue").metadata["help"])
    for name in ("episodes", "episode_seed", "record"):
        parser.add_argument(
            f"--{name.replace('_', '-')}", type=int, default=default_of(config, name), help=help_of(config, name)
        )
    parser.add_argument(
        "--protocols", type=_csv(str), default=default_of(config, "protocols"), metavar=",".join(PROTOCOLS),
        help=help_of(config, "protocols"),
    )  # fmt: skip


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="sim_command", metavar="TASK", required=True)
    obstacle = sub.add_parser("obstacle", help=OBSTACLE_HELP, description=OBSTACLE_HELP)
    obstacle.add_argument("--out", required=True, help="a new or empty folder for everything")
    _loop_arguments(obstacle, SimConfig)
    for name, kind in (("demonstrations", int), ("seed", int), ("train_steps", int), ("experts", int)):
        obstacle.add_argument(
            f"--{name.replace('_', '-')}", type=kind, default=default_of(SimConfig, name), help=help_of(SimConfig, name)
        )
    obstacle.add_argument(
        "--train-seeds", type=_csv(int), default=default_of(SimConfig, "train_seeds"), metavar="N,N,...",
        help=help_of(SimConfig, "train_seeds"),
    )  # fmt: skip
    obstacle.add_argument("--weights", default=default_of(SimConfig, "weights"), help=help_of(SimConfig, "weights"))
    obstacle.add_argument("--offline", action="store_true", help="never download the ImageNet weights")
    obstacle.set_defaults(_sim=run_obstacle)
    evaluate = sub.add_parser("eval", help=EVAL_HELP, description=EVAL_HELP)
    evaluate.add_argument("policy", help="a folder written by `cnep export` (runs without torch) or `cnep train`")
    evaluate.add_argument("--out", help="a new or empty folder for summary.json and the recordings (default: none)")
    evaluate.add_argument("--extractor", metavar="FILE", help="a checkpoint's feature weights (as `cnep export` takes)")
    _loop_arguments(evaluate, EvalConfig)
    evaluate.set_defaults(_sim=run_eval)


def run(args: argparse.Namespace) -> int:
    from cnep.sim import require_extra

    require_extra()  # one line naming the extra, before the stage imports MuJoCo
    return args._sim(args)


def _loop(args: argparse.Namespace) -> dict:
    return {
        "task": args.task,
        "cue": args.cue,
        "episodes": args.episodes,
        "episode_seed": args.episode_seed,
        "protocols": args.protocols,
        "record": args.record,
        "quiet": args.quiet,
    }


def run_obstacle(args: argparse.Namespace) -> int:
    import time

    config = SimConfig(
        out=args.out,
        demonstrations=args.demonstrations,
        seed=args.seed,
        train_seeds=args.train_seeds,
        train_steps=args.train_steps,
        experts=args.experts,
        weights=args.weights,
        offline=args.offline,
        **_loop(args),
    )  # checked before the stage loads
    from cnep.pipeline.sim.stage import SUMMARY_FILE, run_sim

    start = time.perf_counter()
    summary = run_sim(config)
    print(summary["table"])
    print(f"features: {summary['features']}; wrote {config.out}/{SUMMARY_FILE} and the recordings in "
          f"{config.out}/episodes; done in {time.perf_counter() - start:.0f} s")  # fmt: skip
    return 0


def run_eval(args: argparse.Namespace) -> int:
    config = EvalConfig(policy=args.policy, out=args.out, extractor=args.extractor, **_loop(args))
    from cnep.pipeline.run.config import policy_kind

    policy_kind(config.policy)  # refused before the stage loads
    from cnep.pipeline.sim.evaluate import run_eval as evaluate

    summary = evaluate(config)
    print(summary["table"])
    return 0
