"""`cnep sim obstacle --out DIR`, `cnep sim pick-place --out DIR`, `cnep sim grid --out DIR` and `cnep sim eval
POLICY`: policies in closed loop in the simulator (the `sim` extra), each task's run by the one stage
(pipeline.sim.stage.run_sim), the benchmark's grid of them by pipeline.sim.grid. The options are the fields of
SimConfig, PickPlaceConfig, GridConfig and EvalConfig (pipeline.cli.fields)."""

from __future__ import annotations

import argparse

from cnep.pipeline.cli.executor import add_executor, executor_of
from cnep.pipeline.cli.fields import add_options, build, chosen_options, options
from cnep.pipeline.sim.config import SHOWN, SIM_TASKS, EvalConfig, PickPlaceConfig, SimConfig, with_task
from cnep.pipeline.sim.grid_config import GridConfig

HELP = (
    "closed loop in a simulator: `obstacle` and `pick-place` from nothing to the table, `grid` the benchmark over "
    "sets, seeds and numbers of demonstrations, `eval` a given policy (the `sim` extra)"
)
OBSTACLE_HELP = (
    "generate demonstrations in the simulator, ingest, extract, train the CNEP and the matched CNMP, keep the "
    "checkpoint of each that succeeds most on validation episodes, export, run them in closed loop on other episodes "
    "and print the table"
)
PICK_PLACE_HELP = (
    "the pick-and-place task: generate demonstrations, ingest, extract, train the CNEP and the matched CNMP, keep "
    "the checkpoint of each that succeeds most on validation episodes, export, run them and the baselines in closed "
    "loop on other episodes (scenes that decide the place, leave it free, change during the motion) and print the "
    "table"
)
GRID_HELP = (
    "the closed-loop benchmark: every task x demonstration set x training seed x demonstrations per behaviour x model "
    "trained and run on the same reported episode seeds, resumable; writes a CSV and a table with Wilson intervals"
)
GRID_SHOWN = {**SHOWN, "train_steps": "the task's, as `cnep sim TASK` trains its models"}
EVAL_HELP = "run a policy (exported folder or checkpoint) in closed loop in the simulator and print its rates"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="sim_command", metavar="TASK", required=True)
    for cls, help in ((SimConfig, OBSTACLE_HELP), (PickPlaceConfig, PICK_PLACE_HELP)):
        task = sub.add_parser(cls.TASK, help=help, description=help)
        task.add_argument(
            "--out",
            required=True,
            help="a new or empty folder for everything; the stages work in .OUT.partial beside it, which keeps those "
            "finished when the run is stopped: the same command again resumes after them",
        )
        add_options(task, options(cls), defaults=SHOWN)
        task.set_defaults(_sim=run_task, _config=cls)
    grid = sub.add_parser("grid", help=GRID_HELP, description=GRID_HELP)
    grid.add_argument("--out", required=True, help="the grid's folder: a new one, or a grid's to resume or extend")
    grid.add_argument(
        "--tasks",
        nargs="+",
        choices=SIM_TASKS,
        default=argparse.SUPPRESS,
        help=f"the tasks, among those with a `cnep sim TASK` command (default: {' '.join(SIM_TASKS)})",
    )
    add_options(grid, options(GridConfig), defaults=GRID_SHOWN)
    add_executor(grid, "the cells", "--workers")
    grid.set_defaults(_sim=run_grid)
    evaluate = sub.add_parser("eval", help=EVAL_HELP, description=EVAL_HELP)
    evaluate.add_argument("policy", help="a folder written by `cnep export` (runs without torch) or `cnep train`")
    evaluate.add_argument("--out", help="a new or empty folder for summary.json and the recordings (default: none)")
    evaluate.add_argument("--extractor", metavar="FILE", help="a checkpoint's feature weights (as `cnep export` takes)")
    add_options(evaluate, options(EvalConfig), defaults=SHOWN)
    evaluate.set_defaults(_sim=run_eval)


def config_of(cls: type, args: argparse.Namespace, **given):
    """The settings `cls` of the parsed command line: the options given, the others the dataclass's defaults."""
    return build(cls, chosen_options(cls, args), quiet=args.quiet, **given)


def run(args: argparse.Namespace) -> int:
    return args._sim(args)


def run_task(args: argparse.Namespace) -> int:
    import time

    config = config_of(args._config, args, out=args.out)  # checked before the stage loads
    from cnep.pipeline.progress import heartbeat
    from cnep.pipeline.sim.extras import require_extras

    require_extras(config, f"cnep sim {config.TASK}")  # one line naming the missing extras, before any work

    with heartbeat("loading torch and the simulator", args.quiet):
        from cnep.pipeline.sim.partial import SUMMARY_FILE
        from cnep.pipeline.sim.stage import run_sim

    start = time.perf_counter()
    summary = run_sim(config)
    print(summary["table"])
    print(f"features: {summary['features']}; wrote {config.out}/{SUMMARY_FILE} and the recordings in "
          f"{config.out}/episodes; done in {time.perf_counter() - start:.0f} s")  # fmt: skip
    return 0


def run_grid(args: argparse.Namespace) -> int:
    kind, address = executor_of(args)
    tasks = {"tasks": tuple(args.tasks)} if "tasks" in args else {}
    config = config_of(GridConfig, args, out=args.out, executor=kind, address=address, **tasks)
    from cnep.pipeline.progress import heartbeat
    from cnep.pipeline.sim.extras import require_extras

    require_extras(config, "cnep sim grid")

    with heartbeat("loading torch and the simulator", args.quiet):
        from cnep.pipeline.sim.grid import CSV_FILE, TABLE_FILE
        from cnep.pipeline.sim.grid import run_grid as grid

    result = grid(config)
    print(result.table)
    print(f"{result.ran} of {result.cells} cells run now; wrote {config.out}/{CSV_FILE} and {config.out}/{TABLE_FILE}")
    return 0


def run_eval(args: argparse.Namespace) -> int:
    config = config_of(EvalConfig, args, policy=args.policy, out=args.out, extractor=args.extractor)
    from cnep.pipeline.progress import heartbeat
    from cnep.pipeline.run.config import conditioning_line, own_conditioning
    from cnep.pipeline.sim.extras import require_extras

    require_extras(config, "cnep sim eval")  # not a policy folder, or the extras missing: refused before any work
    config = with_task(config)  # not the policy's task: refused before the stage loads

    with heartbeat("loading torch and the simulator", args.quiet):
        from cnep.pipeline.sim.evaluate import run_eval as evaluate

    summary = evaluate(config)
    print(summary["table"])
    own = own_conditioning(config.policy)
    print(conditioning_line(own, config.conditioning))
    return 0
