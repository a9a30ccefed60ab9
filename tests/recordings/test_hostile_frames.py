"""A demonstration's camera frame that declares more pixels than a frame may have is refused before it is decoded (a
few hundred bytes of JPEG can declare gigabytes), in one line and exit 2 from the commands that decode frames."""

import math
import tracemalloc

import pytest

from cnep.pipeline.cli.main import main
from cnep.recordings import RecordingError, read_demonstration, validation, write_demonstration
from cnep.recordings.constants import MAX_FRAME_PIXELS
from cnep.recordings.validation import jpeg_size
from tests.recordings.factories import declaring, demonstration_factory


@pytest.fixture
def bombed(tmp_path, monkeypatch):
    """A demonstration whose frame 3 declares 20000 x 20000 pixels (1.2 GB as RGB) in under a kilobyte, written as
    another writer would (cnep's refuses it)."""
    demo = demonstration_factory(6, frame_size=16)
    with monkeypatch.context() as patched:
        patched.setattr(validation, "MAX_FRAME_PIXELS", 2**32)
        demo.frames[3] = declaring(demo.frames[3], 20000, 20000)
        assert jpeg_size(demo.frames[3]) == (20000, 20000)
        return write_demonstration(tmp_path / "bomb.mcap", demo)


def test_a_frame_declaring_too_many_pixels_is_refused_by_the_reader(bombed):
    tracemalloc.start()
    try:
        with pytest.raises(
            RecordingError, match=f"{bombed}: .*frame 3 is not a decodable JPEG .*declares 20000x20000 pixels"
        ):
            read_demonstration(bombed)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 16 << 20, peak


def test_extract_refuses_it_in_one_line(bombed, tmp_path, capsys):
    capsys.readouterr()
    assert main(["-q", "extract", str(bombed), "--out", str(tmp_path / "out"), "--weights", "random"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(bombed) in err[0] and "frame 3 is not a decodable JPEG (it declares" in err[0], err


def test_a_frame_of_the_largest_size_passes_the_reader(tmp_path):
    side = math.isqrt(MAX_FRAME_PIXELS)
    demo = demonstration_factory(2, frame_size=16)
    demo.frames[0] = declaring(demo.frames[0], side, side)
    path = write_demonstration(tmp_path / "large.mcap", demo)
    assert read_demonstration(path).frames[0] == demo.frames[0]


def test_cnep_writes_no_such_frame(tmp_path):
    demo = demonstration_factory(6, frame_size=16)
    demo.frames[3] = declaring(demo.frames[3], 20000, 20000)
    with pytest.raises(RecordingError, match=r"\(step 3\): .*is not a decodable JPEG .*declares 20000x20000 pixels"):
        write_demonstration(tmp_path / "bomb.mcap", demo)
    assert not (tmp_path / "bomb.mcap").exists()
