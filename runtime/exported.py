"""An exported policy folder (`cnep export`) loaded as a `Policy`, with ONNX Runtime or OpenVINO, without torch.

    policy = load_policy("policy/")                      # fp32 features, ONNX Runtime
    policy = load_policy("policy/", precision="int8")    # the int8 feature graph, if the export has one

The graphs' input and output names are fixed here (the exporter imports them): the features graph takes
`pixels` (N, 224, 224, 3) uint8 and gives `features` (N, 1280); the encoder takes `obs` (N, 1 + obs_dim)
and gives `encodings` (N, H); the decoder takes `r` (1, H) and `query` (M, 1 + query_dim) and gives
`gate` (d,), `mean` and `std` (d, M, dy), in the model's normalised units. Each graph is run once when loaded, on
zeros of those shapes: a graph that takes or gives anything else (another model's, the encoder and the decoder
swapped) is refused then, naming its file, as is anything its backend raises (runtime.sessions).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cnep.runtime.conditioning import Columns, ConditioningPolicy
from cnep.runtime.constants import DEFAULT_BACKEND, DEFAULT_PRECISION, DEFAULT_WAYPOINTS
from cnep.runtime.errors import PolicyError
from cnep.runtime.frames import pixel_buffer
from cnep.runtime.gripper import GripperCommand
from cnep.runtime.manifest import check_closed, read_manifest
from cnep.runtime.policy import Features, Policy
from cnep.runtime.sessions import Graph, load_graph
from cnep.runtime.spans import span_indices
from cnep.runtime.timebase import TimeBase

FEATURES_INPUT, FEATURES_OUTPUT = "pixels", "features"
ENCODER_INPUT, ENCODER_OUTPUT = "obs", "encodings"
DECODER_INPUTS, DECODER_OUTPUTS = ("r", "query"), ("gate", "mean", "std")


def load_features(
    folder: str | Path, precision: str = DEFAULT_PRECISION, backend: str = DEFAULT_BACKEND, threads: int | None = None
) -> Features | None:
    """The feature function (uint8 pixels (N, 224, 224, 3) -> float32 features (N, 1280)) of the policy exported
    to `folder`, checked as `load_policy` checks it; None for a model that sees no camera."""
    folder = Path(folder)
    manifest = read_manifest(folder)
    check_closed(folder, manifest)
    if manifest.spec.features is None:
        return None
    if precision not in manifest.features:
        raise PolicyError(
            f"{folder}: has no {precision} feature graph (it has {', '.join(sorted(manifest.features))}); "
            f"export with --int8 for int8 features"
        )
    path = manifest.verified(folder, manifest.features[precision]["file"])
    graph = load_graph(str(path), backend, threads)
    a, b = manifest.spec.features
    pixels = pixel_buffer(1)
    pixels.fill(0)
    given = graph({FEATURES_INPUT: pixels})[0]  # (1, F)
    if np.shape(given) != (1, b - a):
        raise PolicyError(
            f"{path}: gives features of shape {np.shape(given)} for one frame, the model takes (1, {b - a}); export "
            f"the checkpoint again"
        )
    return lambda pixels: graph({FEATURES_INPUT: pixels})[0]


class ExportedNetwork:
    """The encoder and the decoder (gate + experts) graphs as a `runtime.conditioning.Network`."""

    def __init__(self, encoder: Graph, decoder: Graph) -> None:
        self._encoder, self._decoder = encoder, decoder

    def encode(self, obs: np.ndarray) -> np.ndarray:
        """[t, observed columns] (N, 1 + obs_dim) float32 -> encodings (N, H)."""
        return self._encoder({ENCODER_INPUT: obs})[0]

    def decode(self, r: np.ndarray, query: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Latent (1, H), queries (M, 1 + query_dim) -> gate (d,), mean and std (d, M, dy)."""
        gate, mean, std = self._decoder({DECODER_INPUTS[0]: r, DECODER_INPUTS[1]: query})
        return gate, mean, std


def check_network(network: ExportedNetwork, columns: Columns, n_experts: int, encoder: Path, decoder: Path) -> None:
    """Run the graphs once on zeros (two observations, three queries); PolicyError naming the graph whose outputs do
    not have the shapes of the model `columns` and `n_experts` describe."""
    obs_dim, query_dim = len(span_indices(columns.observed)), len(span_indices(columns.query))
    dy = len(span_indices(columns.predicted))
    encodings = network.encode(np.zeros((2, 1 + obs_dim), dtype=np.float32))  # (2, H)
    if np.ndim(encodings) != 2 or len(encodings) != 2:
        raise PolicyError(
            f"{encoder}: gives encodings of shape {np.shape(encodings)} for 2 observations, an encoder (2, H); "
            f"export the checkpoint again"
        )
    r = np.zeros((1, encodings.shape[1]), dtype=np.float32)  # (1, H)
    gate, mean, std = network.decode(r, np.zeros((3, 1 + query_dim), dtype=np.float32))  # (d,), (d, 3, dy) x 2
    if np.shape(gate) != (n_experts,) or {np.shape(mean), np.shape(std)} != {(n_experts, 3, dy)}:
        raise PolicyError(
            f"{decoder}: gives a gate of shape {np.shape(gate)} and predictions of {np.shape(mean)} for 3 queries, "
            f"the manifest's model ({n_experts},) and ({n_experts}, 3, {dy}); export the checkpoint again"
        )


def load_policy(
    folder: str | Path,
    *,
    precision: str = DEFAULT_PRECISION,
    backend: str = DEFAULT_BACKEND,
    threads: int | None = None,
    waypoints: int = DEFAULT_WAYPOINTS,
    conditioning: ConditioningPolicy | None = None,
    time_base: TimeBase | None = None,
    gripper: GripperCommand | None = None,
    camera: str | None = None,
) -> Policy:
    """The policy exported to `folder`, each graph checked against the manifest's sha256.

    Before any graph is opened, the folder is checked to be closed (`runtime.manifest`): the manifest names only
    plain files inside it, and it holds nothing else but `runtime/` (PolicyError naming the entry otherwise).

    precision: the feature graph to run (`fp32`, or `int8` when exported with --int8); backend: `onnxruntime`
    or `openvino`; threads: intra-op threads per graph (None: one per core); waypoints, conditioning,
    time_base, gripper, camera: as `Policy` takes them (None: the exported ones).
    """
    folder = Path(folder)
    manifest = read_manifest(folder)
    features = load_features(folder, precision, backend, threads)
    encoder, decoder = (manifest.verified(folder, manifest.graphs[name]) for name in ("encoder", "decoder"))
    network = ExportedNetwork(load_graph(str(encoder), backend, threads), load_graph(str(decoder), backend, threads))
    check_network(network, manifest.spec.columns, manifest.spec.n_experts, encoder, decoder)
    return Policy(
        network,
        manifest.spec,
        features,
        waypoints=waypoints,
        conditioning=conditioning,
        time_base=time_base,
        gripper=gripper,
        camera=camera,
    )
