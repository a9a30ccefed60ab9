"""Names and defaults of the torch-free runtime: observation keys, exported files, the manifest's format."""

from __future__ import annotations

# Observation keys, as LeRobot names them: one RGB image per camera, the robot's state vector, and the seconds
# since the episode began (LeRobot's dataset frames carry `timestamp` the same way).
IMAGE_KEY_PREFIX = "observation.images."
STATE_KEY = "observation.state"
TIMESTAMP_KEY = "timestamp"

# What an observation may carry: a timestamp under a day (a clock's time of day or epoch seconds is refused), the
# end effector within a kilometre of the robot's origin on each axis, and a quaternion whose length is 1 within the
# recordings' tolerance (normalised; further off, or zero, it is no orientation and is refused).
MAX_TIME_S = 86_400.0
MAX_POSITION_M = 1_000.0
QUATERNION_TOLERANCE = 0.1
# The gripper is in the recordings' unit (an opening in m, a command in [0, 1], a motor's ticks), so its bound is the
# training demonstrations' own: within this many of their standard deviations of their mean. Further off, a reading
# is a sensor's "no reading" value (3e38, -1) or another unit, which the model would turn into a wild motion.
GRIPPER_DEVIATIONS = 100.0

IMAGE_SIZE = 224  # frames are resized to IMAGE_SIZE x IMAGE_SIZE pixels before the feature network

# The exported folder (`cnep export`): a manifest, the ONNX graphs and the runtime's own installable source.
MANIFEST_FILE = "manifest.json"
MANIFEST_FORMAT = "cnep-policy"
FORMAT_VERSION = 2  # what `cnep export` writes
READ_VERSIONS = (1, 2)  # what the runtime loads: 1 lacks the gripper command and the active expert's rule
FEATURES_FILES = {"fp32": "features.onnx", "int8": "features-int8.onnx"}  # uint8 pixels -> features, per precision
ENCODER_FILE = "encoder.onnx"  # [t, normalised observed columns] (N, 1 + obs_dim) -> encodings (N, H)
DECODER_FILE = "decoder.onnx"  # latent (1, H), queries (M, 1 + query_dim) -> gate (d,), mean and std (d, M, dy)
RUNTIME_FOLDER = "runtime"  # `pip install DIR/runtime` installs cnep.runtime with RUNTIME_REQUIREMENTS, no torch

# What the runtime imports besides the standard library (pip names); pyproject.toml's bounds, kept equal by a test.
RUNTIME_REQUIREMENTS = ("numpy>=1.24", "onnxruntime>=1.17", "opencv-python-headless>=4.8")

BACKENDS = ("onnxruntime", "openvino")  # what runs the exported graphs; openvino only where it is installed
DEFAULT_BACKEND = BACKENDS[0]
DEFAULT_PRECISION = "fp32"  # the feature graph a policy runs (FEATURES_FILES' keys)
DEFAULT_WAYPOINTS = 10  # future steps a policy predicts per step (select_action returns the first)
