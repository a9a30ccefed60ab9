import numpy as np
import pytest
import torch

from cnep.models.cnep import CNEP
from cnep.models.sampler import TrajectoryStack, sample_batch
from cnep.models.schedule import FIRST_READ_SHARE
from tests.models.factories import tiny_config


def _stack(lengths=(5, 12, 30)):
    cfg = tiny_config(n_experts=2)
    model = CNEP(cfg)
    width = cfg.columns.width
    # column 0 of step k holds k, so a sampled value tells which step it came from
    trajs = [
        np.column_stack([np.arange(T), np.full((T, width - 1), i)]).astype(np.float32) for i, T in enumerate(lengths)
    ]
    return TrajectoryStack(trajs, model), lengths


def test_batches_have_the_documented_shapes_and_valid_masks():
    stack, lengths = _stack()
    g = torch.Generator().manual_seed(0)
    b = sample_batch(stack, 64, n_max=10, m_max=7, g=g)
    assert b.obs.shape == (64, 10, 3) and b.obs_mask.shape == (64, 10)
    assert b.query.shape == (64, 7, 2) and b.target.shape == (64, 7, 2) and b.target_mask.shape == (64, 7)
    assert b.obs_mask[:, 0].all() and b.target_mask[:, 0].all()  # n, m >= 1
    assert (b.obs_mask.sum(1) <= 10).all()


def test_observations_are_distinct_valid_steps_with_normalised_time():
    stack, lengths = _stack()  # the model's normaliser is unfitted (identity), so values stay raw
    b = sample_batch(stack, 200, n_max=10, m_max=10, g=torch.Generator().manual_seed(1))
    for i in range(200):
        mask = b.obs_mask[i]
        t, step, traj = b.obs[i, mask, 0], b.obs[i, mask, 1], b.obs[i, mask, 2]
        T = lengths[int(traj[0])]
        assert (traj == traj[0]).all()  # one trajectory per sample
        assert (step >= 0).all() and (step < T).all()
        assert len(torch.unique(step)) == len(step)  # without replacement
        torch.testing.assert_close(t, step / (T - 1))


def test_short_trajectories_cap_the_number_of_points():
    stack, _ = _stack(lengths=(3, 3))
    b = sample_batch(stack, 50, n_max=10, m_max=10, g=torch.Generator().manual_seed(2))
    assert (b.obs_mask.sum(1) <= 3).all() and (b.target_mask.sum(1) <= 3).all()


def test_same_generator_seed_same_batch():
    stack, _ = _stack()
    a = sample_batch(stack, 16, 10, 10, torch.Generator().manual_seed(5))
    b = sample_batch(stack, 16, 10, 10, torch.Generator().manual_seed(5))
    torch.testing.assert_close(a.obs, b.obs)
    torch.testing.assert_close(a.target, b.target)


def test_observation_noise_moves_the_observed_values_only():
    stack, _ = _stack()
    clean = sample_batch(stack, 32, 10, 10, torch.Generator().manual_seed(6))
    noisy = sample_batch(stack, 32, 10, 10, torch.Generator().manual_seed(6), obs_noise=0.5)
    torch.testing.assert_close(noisy.obs[..., 0], clean.obs[..., 0])  # the times
    for name in ("obs_mask", "query", "target", "target_mask"):
        torch.testing.assert_close(getattr(noisy, name), getattr(clean, name))
    shift = (noisy.obs[..., 1:] - clean.obs[..., 1:])[clean.obs_mask]  # (real points, obs_dim)
    assert 0.4 < float(shift.std()) < 0.6 and abs(float(shift.mean())) < 0.1


