"""`cnep train TRAJ... --out CKPT`: trajectory MCAP files -> CNEP checkpoint folder (also under torchrun).

Settings come from, in this order of precedence: the command line, then a JSON file given with
`--config` (keys are the option names with underscores, e.g. `{"steps": 5000, "layout": "motion",
"encoder_widths": [64, 64]}`), then the defaults below (`None`: the default of `models.TrainConfig`).
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import json

from cnep.pipeline.train.constants import (
    DEFAULT_DEVICE,
    DEFAULT_PATIENCE,
    DEFAULT_PRESET,
    DEFAULT_SAVE_EVERY,
    DEFAULT_VAL_FRACTION,
    DEVICES,
    PRESET_NAMES,
)

HELP = "train a CNEP on trajectory files (resumable; multi-process with torchrun)"

# Options passed straight to models.TrainConfig: name -> (type, help). Not given: TrainConfig's default.
TRAIN_OPTIONS = {
    "steps": (int, "training steps"),
    "batch_size": (int, "samples per step and process"),
    "lr": (float, "peak learning rate of Adam"),
    "warmup_steps": (int, "steps of linear learning-rate warm-up"),
    "val_every": (int, "steps between validations"),
    "n_max": (int, "most observations per sample"),
    "m_max": (int, "most targets per sample"),
    "gate_freeze_fraction": (float, "share of the steps with the gate held uniform"),
    "gate_lr_scale": (float, "the gate's learning rate as a fraction of --lr"),
    "obs_noise": (float, "std of the noise added to training contexts' observed values (normalised units)"),
}

DEFAULTS = {
    "layout": DEFAULT_PRESET,
    "experts": 2,
    "assignment": "bounded",
    "encoder_widths": (128, 128),
    "expert_widths": (128, 128),
    "patience": DEFAULT_PATIENCE,
    "seed": 0,
    "val_fraction": DEFAULT_VAL_FRACTION,
    "save_every": DEFAULT_SAVE_EVERY,
    "device": DEFAULT_DEVICE,
    **dict.fromkeys(TRAIN_OPTIONS),
}


def _widths(text: str) -> tuple[int, ...]:
    try:
        return tuple(int(w) for w in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected comma-separated layer widths such as 128,128, got {text!r}"
        ) from None


def _default(name: str) -> str:
    value = DEFAULTS[name] if DEFAULTS[name] is not None else train_config_defaults().get(name)
    if value is None and name == "gate_lr_scale":  # None: the assignment's own
        return "the assignment's: " + ", ".join(
            f"{scale} for {a}" for a, scale in _config_literal("GATE_LR_SCALES").items()
        )
    if value is None:
        return "models.TrainConfig's default"
    return ",".join(map(str, value)) if isinstance(value, tuple) else str(value)


@functools.cache
def _config_tree():
    """models/config.py parsed, without importing it (torch)."""
    import ast
    import importlib.util
    from pathlib import Path

    spec = importlib.util.find_spec("cnep.models")
    source = Path(next(iter(spec.submodule_search_locations))) / "config.py"
    return ast.parse(source.read_text(encoding="utf-8"))


def _config_literal(name: str):
    """The literal value of a module-level constant of models/config.py."""
    import ast

    node = next(
        node
        for node in _config_tree().body
        if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == name for t in node.targets)
    )
    return ast.literal_eval(node.value)


@functools.cache
def train_config_defaults() -> dict:
    """models.TrainConfig's literal field defaults, read from models/config.py without importing it (torch)."""
    import ast

    body = next(
        node.body for node in _config_tree().body if isinstance(node, ast.ClassDef) and node.name == "TrainConfig"
    )
    found = {}
    for node in body:
        if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name) and node.value is not None:
            with contextlib.suppress(ValueError):  # not a literal (a factory): --help names TrainConfig's default
                found[node.target.id] = ast.literal_eval(node.value)
    return found


