"""Names, schemas and column blocks of the recording files: the one place they are spelled out.

Every other module (and every other package) imports these; never retype a topic name or a column
range. Changing anything here that changes what a file contains means bumping `FORMAT_VERSION`.
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType

# Version of the file contract written into every file's `episode` metadata. Readers refuse others.
FORMAT_VERSION = "1"
SUPPORTED_FORMAT_VERSIONS = frozenset({FORMAT_VERSION})

# File kinds, stored as `episode.kind`.
KIND_DEMONSTRATION = "demonstration"
KIND_TRAJECTORY = "trajectory"

# Topics.
TOPIC_IMAGE = "/camera/rgb"  # foxglove.CompressedImage, JPEG
CAMERA_NAME = "rgb"  # that camera as an observation or a LeRobot dataset names it: observation.images.rgb
TOPIC_POSE = "/ee/pose"  # foxglove.PoseInFrame, xyz in m + quaternion xyzw
TOPIC_GRIPPER = "/gripper"  # foxglove.JointStates with one joint named GRIPPER_JOINT
TOPIC_TRAJECTORY = "/trajectory"  # cnep.FeatureVector, packed float32, width = the column blocks' width
# cnep.FeatureVector: a step's feature block under each view (perception.views), V x 1280 packed float32
TOPIC_VIEWS = "/trajectory/views"
TOPIC_EVENTS = "/events"  # foxglove.Event, metadata key/value pairs (e.g. expert switches)

# Schema names (protobuf full names).
SCHEMA_IMAGE = "foxglove.CompressedImage"
SCHEMA_POSE = "foxglove.PoseInFrame"
SCHEMA_GRIPPER = "foxglove.JointStates"
SCHEMA_TRAJECTORY = "cnep.FeatureVector"
SCHEMA_EVENT = "foxglove.Event"

GRIPPER_JOINT = "gripper"
IMAGE_FORMAT = "jpeg"
FRAME_ID_CAMERA = "camera"
FRAME_ID_BASE = "base"

# Metadata record names.
METADATA_EPISODE = "episode"  # written when a writer opens: survives a killed recorder
METADATA_STEPS = "steps"  # written when a writer closes cleanly: n_steps, start/end/duration in ns
METADATA_EXTRACTOR = "extractor"  # feature extractor identity (trajectories with features only), at open
METADATA_REPAIR = "repair"  # written by `cnep repair`: source file, bytes and chunks used, what was lost
EPISODE_CAMERA = "camera"  # a key of `episode` metadata: the camera's observation key (a LeRobot dataset's feature)
NO_CAMERA = "none"  # its value for a recording without a camera

# Channel metadata keys of TOPIC_TRAJECTORY.
CHANNEL_KEY_BLOCKS = "layout"  # JSON {block: [start, stop]}: the column blocks (the key in the file is "layout")
CHANNEL_KEY_WIDTH = "width"
CHANNEL_KEY_DTYPE = "dtype"
CHANNEL_KEY_VIEWS = "views"  # of TOPIC_VIEWS: how many views each step holds

# The per-step vector [features(1280) | pose_xyz(3) | pose_quat_xyzw(4) | gripper(1)].
FEATURE_DIM = 1280
POSE_DIM = 7
STEP_DIM = FEATURE_DIM + POSE_DIM + 1  # 1288
MOTION_DIM = POSE_DIM + 1  # 8: the same vector without the feature block

BLOCK_FEATURES = "features"
BLOCK_POSE_XYZ = "pose_xyz"
BLOCK_POSE_QUAT = "pose_quat_xyzw"
BLOCK_GRIPPER = "gripper"

Blocks = Mapping[str, tuple[int, int]]  # block name -> [start, stop) column range

BLOCKS_FULL: Blocks = MappingProxyType(
    {
        BLOCK_FEATURES: (0, FEATURE_DIM),
        BLOCK_POSE_XYZ: (FEATURE_DIM, FEATURE_DIM + 3),
        BLOCK_POSE_QUAT: (FEATURE_DIM + 3, FEATURE_DIM + 7),
        BLOCK_GRIPPER: (FEATURE_DIM + 7, STEP_DIM),
    }
)
BLOCKS_MOTION: Blocks = MappingProxyType(
    {
        BLOCK_POSE_XYZ: (0, 3),
        BLOCK_POSE_QUAT: (3, 7),
        BLOCK_GRIPPER: (7, MOTION_DIM),
    }
)
# The only column blocks a trajectory file may carry, by width.
BLOCKS_BY_WIDTH: Mapping[int, Blocks] = MappingProxyType({STEP_DIM: BLOCKS_FULL, MOTION_DIM: BLOCKS_MOTION})

# Writing. Chunk compression by file kind: trajectories are float32 vectors that zstd hardly shrinks, while lz4
# writes them faster and reads them as fast (python -m benchmarks.bench_recordings measures both), so they use lz4;
# demonstrations use zstd. A chunk closes once it holds CHUNK_SIZE_BYTES of messages (uncompressed): a file cut short
# (a recorder killed, a disk full) loses only its last chunk to `cnep repair`, a few seconds of motion or a frame or
# two, where one large chunk would lose a whole short recording.
CHUNK_SIZE_BYTES = 16 * 1024
# Reading. A chunk that declares more uncompressed bytes than MAX_CHUNK_BYTES is damaged, and so is one past the
# file's budget: its chunks together inflate to at most INFLATION_GRACE_BYTES + MAX_INFLATION times the file's size
# (recordings.chunks), so that a small hostile file costs what a file of its size would. Recordings inflate by a
# few times at most (JPEG frames and float32 columns hardly compress).
MAX_CHUNK_BYTES = 64 * 1024 * 1024
MAX_INFLATION = 100
INFLATION_GRACE_BYTES = 2 * 1024 * 1024
# A file's summary (recordings.summary) is read within these: its summary section (about 120 bytes per chunk, so
# hours of frames at a chunk each) and each metadata record it indexes (a few hundred bytes in a cnep file).
MAX_SUMMARY_BYTES = 64 * 1024 * 1024
MAX_METADATA_BYTES = 1024 * 1024
# A camera frame declaring more pixels than this is refused when read, before anything decodes it: a few hundred bytes
# of JPEG can declare 65535 x 65535 pixels. This allows 8192 x 8192 (192 MiB decoded as RGB).
MAX_FRAME_PIXELS = 8192 * 8192
COMPRESSION_BY_KIND: Mapping[str, str] = MappingProxyType({KIND_DEMONSTRATION: "zstd", KIND_TRAJECTORY: "lz4"})
DEFAULT_COMPRESSION = "zstd"
JPEG_QUALITY = 90  # used only when a frame has to be (re-)encoded during ingest
LIBRARY_NAME = "cnep-pipeline recordings"
