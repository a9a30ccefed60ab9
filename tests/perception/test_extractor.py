import cv2
import numpy as np
import pytest
import torch

from cnep.perception import FeatureExtractor, PerceptionError, compatibility_key
from cnep.perception.calibration import calibrate_random_network, recalibrate_batchnorm
from cnep.perception.constants import ARCHITECTURES, PREPROCESSING
from cnep.perception.network import FeatureNet
from cnep.perception.weights import seeded_features

from .conftest import scene_frames


@pytest.fixture(scope="module")
def calibrated(two_scenes) -> FeatureExtractor:
    extractor = FeatureExtractor("random", backend="eager", threads=1, seed=0)
    extractor.calibrate(np.concatenate(two_scenes))
    return extractor


def _cosine(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return (a * b).sum(-1) / np.linalg.norm(a, axis=-1) / np.linalg.norm(b, axis=-1)


def test_shape_and_dtype(calibrated, two_scenes):
    features = calibrated(two_scenes[0])
    assert features.shape == (4, 1280) and features.dtype == np.float32
    assert np.isfinite(features).all() and (features >= 0).all()  # ReLU6 then average: non-negative


def test_frames_of_any_size(calibrated):
    frames = np.random.default_rng(0).integers(0, 256, (2, 31, 97, 3), dtype=np.uint8)
    assert calibrated(frames).shape == (2, 1280)


def test_batch_size_does_not_change_features(two_scenes):
    frames = np.concatenate(two_scenes)[:5]
    outputs = []
    for batch_size in (1, 2, 5):
        extractor = FeatureExtractor("random", backend="eager", threads=1, batch_size=batch_size)
        extractor.calibrate(frames)
        outputs.append(extractor(frames))
    np.testing.assert_allclose(outputs[0], outputs[1], rtol=1e-4, atol=1e-6)
    np.testing.assert_allclose(outputs[0], outputs[2], rtol=1e-4, atol=1e-6)


def test_uncalibrated_random_weights_refuse_to_extract(two_scenes):
    extractor = FeatureExtractor("random", backend="eager", threads=1)
    assert extractor.needs_calibration
    with pytest.raises(PerceptionError, match="call calibrate"):
        extractor(two_scenes[0])
    with pytest.raises(PerceptionError, match="need calibrate"):
        extractor.prepare()


def test_uncalibrated_features_are_dead_and_calibration_revives_them(two_scenes):
    extractor = FeatureExtractor("random", backend="eager", threads=1)
    with torch.inference_mode():  # look under the hood: the raw network before calibration
        raw = extractor.net(torch.from_numpy(_pixels(two_scenes[0]))).numpy()  # (4, 1280)
    assert np.abs(raw).max() < 1e-5
    extractor.calibrate(np.concatenate(two_scenes))
    assert extractor(two_scenes[0]).std() > 1e-2


def _pixels(frames: np.ndarray) -> np.ndarray:
    from cnep.perception import resize_frames

    return resize_frames(frames)


def _scene_separation(features: list[np.ndarray]) -> tuple[float, float]:
    """(leave-one-out 1-nearest-neighbour scene accuracy, mean within-scene / mean between-scene distance)."""
    x = np.concatenate(features)  # (N, 1280)
    scene = np.repeat(np.arange(len(features)), [len(f) for f in features])  # (N,)
    distance = np.linalg.norm(x[:, None] - x[None], axis=-1)  # (N, N)
    np.fill_diagonal(distance, np.inf)
    accuracy = float(np.mean(scene[distance.argmin(axis=1)] == scene))
    same, off_diagonal = scene[:, None] == scene[None], ~np.eye(len(x), dtype=bool)
    return accuracy, float(distance[same & off_diagonal].mean() / distance[~same].mean())


@pytest.fixture(scope="module")
def six_scenes(two_scenes) -> list[np.ndarray]:
    """Six scenes of 4 frames; frames of one scene differ by noise and shifts of up to 2 pixels."""
    return [*two_scenes, *(scene_frames(k, seed=k) for k in range(2, 6))]


def _pooled_globally(net: torch.nn.Module, frames: np.ndarray) -> np.ndarray:
    """(N, 1280) features of `net`'s convolutions, averaged over the whole map: the calibration's own measure, apart
    from the pooling random weights use (cells keep where things are, so they move with a 2-pixel shift too)."""
    with torch.inference_mode():
        return FeatureNet(net.features, "global").eval()(torch.from_numpy(_pixels(frames))).numpy()


def test_calibrated_random_features_tell_scenes_apart(calibrated, six_scenes):
    accuracy, ratio = _scene_separation([_pooled_globally(calibrated.net, f) for f in six_scenes])  # 2-5 unseen
    assert accuracy == 1.0
    assert ratio < 0.5, ratio


def test_statistics_re_estimation_alone_separates_scenes_worse(calibrated, six_scenes):
    # Why calibration also sets an activation bias: without it the network is chaotic (docs/concepts.md).
    extractor = FeatureExtractor("random", backend="eager", threads=1)
    recalibrate_batchnorm(extractor.net, [_pixels(np.concatenate(six_scenes[:2]))])
    _, plain_ratio = _scene_separation([_pooled_globally(extractor.net, frames) for frames in six_scenes])
    _, biased_ratio = _scene_separation([_pooled_globally(calibrated.net, frames) for frames in six_scenes])
    assert plain_ratio > 1.3 * biased_ratio, (plain_ratio, biased_ratio)


def _tiles() -> tuple[np.ndarray, np.ndarray]:
    """24 frames (60x80) of a 10-pixel tile in one of three colours, 8 each, anywhere on a grey table under a light
    of drawn brightness, with sensor noise; and each frame's colour (24,)."""
    rng = np.random.default_rng(0)
    frames, colours = [], []
    for colour, rgb in enumerate(((200, 40, 40), (40, 170, 70), (220, 200, 50))):
        for _ in range(8):
            image = np.full((60, 80, 3), 150.0 + rng.uniform(-20, 20), dtype=np.float32)
            x, y = (int(v) for v in rng.integers((10, 10), (50, 30)))
            cv2.rectangle(image, (x, y), (x + 10, y + 10), rgb, -1)
            frames.append(np.clip(image + rng.normal(0, 6, image.shape), 0, 255).astype(np.uint8))
            colours.append(colour)
    return np.stack(frames), np.array(colours)


def _colour_read(net: torch.nn.Module, frames: np.ndarray, colours: np.ndarray) -> float:
    """Leave-one-out nearest-neighbour accuracy of the tiles' colour from `net`'s globally pooled features."""
    x = _pooled_globally(net, frames)
    distance = np.linalg.norm(x[:, None] - x[None], axis=-1)
    np.fill_diagonal(distance, np.inf)
    return float(np.mean(colours[distance.argmin(axis=1)] == colours))


def test_low_pass_random_weights_keep_a_small_tile_s_colour_that_torchvision_s_kernels_cancel():
    # Random 3x3 kernels of either sign are high-pass filters: a flat tile's colour cancels (perception.calibration).
    frames, colours = _tiles()
    default = FeatureExtractor("random", backend="eager", threads=1)
    default.calibrate(frames)
    plain = FeatureNet(seeded_features(0), "cells")  # torchvision's kernels, the same seed
    calibrate_random_network(plain, [_pixels(frames)])
    assert _colour_read(default.net, frames, colours) >= 0.75
    assert _colour_read(plain, frames, colours) <= 0.5  # chance is 1/3


def test_only_random_weights_are_calibrated(tmp_path, calibrated, two_scenes):
    calibrated.save_weights(tmp_path / "w.pt")
    with pytest.raises(PerceptionError, match=r"calibrate\(\) is for seeded random weights"):
        FeatureExtractor(tmp_path / "w.pt", backend="eager", threads=1).calibrate(two_scenes[0])


def test_calibration_changes_the_weights_hash_deterministically(two_scenes):
    frames = np.concatenate(two_scenes)
    first, second = (FeatureExtractor("random", backend="eager", threads=1) for _ in range(2))
    before = first.identity["weights_sha256"]
    first.calibrate(frames)
    second.calibrate(frames)
    assert first.identity["weights_sha256"] != before
    assert first.identity == second.identity
    assert first.identity["weights"] == "random:seed=0+calibrated:bias=3.0,frames=8"


def test_identity_names_architecture_weights_preprocessing_and_backend(calibrated):
    identity = calibrated.identity
    assert identity["architecture"] == ARCHITECTURES["cells"]  # seeded random weights pool by cells
    assert identity["feature_dim"] == "1280"
    assert identity["preprocessing"] == PREPROCESSING
    assert identity["backend"] == "eager"
    assert len(identity["weights_sha256"]) == 64
    assert all(isinstance(v, str) for v in identity.values())


def test_compatibility_ignores_backend_but_not_weights(calibrated, two_scenes):
    identity = calibrated.identity
    assert compatibility_key(identity) == compatibility_key({**identity, "backend": "onnxruntime"})
    other = FeatureExtractor("random", backend="eager", threads=1, seed=1)
    other.calibrate(np.concatenate(two_scenes))
    assert compatibility_key(identity) != compatibility_key(other.identity)


def test_saved_calibrated_weights_reload_with_the_same_features(calibrated, two_scenes, tmp_path):
    calibrated.save_weights(tmp_path / "calibrated.pt")
    reloaded = FeatureExtractor(tmp_path / "calibrated.pt", backend="eager", threads=1)
    assert not reloaded.needs_calibration
    assert compatibility_key(reloaded.identity) == compatibility_key(calibrated.identity)
    np.testing.assert_array_equal(reloaded(two_scenes[0]), calibrated(two_scenes[0]))


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"backend": "tensorrt"}, "backend 'tensorrt' is not available"),
        ({"batch_size": 0}, "batch_size must be >= 1"),
        ({"threads": 0}, "threads must be >= 1"),
    ],
)
def test_bad_settings_are_rejected(kwargs, message):
    with pytest.raises(PerceptionError, match=message):
        FeatureExtractor("random", **kwargs)
