"""`cnep train TRAJ... --out CKPT`: trajectory MCAP files -> CNEP checkpoint folder (also under torchrun).

Settings come from, in this order of precedence: the command line, then a JSON file given with
`--config` (keys are the option names with underscores, e.g. `{"steps": 5000, "layout": "motion",
"encoder_widths": [64, 64]}`), then the defaults. Every default and its help text is a field of the
settings' dataclass (SETTINGS): `TrainStageConfig`, `models.CNEPConfig`, `models.TrainConfig`; this module
reads them (without importing torch) and keeps no value of its own.
"""

from __future__ import annotations

import argparse

from cnep.models.config import ASSIGNMENTS, GATE_LR_SCALES, CNEPConfig, TrainConfig
from cnep.pipeline.cli.fields import default_of, field_of, help_of
from cnep.pipeline.train.config import TrainStageConfig
from cnep.pipeline.train.constants import DEVICES, PRESET_NAMES

HELP = "train a CNEP on trajectory files (resumable; multi-process with torchrun)"

# Options given straight to models.TrainConfig, by its field names.
TRAIN_OPTIONS = (
    "steps",
    "batch_size",
    "lr",
    "warmup_steps",
    "val_every",
    "n_max",
    "m_max",
    "gate_freeze_fraction",
    "gate_lr_scale",
    "obs_noise",
    "observed_only_decay",
    "observed_only_dropout",
    "first_steps_fraction",
    "first_steps_max",
    "patience",
    "seed",
    "threads",
)
# Every setting of the command (its option name with underscores) -> (the dataclass, the field) holding its
# default and help.
SETTINGS = {
    "layout": (TrainStageConfig, "layout"),
    "experts": (CNEPConfig, "n_experts"),
    "assignment": (CNEPConfig, "assignment"),
    "encoder_widths": (CNEPConfig, "encoder_widths"),
    "expert_widths": (CNEPConfig, "expert_widths"),
    **{name: (TrainConfig, name) for name in TRAIN_OPTIONS},
    "val_fraction": (TrainStageConfig, "val_fraction"),
    "save_every": (TrainStageConfig, "save_every"),
    "device": (TrainStageConfig, "device"),
}
CHOICES = {"layout": PRESET_NAMES, "assignment": ASSIGNMENTS, "device": DEVICES}
NOTES = {"patience": "0 never stops early"}  # what the command line adds to a field's help


def default(name: str):
    """The default of setting `name`: its dataclass field's."""
    return default_of(*SETTINGS[name])


def _widths(text: str) -> tuple[int, ...]:
    try:
        return tuple(int(w) for w in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected comma-separated layer widths such as 128,128, got {text!r}"
        ) from None


def _kind(name: str):
    """The type a setting's value has: from its field's annotation (a string: the module defers annotations)."""
    annotation = str(field_of(*SETTINGS[name]).type)
    if annotation.startswith("tuple"):
        return tuple
    return next(kind for kind in (float, int, str) if kind.__name__ in annotation)


def _help(name: str) -> str:
    if name == "gate_lr_scale":  # None: the assignment's own
        assignments = ", ".join(f"{scale} for {a}" for a, scale in GATE_LR_SCALES.items())
        return help_of(*SETTINGS[name], default=f"the assignment's: {assignments}")
    return help_of(*SETTINGS[name], note=NOTES.get(name))


def _option(group, name: str) -> None:
    kind = _kind(name)
    group.add_argument(
        f"--{name.replace('_', '-')}",
        type=_widths if kind is tuple else kind,
        default=argparse.SUPPRESS,  # options not given stay out of args, so --config and the defaults fill them
        choices=CHOICES.get(name),
        help=_help(name),
    )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("inputs", nargs="+", metavar="TRAJ", help="trajectory files or folders of them (read only)")
    parser.add_argument("--out", required=True, help="checkpoint folder to create (written when training completes)")
    parser.add_argument(
        "--config",
        metavar="JSON",
        default=None,
        help="JSON file of settings (option names with underscores); the command line wins",
    )
    _option(parser, "layout")
    model = parser.add_argument_group("model")
    for name in ("experts", "assignment", "encoder_widths", "expert_widths"):
        _option(model, name)
    model.add_argument(
        "--matched-cnmp", action="store_true", help=field_of(TrainStageConfig, "matched_cnmp").metadata["help"]
    )
    training = parser.add_argument_group("training")
    for name in (*TRAIN_OPTIONS, "val_fraction", "save_every", "device"):
        _option(training, name)
    training.add_argument("--resume", action="store_true", help="continue the interrupted run writing to --out")
    training.add_argument(
        "--force",
        action="store_true",
        help="replace an existing --out checkpoint (one cnep train wrote) when training completes",
    )