def test_first_steps_contexts_are_a_trajectorys_first_k_steps_in_the_share_asked():
    stack, lengths = _stack(lengths=(3, 12, 30))
    b = sample_batch(stack, 2000, 10, 10, torch.Generator().manual_seed(7), first_steps=(0.25, 4))
    first = 0
    ks = set()
    for i in range(2000):
        mask = b.obs_mask[i]
        step = b.obs[i, mask, 1]
        T = lengths[int(b.obs[i, mask, 2][0])]
        k = len(step)
        if k <= min(4, T) and torch.equal(step, torch.arange(k, dtype=step.dtype)):
            first += 1
            ks.add(k)
    # a random context is 0, 1, ... by chance only rarely (a 3-step trajectory's contexts most often)
    assert 0.22 < first / 2000 < 0.32 and ks == {1, 2, 3, 4}
    clean = sample_batch(stack, 2000, 10, 10, torch.Generator().manual_seed(7))
    torch.testing.assert_close(b.target, clean.target)  # the targets stay random steps
    assert (b.obs_mask.sum(1) <= torch.tensor(lengths)[b.obs[:, 0, 2].long()]).all()


def test_no_first_steps_draws_the_batches_drawn_without_them():
    stack, _ = _stack()
    g, h = torch.Generator().manual_seed(8), torch.Generator().manual_seed(8)
    for _ in range(3):  # the generator's state after each batch too
        a = sample_batch(stack, 16, 10, 10, g, first_steps=(0.0, 4))
        b = sample_batch(stack, 16, 10, 10, h)
        torch.testing.assert_close(a.obs, b.obs)


def test_online_contexts_are_the_deployed_policys_set_at_a_step_and_target_the_steps_after_it():
    stack, lengths = _stack(lengths=(1, 12, 30))
    b = sample_batch(stack, 3000, 10, 6, torch.Generator().manual_seed(9), online=(0.5, 10, 2))
    assert b.obs.shape[1] == 12  # anchors + window columns, more than n_max
    online, reached, first = 0, set(), 0
    for i in range(3000):
        step, T = b.obs[i, b.obs_mask[i], 1], lengths[int(b.obs[i, b.obs_mask[i], 2][0])]
        target = (b.query[i, b.target_mask[i], 0] * max(T - 1, 1)).round()  # time = step / (T - 1)
        k = int(step.max())
        deployed = torch.tensor([*range(min(2, k + 1)), *range(max(2, k - 9), k + 1)], dtype=step.dtype)
        if T > 1 and torch.equal(step, deployed) and (target > k).all():
            online += 1
            first += k == 0
            reached.add(k)
            assert len(target) <= 6 and (target < T).all()
        if T == 1:  # a one-step trajectory: its step observed and targeted
            assert step.tolist() == [0] and target.tolist() == [0]
    # half the samples of the two longer trajectories (a random context is such a set with later targets rarely)
    assert 0.28 < online / 3000 < 0.4 and reached == set(range(29))
    # the first read, a FIRST_READ_SHARE of them beside its share of the uniform draw
    assert FIRST_READ_SHARE < first / online < FIRST_READ_SHARE + 0.15
    assert (b.obs_mask.sum(1) <= 12).all()


def test_no_online_contexts_draws_the_batches_drawn_without_them():
    stack, _ = _stack()
    g, h = torch.Generator().manual_seed(10), torch.Generator().manual_seed(10)
    for _ in range(3):
        a = sample_batch(stack, 16, 10, 10, g, online=(0.0, 10, 1))
        b = sample_batch(stack, 16, 10, 10, h)
        torch.testing.assert_close(a.obs, b.obs)
        torch.testing.assert_close(a.target, b.target)


def test_a_demonstration_is_every_step_of_a_short_one_and_evenly_spaced_steps_of_a_long_one():
    stack, lengths = _stack(lengths=(5, 12, 30))  # predicted column 0 of trajectory i holds i
    traj = torch.tensor([0, 2, 1])
    query, target, mask = stack.demonstration(traj, most=8)
    assert query.shape == (3, 8, 2) and target.shape == (3, 8, 2) and mask.shape == (3, 8)
    assert mask.sum(1).tolist() == [5, 8, 8]
    steps = (query[..., 0] * torch.tensor([4.0, 29.0, 11.0]).unsqueeze(1)).round()  # time = step / (T - 1)
    assert steps[0, :5].tolist() == [0, 1, 2, 3, 4]  # all of the 5 steps
    assert steps[1].tolist() == [0, 4, 8, 12, 17, 21, 25, 29]  # 8 of 30, first to last
    assert steps[2].tolist() == [0, 2, 3, 5, 6, 8, 9, 11]  # 8 of 12
    assert (target[..., 0] == traj.unsqueeze(1)).all()  # each sample's own trajectory


