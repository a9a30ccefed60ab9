import numpy as np
import pytest

from cnep.models.evaluation import (
    DECISIVE,
    NOISE,
    _decisive,
    _separable_partners,
    commitment,
    commitment_scores,
    heldout_queries,
    paper_queries,
    score,
    shared_queries,
    within_mode_band,
)
from cnep.models.synthetic import SETS, make_set


@pytest.mark.parametrize("name", sorted(SETS))
def test_sets_have_disjoint_splits_and_the_documented_sizes(name):
    ds = make_set(name, seed=0)
    _, n_modes, (n_train, n_val, n_test) = SETS[name]
    assert ds.train.shape[0] == n_train and ds.val.shape[0] == n_val and ds.test.shape[0] == n_test
    assert ds.n_modes == n_modes and ds.train.ndim == 3 and ds.train.shape[2] == 1
    assert np.isfinite(ds.train).all()
    for other in (ds.val, ds.test):  # no validation or test demonstration is a training one
        gaps = np.abs(ds.train[:, None] - other[None]).max(axis=(2, 3))
        assert gaps.min() > 0


def test_same_seed_same_set():
    a, b = make_set("bimodal", seed=3), make_set("bimodal", seed=3)
    np.testing.assert_array_equal(a.train, b.train)
    assert not np.array_equal(a.train, make_set("bimodal", seed=4).train)


def test_paper_queries_condition_near_a_crossing_and_at_the_end():
    ds = make_set("bimodal", seed=0)
    queries = paper_queries(ds.train, ds.train_modes, n=20, seed=0)
    for q in queries:
        assert q.obs_t[1] == 1.0 and 0 < q.obs_t[0] < 1
        step = round(q.obs_t[0] * (ds.steps - 1))
        means = [ds.train[ds.train_modes == k, step, 0].mean() for k in range(2)]
        assert abs(means[0] - means[1]) < 0.3  # the two modes come close there
        # the ground truth is the training demonstration nearest to the two conditioning points
        dist = (ds.train[:, step, 0] - q.obs_y[0, 0]) ** 2 + (ds.train[:, -1, 0] - q.obs_y[1, 0]) ** 2
        np.testing.assert_array_equal(q.truth, ds.train[dist.argmin()])


def test_nearest_demo_scores_zero_and_the_wrong_mode_scores_badly():
    ds = make_set("bimodal", seed=0)
    queries = paper_queries(ds.train, ds.train_modes, n=10, seed=1)

    def lookup(obs_t, obs_y, query_t):
        steps = np.round(obs_t * (ds.steps - 1)).astype(int)
        return ds.train[((ds.train[:, steps] - obs_y) ** 2).sum((1, 2)).argmin()]

    def other_mode(obs_t, obs_y, query_t):
        truth = lookup(obs_t, obs_y, query_t)
        mode = ds.train_modes[np.flatnonzero((ds.train == truth).all(axis=(1, 2)))[0]]
        return ds.train[np.flatnonzero(ds.train_modes != mode)[0]]

    good = score(lookup, queries, ds.train, ds.train_modes)
    bad = score(other_mode, queries, ds.train, ds.train_modes)
    assert good["mse"] == 0 and good["mode_accuracy"] == 1
    assert bad["mse"] > 0.1 and bad["mode_accuracy"] == 0


def test_heldout_queries_come_from_unseen_demonstrations():
    ds = make_set("multimodal", seed=0)
    queries = heldout_queries(ds.train, ds.train_modes, ds.test, ds.test_modes, n=15, seed=0)
    for q in queries:
        i = np.flatnonzero((ds.test == q.truth).all(axis=(1, 2)))
        assert len(i) == 1 and ds.test_modes[i[0]] == q.mode
        np.testing.assert_array_equal(q.obs_y[1], q.truth[-1])


