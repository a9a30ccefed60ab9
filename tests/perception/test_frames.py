import cv2
import numpy as np
import pytest

from cnep.perception import PerceptionError, decode_image, resize_frames


def _jpeg(rgb: np.ndarray) -> bytes:
    ok, data = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 95])
    assert ok
    return data.tobytes()


def test_decode_returns_rgb_in_channel_order():
    red = np.zeros((30, 40, 3), dtype=np.uint8)
    red[..., 0] = 200  # R
    decoded = decode_image(_jpeg(red))
    assert decoded.shape == (30, 40, 3) and decoded.dtype == np.uint8
    assert decoded[..., 0].mean() > 180 and decoded[..., 2].mean() < 20


@pytest.mark.parametrize("data", [b"", b"not a jpeg at all", b"\xff\xd8\xff\xe0" + bytes(50)])
def test_undecodable_bytes_raise_perception_error(data):
    with pytest.raises(PerceptionError, match="cannot decode image"):
        decode_image(data)


def test_truncated_jpeg_raises_perception_error():
    data = _jpeg(np.full((32, 32, 3), 90, dtype=np.uint8))
    with pytest.raises(PerceptionError, match="cannot decode image"):
        decode_image(data[: len(data) // 2])


@pytest.mark.parametrize("shape", [(2, 48, 64, 3), (1, 480, 640, 3), (3, 100, 30, 3), (1, 224, 224, 3)])
def test_resize_any_size_to_224(shape):
    frames = np.random.default_rng(0).integers(0, 256, shape, dtype=np.uint8)
    out = resize_frames(frames)
    assert out.shape == (shape[0], 224, 224, 3) and out.dtype == np.uint8


def test_resize_keeps_a_flat_colour():
    frames = np.full((1, 48, 64, 3), (10, 120, 250), dtype=np.uint8)
    assert (resize_frames(frames) == np.array((10, 120, 250), dtype=np.uint8)).all()


@pytest.mark.parametrize(
    "frames, message",
    [
        (np.zeros((2, 8, 8, 3), dtype=np.float32), "uint8"),
        (np.zeros((8, 8, 3), dtype=np.uint8), r"\(N, H, W, 3\)"),
        (np.zeros((2, 8, 8, 4), dtype=np.uint8), r"\(N, H, W, 3\)"),
        (np.zeros((2, 0, 8, 3), dtype=np.uint8), r"\(N, H, W, 3\)"),
        ([[1, 2, 3]], "uint8"),
    ],
)
def test_bad_frames_are_rejected_with_the_rule(frames, message):
    with pytest.raises(PerceptionError, match=message):
        resize_frames(frames)