def settings(args: argparse.Namespace) -> tuple[dict, set[str]]:
    """The defaults, overridden by the --config file, overridden by the options given on the command line; and
    the names of the settings given (in the file or on the command line)."""
    from_file = read_settings(args.config) if args.config else {}
    given = {name: getattr(args, name) for name in SETTINGS if hasattr(args, name)}
    return {**{name: default(name) for name in SETTINGS}, **from_file, **given}, {*from_file, *given}


def read_settings(path: str) -> dict:
    """The settings of a --config JSON file, checked against SETTINGS' names and types."""
    from cnep.pipeline.errors import PipelineError
    from cnep.runtime.jsonfile import read_json

    try:
        data = read_json(path)
    except (OSError, ValueError) as exc:
        raise PipelineError(f"{path}: cannot read the --config file ({exc})") from None
    if not isinstance(data, dict):
        raise PipelineError(f"{path}: a --config file holds one JSON object of settings, got {type(data).__name__}")
    unknown = sorted(set(data) - set(SETTINGS))
    if unknown:
        raise PipelineError(f"{path}: unknown setting(s) {', '.join(unknown)}; known: {', '.join(sorted(SETTINGS))}")
    return {name: _checked(path, name, value) for name, value in data.items()}


def _checked(path: str, name: str, value):
    from cnep.pipeline.errors import PipelineError

    kind = _kind(name)
    if value is None and default(name) is None:
        return value
    if kind is tuple and isinstance(value, list) and all(isinstance(v, int) for v in value):
        return tuple(value)
    if kind is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if isinstance(value, kind) and not isinstance(value, bool):
        return value
    raise PipelineError(
        f"{path}: setting {name} must be {'a list of integers' if kind is tuple else kind.__name__}, got {value!r}"
    )


def fit_warmup(training: TrainConfig, warmup_given: bool) -> TrainConfig:
    """A TrainConfig whose warm-up ends before its last step: scaled like the defaults when not given, else a warning.

    With `--steps 1000` and the default 2000 warm-up steps the learning rate would never reach its peak.
    """
    import dataclasses
    import logging

    if training.warmup_steps < training.steps:
        return training
    log = logging.getLogger("cnep.pipeline.train")
    if warmup_given:
        log.warning(
            "--warmup-steps %d >= --steps %d: the learning rate never reaches its peak --lr",
            training.warmup_steps,
            training.steps,
        )
        return training
    warmup = training.steps * TrainConfig.warmup_steps // TrainConfig.steps
    log.warning(
        "--steps %d is not more than the default warm-up of %d steps: warming up over %d steps instead (the "
        "defaults' share of the steps); set --warmup-steps to choose",
        training.steps,
        training.warmup_steps,
        warmup,
    )
    return dataclasses.replace(training, warmup_steps=warmup)


def stage_config(args: argparse.Namespace) -> TrainStageConfig:
    """The train stage's settings for the parsed command line (with its --config file)."""
    from pathlib import Path

    chosen, given = settings(args)
    training = {name: chosen[name] for name in TRAIN_OPTIONS}
    training["patience"] = training["patience"] or None  # 0: never stop early
    return TrainStageConfig(
        inputs=tuple(Path(p) for p in args.inputs),
        out=Path(args.out),
        layout=chosen["layout"],
        n_experts=chosen["experts"],
        assignment=chosen["assignment"],
        encoder_widths=chosen["encoder_widths"],
        expert_widths=chosen["expert_widths"],
        matched_cnmp=args.matched_cnmp,
        training=fit_warmup(TrainConfig(**training), warmup_given="warmup_steps" in given),
        val_fraction=chosen["val_fraction"],
        save_every=chosen["save_every"],
        device=chosen["device"],
        resume=args.resume,
        force=args.force,
        quiet=args.quiet,
    )


def run(args: argparse.Namespace) -> int:
    import os

    from cnep.pipeline.inputs import find_trajectory_files

    config = stage_config(args)
    find_trajectory_files(config.inputs)  # a missing input is refused before torch loads with the stage
    from cnep.pipeline.train.stage import train

    out = train(config)
    if os.environ.get("RANK", "0") == "0":  # under torchrun only rank 0 reports
        from cnep.models import read_checkpoint_config

        result = read_checkpoint_config(out)["result"]
        print(
            f"trained {result['steps_run']} steps in {result['elapsed_s']:.1f} s; best validation error "
            f"{result['best_val_error']:.4g} (normalised units) at step {result['best_step']} -> {out}"
        )
    return 0