def test_modes_that_end_at_the_same_place_are_never_paired():
    ds = make_set("multimodal", seed=0)  # modes 2 and 3 both end near 0; 0 and 1 end elsewhere
    partners = _separable_partners(ds.train, ds.train_modes)
    assert 3 not in partners[2] and 2 not in partners[3]
    assert set(partners[0]) == {1, 2, 3} and set(partners[1]) == {0, 2, 3}


def test_every_query_names_its_mode_decisively():
    ds = make_set("multimodal", seed=2)  # seed 2 draws 5 undecided paper queries among its first 55
    paper = paper_queries(ds.train, ds.train_modes, n=50, seed=2)
    heldout = heldout_queries(ds.train, ds.train_modes, ds.test, ds.test_modes, n=50, seed=2)
    assert len(paper) == len(heldout) == 50
    for q in paper + heldout:
        steps = np.round(q.obs_t * (ds.steps - 1)).astype(int)
        dist = ((ds.train[:, steps] - q.obs_y) ** 2).sum((1, 2))
        own, other = dist[ds.train_modes == q.mode].min(), dist[ds.train_modes != q.mode].min()
        assert other >= DECISIVE * own
        assert (other - own) / (2 * (NOISE * np.ptp(ds.train)) ** 2) >= np.log(DECISIVE)  # log likelihood ratio


def test_points_halfway_between_two_modes_are_not_decisive():
    ds = make_set("multimodal", seed=0)
    steps = np.array([54, ds.steps - 1])  # modes 1, 2 and 3 meet near step 54; 2 and 3 end together
    two, three = ds.train[ds.train_modes == 2][0], ds.train[ds.train_modes == 3][0]
    between = 0.5 * (two[steps] + three[steps])
    assert not _decisive(ds.train, ds.train_modes, steps, between, 2)
    assert not _decisive(ds.train, ds.train_modes, steps, between, 3)
    away = np.array([140, ds.steps - 1])  # mode 3 is near 0 here, mode 2 near 0.6
    assert _decisive(ds.train, ds.train_modes, away, three[away], 3)  # on a demonstration of mode 3


def test_points_that_two_modes_pass_within_the_noise_are_not_decisive():
    ds = make_set("multimodal", seed=0)
    steps = np.array([54, ds.steps - 1])
    three = ds.train[ds.train_modes == 3][0]
    dist = ((ds.train[:, steps] - three[steps]) ** 2).sum((1, 2))
    assert dist[ds.train_modes == 3].min() == 0  # infinitely nearer by the ratio alone
    assert np.sqrt(dist[ds.train_modes == 2].min()) < NOISE * np.ptp(
        ds.train
    )  # but a mode-2 demo passes within the noise
    assert not _decisive(ds.train, ds.train_modes, steps, three[steps], 3)


def crossing_pool(T: int = 21) -> tuple[np.ndarray, np.ndarray]:
    """Three modes of 4 demonstrations each: y = t and y = 1 - t cross at t = 0.5; y = 2 never meets them."""
    t = np.linspace(0, 1, T)
    offsets = np.array([-0.02, -0.01, 0.01, 0.02])
    shapes = [t, 1 - t, np.full(T, 2.0)]
    demos = np.stack([shape + o for shape in shapes for o in offsets])[..., None]  # (12, T, 1)
    return demos, np.repeat(np.arange(3), 4)


def test_within_mode_band_is_three_within_mode_stds():
    demos, modes = crossing_pool()
    assert within_mode_band(demos, modes) == pytest.approx(3 * np.std([-0.02, -0.01, 0.01, 0.02]))


def test_shared_queries_find_the_crossing_and_name_the_modes_that_share_it():
    demos, modes = crossing_pool()
    queries = shared_queries(demos, modes)
    assert len(queries) == 1  # the third mode meets neither, and the first two meet once
    q = queries[0]
    assert q.obs_t.tolist() == [0.5] and q.obs_y.shape == (1, 1) and q.obs_y[0, 0] == pytest.approx(0.5)
    assert q.modes == (0, 1)