def add_arguments(parser: argparse.ArgumentParser) -> None:
    keep = argparse.SUPPRESS  # options not given stay out of args, so --config and DEFAULTS can fill them
    parser.add_argument("inputs", nargs="+", metavar="TRAJ", help="trajectory files or folders of them (read only)")
    parser.add_argument("--out", required=True, help="checkpoint folder to create (written when training completes)")
    parser.add_argument(
        "--config",
        metavar="JSON",
        default=None,
        help="JSON file of settings (option names with underscores); the command line wins",
    )
    parser.add_argument(
        "--layout",
        default=keep,
        choices=PRESET_NAMES,
        help="columns observed/queried/predicted: wine-glass = observe features+pose+gripper, query "
        "features, predict pose+gripper (1288-d files); scene = the same, but queries carry the "
        "time only; motion = pose+gripper only (8-d files or "
        "the motion columns of 1288-d files); all = observe and predict every column "
        f"(default {_default('layout')})",
    )
    m = parser.add_argument_group("model")
    m.add_argument(
        "--experts", type=int, default=keep, help=f"number of experts; 1 is a CNMP (default {_default('experts')})"
    )
    m.add_argument(
        "--assignment",
        default=keep,
        choices=("paper", "mixture", "annealed", "bounded"),
        help="how the loss assigns a context's targets to the experts: paper = the paper's gate-weighted "
        "NLL (every expert the gate has not ruled out learns every target), mixture = the mixture "
        "likelihood (the expert that explains the targets learns them; commits where the context "
        "cannot tell behaviours apart), annealed = the same posterior assignment, soft and balanced "
        "over the experts early in training, as sharp as the mixture's from 60%% of the steps on, "
        "the gate trained towards it at full strength, bounded = annealed with each expert's share "
        "kept within 0.5-1.5x an equal one instead of equal, faded out over 60-80%% of the steps; "
        "the best model is kept from where the balancing ends; docs/concepts.md "
        f"(default {_default('assignment')}: commits on shared contexts, keeps the paper's accuracy)",
    )
    m.add_argument(
        "--encoder-widths",
        type=_widths,
        default=keep,
        help=f"encoder layer widths (default {_default('encoder_widths')})",
    )
    m.add_argument(
        "--expert-widths", type=_widths, default=keep, help=f"expert layer widths (default {_default('expert_widths')})"
    )
    m.add_argument(
        "--matched-cnmp",
        action="store_true",
        help="train the one-expert CNMP with the parameter count of the CNEP these options describe "
        "(its expert widened; the comparison the paper makes)",
    )
    t = parser.add_argument_group("training")
    for name, (kind, text) in TRAIN_OPTIONS.items():
        t.add_argument(
            f"--{name.replace('_', '-')}", type=kind, default=keep, help=f"{text} (default {_default(name)})"
        )
    t.add_argument(
        "--patience",
        type=int,
        default=keep,
        help=f"validations without improvement before stopping early; 0 never stops early "
        f"(default {_default('patience')})",
    )
    t.add_argument(
        "--seed",
        type=int,
        default=keep,
        help=f"seed of the initial weights, split and batches (default {_default('seed')})",
    )
    t.add_argument(
        "--val-fraction",
        type=float,
        default=keep,
        help=f"share of the demonstrations held out for validation (default {_default('val_fraction')})",
    )
    t.add_argument(
        "--save-every", type=int, default=keep, help=f"steps between resumable saves (default {_default('save_every')})"
    )
    t.add_argument("--device", default=keep, choices=DEVICES, help=f"(default {_default('device')})")
    t.add_argument("--resume", action="store_true", help="continue the interrupted run writing to --out")
    t.add_argument(
        "--force",
        action="store_true",
        help="replace an existing --out checkpoint (one cnep train wrote) when training completes",
    )


def settings(args: argparse.Namespace) -> dict:
    """DEFAULTS, overridden by the --config file, overridden by the options given on the command line."""
    from_file = read_settings(args.config) if args.config else {}
    given = {name: getattr(args, name) for name in DEFAULTS if hasattr(args, name)}
    return {**DEFAULTS, **from_file, **given}


def read_settings(path: str) -> dict:
    """The settings of a --config JSON file, checked against DEFAULTS' names and types."""
    from cnep.pipeline.errors import PipelineError  # here, not at module level: it imports torch

    try:
        with open(path, encoding="utf-8") as f:
            data = json.load(f)
    except (OSError, json.JSONDecodeError) as exc:
        raise PipelineError(f"{path}: cannot read the --config file ({exc})") from None
    if not isinstance(data, dict):
        raise PipelineError(f"{path}: a --config file holds one JSON object of settings, got {type(data).__name__}")
    unknown = sorted(set(data) - set(DEFAULTS))
    if unknown:
        raise PipelineError(f"{path}: unknown setting(s) {', '.join(unknown)}; known: {', '.join(sorted(DEFAULTS))}")
    return {name: _checked(path, name, value) for name, value in data.items()}


def _checked(path: str, name: str, value):
    from cnep.pipeline.errors import PipelineError

    kind = TRAIN_OPTIONS[name][0] if name in TRAIN_OPTIONS else type(DEFAULTS[name])
    if kind is tuple and isinstance(value, list) and all(isinstance(v, int) for v in value):
        return tuple(value)
    if kind is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if isinstance(value, kind) and not (isinstance(value, bool) and kind is not bool):
        return value
    raise PipelineError(
        f"{path}: setting {name} must be {'a list of integers' if kind is tuple else kind.__name__}, got {value!r}"
    )


def fit_warmup(training, warmup_given: bool):
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
    defaults = train_config_defaults()
    warmup = training.steps * defaults["warmup_steps"] // defaults["steps"]
    log.warning(
        "--steps %d is not more than the default warm-up of %d steps: warming up over %d steps instead (the "
        "defaults' share of the steps); set --warmup-steps to choose",
        training.steps,
        training.warmup_steps,
        warmup,
    )
    return dataclasses.replace(training, warmup_steps=warmup)


def run(args: argparse.Namespace) -> int:
    import os
    from pathlib import Path

    from cnep.models import TrainConfig
    from cnep.pipeline.train.stage import TrainStageConfig, train

    chosen = settings(args)
    given = {name: chosen[name] for name in TRAIN_OPTIONS if chosen[name] is not None}
    training = fit_warmup(
        TrainConfig(patience=chosen["patience"] or None, seed=chosen["seed"], **given),
        warmup_given="warmup_steps" in given,
    )
    config = TrainStageConfig(
        inputs=tuple(Path(p) for p in args.inputs),
        out=Path(args.out),
        layout=chosen["layout"],
        n_experts=chosen["experts"],
        assignment=chosen["assignment"],
        encoder_widths=chosen["encoder_widths"],
        expert_widths=chosen["expert_widths"],
        matched_cnmp=args.matched_cnmp,
        training=training,
        val_fraction=chosen["val_fraction"],
        save_every=chosen["save_every"],
        device=chosen["device"],
        resume=args.resume,
        force=args.force,
        quiet=args.quiet,
    )
    out = train(config)
    if os.environ.get("RANK", "0") == "0":  # under torchrun only rank 0 reports
        from cnep.models import read_checkpoint_config

        result = read_checkpoint_config(out)["result"]
        print(
            f"trained {result['steps_run']} steps in {result['elapsed_s']:.1f} s; best validation error "
            f"{result['best_val_error']:.4g} (normalised units) at step {result['best_step']} -> {out}"
        )
    return 0
