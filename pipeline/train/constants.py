"""Names and defaults of the train stage (stdlib only, so the `cnep train` command can import them at once)."""

from __future__ import annotations

# The presets of `--layout` (pipeline.train.presets maps them onto columns).
WINE_GLASS = "wine-glass"
MOTION = "motion"
SCENE = "scene"
ALL = "all"
PRESET_NAMES = (WINE_GLASS, SCENE, MOTION, ALL)
DEFAULT_PRESET = SCENE  # the gate must decide the behaviour (wine-glass: the query frame gives it away)

DEVICES = ("cpu", "cuda")
DEFAULT_DEVICE = "cpu"

DEFAULT_PATIENCE = 10  # validations without improvement before stopping early
DEFAULT_VAL_FRACTION = 0.2  # share of the demonstrations held out for validation
DEFAULT_SAVE_EVERY = 500  # steps between resumable saves

# Files in the work folder `.<OUT>.partial/` and in the finished checkpoint folder.
STATE_FILE = "state.pt"
LOG_FILE = "training_log.jsonl"