def test_shared_queries_find_a_shared_start_and_a_shared_stretch_once():
    T = 41
    t = np.linspace(0, 1, T)
    # modes 0 and 1 start together at 0 and part; modes 0 and 2 share the stretch t in [0.4, 0.6] (gap 0)
    shapes = [np.sin(np.pi * t), -np.sin(np.pi * t), np.where(np.abs(t - 0.5) <= 0.1, np.sin(np.pi * t), 3.0)]
    demos = np.stack([s + o for s in shapes for o in (-0.01, 0.01)])[..., None]
    modes = np.repeat(np.arange(3), 2)
    steps = {(round(q.obs_t[0] * (T - 1)), q.modes) for q in shared_queries(demos, modes)}
    assert (0, (0, 1)) in steps and (T - 1, (0, 1)) in steps  # shared start and end
    assert sum(1 for s, m in steps if m == (0, 2)) == 1  # one query for the whole shared stretch


def test_commitment_scores_a_demonstration_valid_and_the_average_invalid():
    demos, modes = crossing_pool()
    q = shared_queries(demos, modes)
    T = demos.shape[1]
    average = 0.5 * (demos[modes == 0].mean(0) + demos[modes == 1].mean(0))  # what a blending model makes
    far_mode = demos[8]  # a real demonstration, but of a mode that never passes the point
    generated = np.stack([demos[1], demos[3] + 0.03, average, far_mode, np.full((T, 1), np.nan)])
    s = commitment_scores(generated, q * 5, demos, modes)
    assert s["valid"].tolist() == [True, True, False, False, False]
    np.testing.assert_allclose(s["mse"][:2], [0.0, 0.0009])  # nearest demonstration: itself, then 0.03 off
    np.testing.assert_allclose(s["max_deviation"][:2], [0.0, 0.03])
    assert s["max_deviation"][2] > 0.4 and s["max_deviation"][3] == 0.0
    assert s["mode"].tolist() == [0, 0, 0, 2, -1]
    # judged against the nearest demonstration: 0.06 above the lowest one is 0.02 from the highest (band 0.047)
    assert commitment_scores(np.stack([demos[0] + 0.06]), q, demos, modes)["valid"].tolist() == [True]
    assert commitment_scores(np.stack([demos[3] + 0.06]), q, demos, modes)["valid"].tolist() == [False]


def test_commitment_of_a_method_counts_valid_queries_and_failures():
    demos, modes = crossing_pool()
    q = shared_queries(demos, modes)
    result = commitment(lambda t, y, qt: np.interp(qt, np.linspace(0, 1, 21), demos[5, :, 0])[:, None], q, demos, modes)
    assert result["valid"] == 1.0 and result["queries"] == 1 and result["failures"] == 0
    assert result["band"] == pytest.approx(within_mode_band(demos, modes))
    nan = commitment(lambda t, y, qt: np.full((len(qt), 1), np.nan), q, demos, modes)
    assert nan["valid"] == 0.0 and nan["failures"] == 1


@pytest.mark.parametrize("name", ["bimodal", "multimodal", "multimodal6"])
def test_commitment_band_accepts_every_shared_mode_and_rejects_their_average(name):
    ds = make_set(name, seed=0)
    queries = shared_queries(ds.train, ds.train_modes)
    means = np.stack([ds.train[ds.train_modes == k].mean(0) for k in range(ds.n_modes)])  # (K, T, 1)
    for q in queries:
        assert len(q.modes) >= 2
        committed = commitment_scores(means[list(q.modes)], [q] * len(q.modes), ds.train, ds.train_modes)
        assert committed["valid"].all() and committed["mode"].tolist() == list(q.modes)
        average = commitment_scores(means[list(q.modes)].mean(0)[None], [q], ds.train, ds.train_modes)
        assert not average["valid"].any()
