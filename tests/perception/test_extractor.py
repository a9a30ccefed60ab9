import numpy as np
import pytest
import torch

from cnep.perception import FeatureExtractor, PerceptionError, compatibility_key
from cnep.perception.calibration import recalibrate_batchnorm
from cnep.perception.constants import ARCHITECTURES, PREPROCESSING
from cnep.perception.network import FeatureNet

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
    assert np.abs(raw).max() < 1e-6
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
    assert first.identity["weights"] == "random:seed=0+calibrated:bias=2.0,frames=8"


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
