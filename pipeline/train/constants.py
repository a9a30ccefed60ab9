"""Names of the train stage (stdlib only, so the `cnep train` command can import them at once); its defaults are
TrainStageConfig's (pipeline.train.config)."""

from __future__ import annotations

# The presets of `--layout` (pipeline.train.presets maps them onto columns).
WINE_GLASS = "wine-glass"
MOTION = "motion"
SCENE = "scene"
ALL = "all"
PRESET_NAMES = (WINE_GLASS, SCENE, MOTION, ALL)

DEVICES = ("cpu", "cuda")

# Files in the work folder `.<OUT>.partial/` and in the finished checkpoint folder.
STATE_FILE = "state.pt"
LOG_FILE = "training_log.jsonl"
EXPERT_LABELS = "expert_labels"  # config.json: expert number -> the task of most of its training demonstrations
