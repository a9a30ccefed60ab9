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
CANDIDATES_DIR = "candidates"  # the checkpoint's folder of candidate checkpoints (TrainStageConfig.candidates)
EXPERT_LABELS = "expert_labels"  # config.json: expert number -> the task of most of its training demonstrations
TASKS = "tasks"  # config.json: the tasks of the training demonstrations, sorted
IMAGE_KEY = "image_key"  # config.json: the observation key of the demonstrations' camera (None: not named)
IMAGE_SIZE = "image_size"  # config.json: (height, width) of the training frames in pixels (None: no camera)
CONDITIONING = "conditioning"  # config.json: the policy's conditioning (runtime.ConditioningPolicy.to_dict)
MAX_STEP = "max_step"  # config.json: state name -> the largest step of that pose entry in the demonstrations
# config.json: the settings a model was trained with (models.CNEPConfig, models.TrainConfig with its schedule), which
# a policy of it carries as its recipe (runtime.PolicySpec.recipe).
RECIPE = ("model", "training")
