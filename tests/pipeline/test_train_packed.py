"""The train stage's packed columns and its ranks' shares of the demonstrations."""

import numpy as np
import pytest

from cnep.models.normaliser import Moments
from cnep.outputs import writing_as
from cnep.pipeline.train.data import load_training_set
from cnep.pipeline.train.packed import pack_columns
from cnep.pipeline.train.parallel import Processes, disjoint, share
from cnep.pipeline.train.presets import resolve_preset
from cnep.recordings import read_trajectory, readers, write_trajectory
from tests.recordings.factories import trajectory_factory


@pytest.fixture(autouse=True)
def as_train():
    """A pack is the train stage's work file, recorded as the command's."""
    with writing_as("train"):
        yield


@pytest.fixture
def with_frames(tmp_path):
    """Three trajectory files that carry camera frames."""
    paths = []
    for k, steps in enumerate((6, 9, 4)):
        paths.append(write_trajectory(tmp_path / f"demo-{k}.mcap", trajectory_factory(steps, frames=True, seed=k)))
    return paths


def test_packing_reads_the_columns_without_parsing_a_frame(with_frames, tmp_path, monkeypatch):
    data = load_training_set(with_frames)
    layout = resolve_preset("wine-glass", data.width, with_frames[0])
    originals = [read_trajectory(p).data for p in with_frames]

    def refuse(*args):
        raise AssertionError("a frame was parsed")

    monkeypatch.setattr(readers, "decode_image", refuse)
    packed = pack_columns(data, [2, 0], layout, tmp_path / "pack")
    assert packed.rows.shape == (4 + 6, 1288) and packed.rows.dtype == np.float32
    assert isinstance(packed.rows, np.memmap) and not packed.rows.flags.writeable
    starts, lengths = packed.span([0, 2])
    assert starts.tolist() == [4, 0] and lengths.tolist() == [6, 4]
    np.testing.assert_array_equal(packed.rows[4:10], originals[0])  # the files' own float32 values
    expected = Moments.of(np.concatenate([originals[2], originals[0]]))
    np.testing.assert_allclose(packed.moments([2, 0]).mean, expected.mean, rtol=1e-12)


def test_a_file_s_views_are_packed_after_its_own_rows_and_trained_on_beside_them(tmp_path):
    plain = trajectory_factory(5, seed=0)
    views = np.random.default_rng(9).normal(size=(2, 4, 1280)).astype(np.float32)
    viewed = trajectory_factory(4, seed=1)
    viewed.views = views
    paths = [write_trajectory(tmp_path / "plain.mcap", plain), write_trajectory(tmp_path / "viewed.mcap", viewed)]
    data = load_training_set(paths)
    assert [f.views for f in data.files] == [0, 2]
    layout = resolve_preset("wine-glass", data.width, paths[0])
    packed = pack_columns(data, [1, 0], layout, tmp_path / "pack")
    assert packed.rows.shape == (4 * 3 + 5, 1288)
    starts, lengths = packed.span([0, 1])  # the files' own rows: what validation reads
    np.testing.assert_array_equal(packed.rows[starts[1] : starts[1] + 4], viewed.data)
    np.testing.assert_array_equal(packed.rows[starts[0] : starts[0] + 5], plain.data)
    starts, lengths = packed.seen([1, 0])  # and every view's: what training reads
    assert lengths.tolist() == [4, 4, 4, 5]
    held = {1: 3}  # a file held at its last step is held in each of its views too (pipeline.train.hold)
    assert packed.held([1, 0], held).tolist() == [3, 3, 3, 0]
    assert packed.held([0, 1], held, views=False).tolist() == [0, 3]
    for k, view in enumerate(views):
        rows = packed.rows[starts[1 + k] : starts[1 + k] + 4]
        np.testing.assert_array_equal(rows[:, :1280], view)  # the view's features
        np.testing.assert_array_equal(rows[:, 1280:], viewed.data[:, 1280:])  # the demonstration's motion
    expected = Moments.of(np.concatenate([packed.rows[a : a + n] for a, n in zip(starts, lengths)]))
    np.testing.assert_allclose(packed.moments([1, 0]).mean, expected.mean, rtol=1e-12)


def test_a_pack_is_written_once_and_redone_when_a_file_changes(with_frames, tmp_path, monkeypatch):
    data = load_training_set(with_frames)
    layout = resolve_preset("motion", data.width, with_frames[0])
    first = pack_columns(data, [0, 1], layout, tmp_path / "pack")
    assert first.rows.shape == (15, 8)
    reads = []
    monkeypatch.setattr("cnep.pipeline.train.packed.read_trajectory", lambda *a, **k: reads.append(a) or 1 / 0)
    again = pack_columns(data, [0, 1], layout, tmp_path / "pack")  # read from the pack, no file read
    assert reads == [] and again.digests == first.digests
    write_trajectory(with_frames[1], trajectory_factory(9, frames=True, seed=7))  # same steps, other values
    with pytest.raises(ZeroDivisionError):  # its sha256 changed: the files are read again
        pack_columns(data, [0, 1], layout, tmp_path / "pack")


@pytest.mark.parametrize("world_size", [1, 2, 3, 7])
def test_the_ranks_shares_are_a_partition_that_every_rank_derives_alone(world_size):
    indices = [4, 9, 0, 3, 7, 1, 8]
    shares = [share(indices, Processes(rank, world_size)) for rank in range(world_size)]
    assert sorted(i for part in shares for i in part) == sorted(indices)  # each demonstration on one rank
    assert all(part for part in shares) and disjoint(indices, Processes(0, world_size))
    assert shares == [share(list(indices), Processes(rank, world_size)) for rank in range(world_size)]


def test_fewer_demonstrations_than_ranks_are_every_rank_s():
    assert not disjoint([5], Processes(0, 2))
    assert share([5], Processes(0, 2)) == share([5], Processes(1, 2)) == [5]