def test_each_sample_names_its_trajectory():
    stack, lengths = _stack()
    b = sample_batch(stack, 100, n_max=10, m_max=10, g=torch.Generator().manual_seed(3))
    assert torch.equal(b.target[:, 0, 0].long(), b.trajectory)  # predicted column 0 of trajectory i holds i


def test_a_stack_of_packed_rows_in_a_memory_map_draws_the_same_batches(tmp_path):
    lengths = (5, 12, 30)
    cfg = tiny_config(n_experts=2)
    model = CNEP(cfg)
    rng = np.random.default_rng(0)
    trajs = [rng.standard_normal((T, cfg.columns.width)).astype(np.float32) for T in lengths]
    model.normaliser.fit(trajs)
    np.save(tmp_path / "rows.npy", np.concatenate(trajs))
    packed = TrajectoryStack.from_rows(np.load(tmp_path / "rows.npy", mmap_mode="r"), [0, 5, 17], lengths, model)
    listed = TrajectoryStack(trajs, model)
    a = sample_batch(listed, 32, n_max=10, m_max=40, g=torch.Generator().manual_seed(2), obs_noise=0.1)
    b = sample_batch(packed, 32, n_max=10, m_max=40, g=torch.Generator().manual_seed(2), obs_noise=0.1)
    for field in ("obs", "obs_mask", "query", "target", "target_mask", "trajectory"):
        assert torch.equal(getattr(a, field), getattr(b, field)), field
    every = torch.arange(3)
    assert all(torch.equal(x, y) for x, y in zip(listed.demonstration(every), packed.demonstration(every)))


def test_steps_past_a_trajectory_end_read_as_zero_rows_normalised():
    stack, lengths = _stack()
    stack.loc, stack.scale = torch.tensor([1.0, 2.0, 3.0]), torch.tensor([2.0, 4.0, 8.0])
    values = stack.values(torch.tensor([0]), torch.tensor([[4, 5, 29]]), ((0, 3),))  # trajectory 0 has 5 steps
    assert torch.equal(values[0, 0], (torch.tensor([4.0, 0.0, 0.0]) - stack.loc) / stack.scale)
    assert torch.equal(values[0, 1:], (-stack.loc / stack.scale).expand(2, 3))


def test_a_held_trajectory_reads_its_last_row_past_its_end_and_its_times_run_over_the_held_steps():
    """A trajectory held at its last row, as pipeline.train.hold holds one that stops as its gripper changes."""
    model = CNEP(tiny_config(n_experts=2))
    rows = [np.arange(4 * 5, dtype=np.float32).reshape(4, 5), np.ones((3, 5), np.float32)]
    stack = TrajectoryStack(rows, model, held=[2, 0])
    assert stack.lengths.tolist() == [6, 3] and stack.longest == 6
    traj, steps = torch.tensor([0, 1]), torch.tensor([[3, 4, 5], [1, 2, 3]])
    read = stack.values(traj, steps, [(0, 5)]) * stack.scale + stack.loc  # back to the rows' own values
    torch.testing.assert_close(read[0], torch.from_numpy(rows[0][[3, 3, 3]]))  # the held steps: its last row
    torch.testing.assert_close(read[1, :2], torch.from_numpy(rows[1][[1, 2]]))
    assert (stack.values(traj, steps, [(0, 5)])[1, 2] == 0).all()  # past the unheld one's end: zeros, as before
    torch.testing.assert_close(stack.times(traj, steps)[0], torch.tensor([3, 4, 5]) / 5)
    with pytest.raises(ValueError, match="held must give 2 step counts"):
        TrajectoryStack(rows, model, held=[1])
