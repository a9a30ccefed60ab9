"""`cnep train TRAJ... --out CKPT`: trajectory MCAP files -> CNEP checkpoint folder (also under torchrun)."""

from __future__ import annotations

import argparse

from pipeline.training_constants import (DEFAULT_DEVICE, DEFAULT_PATIENCE, DEFAULT_PRESET, DEFAULT_SAVE_EVERY,
                                         DEFAULT_VAL_FRACTION, DEVICES, PRESET_NAMES)

HELP = "train a CNEP on trajectory files (resumable; multi-process with torchrun)"

# Command-line option -> models.TrainConfig field; None (not given) keeps the stage's default.
TRAIN_OPTIONS = {
    "steps": (int, "training steps (models default 20000)"),
    "batch_size": (int, "samples per step and process (models default 32)"),
    "lr": (float, "peak learning rate of Adam (models default 1e-3)"),
    "warmup_steps": (int, "steps of linear learning-rate warm-up (models default 2000)"),
    "val_every": (int, "steps between validations (models default 500)"),
    "n_max": (int, "most observations per sample (models default 10)"),
    "m_max": (int, "most targets per sample (models default 10)"),
    "gate_freeze_fraction": (float, "share of the steps with the gate held uniform (models default 0.3)"),
}


def _widths(text: str) -> tuple[int, ...]:
    try:
        return tuple(int(w) for w in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated layer widths such as 128,128, got {text!r}")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("inputs", nargs="+", metavar="TRAJ", help="trajectory files or folders of them (read only)")
    parser.add_argument("--out", required=True, help="checkpoint folder to create (written when training completes)")
    parser.add_argument("--layout", default=DEFAULT_PRESET, choices=PRESET_NAMES,
                        help="columns observed/queried/predicted: wine-glass = observe features+pose+gripper, query "
                             "features, predict pose+gripper (1288-d files); motion = pose+gripper only (8-d files or "
                             "the motion columns of 1288-d files); all = observe and predict every column "
                             f"(default {DEFAULT_PRESET})")
    m = parser.add_argument_group("model")
    m.add_argument("--experts", type=int, default=2, help="number of experts; 1 is a CNMP (default 2)")
    m.add_argument("--encoder-widths", type=_widths, default=(128, 128), help="encoder layer widths (default 128,128)")
    m.add_argument("--expert-widths", type=_widths, default=(128, 128), help="expert layer widths (default 128,128)")
    t = parser.add_argument_group("training")
    for name, (kind, text) in TRAIN_OPTIONS.items():
        t.add_argument(f"--{name.replace('_', '-')}", type=kind, default=None, help=text)
    t.add_argument("--patience", type=int, default=DEFAULT_PATIENCE,
                   help=f"validations without improvement before stopping early; 0 never stops early "
                        f"(default {DEFAULT_PATIENCE})")
    t.add_argument("--seed", type=int, default=0, help="seed of the initial weights, split and batches (default 0)")
    t.add_argument("--val-fraction", type=float, default=DEFAULT_VAL_FRACTION,
                   help=f"share of the demonstrations held out for validation (default {DEFAULT_VAL_FRACTION})")
    t.add_argument("--save-every", type=int, default=DEFAULT_SAVE_EVERY,
                   help=f"steps between resumable saves (default {DEFAULT_SAVE_EVERY})")
    t.add_argument("--device", default=DEFAULT_DEVICE, choices=DEVICES, help=f"(default {DEFAULT_DEVICE})")
    t.add_argument("--resume", action="store_true", help="continue the interrupted run writing to --out")
    t.add_argument("--force", action="store_true", help="replace an existing --out folder when training completes")


def run(args: argparse.Namespace) -> int:
    import os
    from pathlib import Path

    from models import TrainConfig
    from pipeline.train import TrainStageConfig, train

    given = {name: getattr(args, name) for name in TRAIN_OPTIONS if getattr(args, name) is not None}
    training = TrainConfig(patience=args.patience or None, seed=args.seed, **given)
    config = TrainStageConfig(
        inputs=tuple(Path(p) for p in args.inputs),
        out=Path(args.out),
        layout=args.layout,
        n_experts=args.experts,
        encoder_widths=args.encoder_widths,
        expert_widths=args.expert_widths,
        training=training,
        val_fraction=args.val_fraction,
        save_every=args.save_every,
        device=args.device,
        resume=args.resume,
        force=args.force,
        quiet=args.quiet,
    )
    out = train(config)
    if os.environ.get("RANK", "0") == "0":  # under torchrun only rank 0 reports
        from models import read_checkpoint_config

        result = read_checkpoint_config(out)["result"]
        print(f"trained {result['steps_run']} steps in {result['elapsed_s']:.1f} s; best validation error "
              f"{result['best_val_error']:.4g} (normalised units) at step {result['best_step']} -> {out}")
    return 0
