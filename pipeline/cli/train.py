"""`cnep train TRAJ... --out CKPT`: trajectory MCAP files -> CNEP checkpoint folder (also under torchrun).

Settings come from, in this order of precedence: the command line, then a JSON file given with
`--config` (keys are the option names with underscores, e.g. `{"steps": 5000, "layout": "motion",
"encoder_widths": [64, 64]}`), then the defaults. Every default and its help text is a field of the
settings' dataclasses (`TrainStageConfig` and the `models.CNEPConfig` and `models.TrainConfig` it holds), whose
fields this module walks (pipeline.cli.fields, without importing torch); it keeps no value of its own.
"""

from __future__ import annotations

import argparse

from cnep.models.assignments import ASSIGNMENTS
from cnep.pipeline.cli.fields import INT_LIMIT, Option, add_options, build, options
from cnep.pipeline.train.config import TrainStageConfig

HELP = "train a CNEP on trajectory files (resumable; multi-process with torchrun)"

STAGE = TrainStageConfig  # the config whose fields (and its nested configs' fields) are the command's settings
NOTES = {"patience": "0 never stops early"}  # what the command line adds to a field's help
# How the command shows a default that the field's value (None) does not say.
SHOWN = {
    "gate_lr_scale": "the assignment's: " + ", ".join(f"{a.gate_lr_scale} for {a.name}" for a in ASSIGNMENTS.values())
}


def settings_of() -> dict[str, Option]:
    """Every setting of the command by its option name (with underscores): the fields of STAGE's configs."""
    return {option.name: option for option in options(STAGE)}


def default(name: str):
    """The default of setting `name`: its dataclass field's."""
    return settings_of()[name].default


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("inputs", nargs="+", metavar="TRAJ", help="trajectory files or folders of them (read only)")
    parser.add_argument("--out", required=True, help="checkpoint folder to create (written when training completes)")
    parser.add_argument(
        "--config",
        metavar="JSON",
        default=None,
        help="JSON file of settings (option names with underscores); the command line wins",
    )
    add_options(parser, list(settings_of().values()), NOTES, SHOWN)


def settings(args: argparse.Namespace) -> tuple[dict, set[str]]:
    """The defaults, overridden by the --config file, overridden by the options given on the command line; and
    the names of the settings given (in the file or on the command line)."""
    known = settings_of()
    from_file = read_settings(args.config) if args.config else {}
    given = {name: getattr(args, name) for name in known if hasattr(args, name)}
    return {**{name: option.default for name, option in known.items()}, **from_file, **given}, {*from_file, *given}


def read_settings(path: str) -> dict:
    """The settings of a --config JSON file, checked against the settings' names and types."""
    from cnep.pipeline.errors import PipelineError
    from cnep.pipeline.inputs import read_json_object

    data = read_json_object(path, "the --config file", "give the settings as one JSON object")
    known = settings_of()
    unknown = sorted(set(data) - set(known))
    if unknown:
        raise PipelineError(f"{path}: unknown setting(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}")
    return {name: _checked(path, name, value) for name, value in data.items()}


def _checked(path: str, name: str, value):
    """The --config file `path`'s `value` of setting `name`, as the setting's type; PipelineError otherwise."""
    from cnep.models.config import in_message
    from cnep.pipeline.errors import PipelineError

    kind = settings_of()[name].kind
    if value is None and default(name) is None:
        return value
    if kind is tuple:
        fits = isinstance(value, list) and all(_an_integer(v) for v in value)
    elif kind is int:
        fits = _an_integer(value)
    elif kind is float:
        fits = _an_integer(value) or isinstance(value, float)
    else:
        fits = isinstance(value, kind)
    if not fits:
        what = {tuple: "a list of integers", int: "an integer"}.get(kind, kind.__name__)
        within = f" from {-(INT_LIMIT - 1)} to {INT_LIMIT - 1}" if kind in (int, tuple) else ""
        raise PipelineError(f"{path}: setting {name} must be {what}{within}, got {in_message(value)}")
    return tuple(value) if kind is tuple else float(value) if kind is float else value


def _an_integer(value: object) -> bool:
    """Whether a --config value is an integer a setting can hold (within pipeline.cli.fields.INT_LIMIT)."""
    return isinstance(value, int) and not isinstance(value, bool) and -INT_LIMIT < value < INT_LIMIT


def stage_config(args: argparse.Namespace) -> TrainStageConfig:
    """The train stage's settings for the parsed command line (with its --config file)."""
    from pathlib import Path

    chosen, _ = settings(args)
    chosen["patience"] = chosen["patience"] or None  # 0: never stop early
    return build(STAGE, chosen, inputs=tuple(Path(p) for p in args.inputs), out=Path(args.out), quiet=args.quiet)


def run(args: argparse.Namespace) -> int:
    import os

    from cnep.pipeline.inputs import find_trajectory_files

    config = stage_config(args)
    find_trajectory_files(config.inputs)  # a missing input is refused before torch loads with the stage
    from cnep.pipeline.progress import heartbeat

    with heartbeat("loading torch and the train stage", args.quiet):
        from cnep.pipeline.train.stage import train

    out = train(config)
    if os.environ.get("RANK", "0") == "0":  # under torchrun only rank 0 reports
        from cnep.models import read_checkpoint_config

        result = read_checkpoint_config(out)["result"]
        print(
            f"trained {result['steps_run']} steps in {result['elapsed_s']:.1f} s; best validation error "
            f"{result['best_val_error']:.4g} (normalised units; predicting the training mean scores "
            f"{result['mean_prediction_error']:.4g}) at step {result['best_step']} -> {out}"
        )
    return 0
