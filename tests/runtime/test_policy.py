"""The runtime's Policy on a numpy network: LeRobot's interface, the time base, the conditioning set, input checks."""

from dataclasses import replace

import numpy as np
import pytest

from cnep.runtime import (
    IMAGE_KEY_PREFIX,
    STATE_KEY,
    STATE_NAMES,
    TIMESTAMP_KEY,
    Columns,
    Conditioner,
    ConditioningPolicy,
    Policy,
    PolicyError,
    PolicySpec,
    TimeBase,
)
from cnep.runtime.constants import GRIPPER_DEVIATIONS
from tests.runtime.fakes import (
    EXPERTS,
    FEATURES,
    TIME_BASE,
    WIDTH,
    LinearNetwork,
    ScriptedNetwork,
    camera_network,
    camera_spec,
    mean_colour_features,
)

CAMERA = IMAGE_KEY_PREFIX + "front"


def state(rng: np.random.Generator) -> np.ndarray:
    """(8,) float32: x y z (m), a unit quaternion xyzw, the gripper."""
    quat = rng.normal(size=4)
    return np.r_[rng.normal(size=3), quat / np.linalg.norm(quat), rng.normal()].astype(np.float32)


def with_state(obs: dict, **values: float) -> dict:
    """`obs` with state entries (by STATE_NAMES) set to `values`."""
    changed = np.array(obs[STATE_KEY], dtype=np.float64)
    for name, value in values.items():
        changed[STATE_NAMES.index(name)] = value
    return {**obs, STATE_KEY: changed}


def observation(k: int, seed: int = 0, time_s: float | None = None) -> dict:
    rng = np.random.default_rng(seed * 1000 + k)
    obs = {
        CAMERA: rng.integers(0, 256, size=(48, 64, 3), dtype=np.uint8),
        STATE_KEY: state(rng),
    }
    if time_s is not None:
        obs[TIMESTAMP_KEY] = time_s
    return obs


def make_policy(**options) -> Policy:
    return Policy(camera_network(), camera_spec(), mean_colour_features, **options)


def test_select_action_is_the_first_waypoint_of_the_step_and_keeps_a_batch_dimension():
    a, b = make_policy(waypoints=4), make_policy(waypoints=4)
    for k in range(5):
        obs = observation(k, time_s=0.1 * k)
        result = a.step(obs)
        assert result.waypoints.shape == result.std.shape == (4, 4) and result.times_s.shape == (4,)
        np.testing.assert_allclose(result.times_s, 0.1 * k + 0.1 * np.arange(1, 5))
        batched = {CAMERA: obs[CAMERA][None], STATE_KEY: obs[STATE_KEY][None], TIMESTAMP_KEY: obs[TIMESTAMP_KEY]}
        action = b.select_action(batched)
        assert action.shape == (1, 4)
        np.testing.assert_array_equal(action[0], result.waypoints[0])
    assert a.action_names == ("x", "y", "z", "gripper")


def test_the_policy_conditions_like_the_conditioner_on_the_rows_it_assembles():
    """The policy's row: the frame's features, then the state; its phase: seconds / the time base's duration."""
    spec, network = camera_spec(), camera_network()
    policy = Policy(network, spec, mean_colour_features, waypoints=3)
    reference = Conditioner(camera_network(), spec.columns, spec.conditioning)
    from cnep.runtime.frames import pixel_buffer, resize_frame

    pixels = pixel_buffer(1)
    for k in range(12):
        obs = observation(k, time_s=0.25 * k)
        result = policy.step(obs)
        row = np.concatenate([mean_colour_features(resize_frame(obs[CAMERA], pixels[0])[None])[0], obs[STATE_KEY]])
        assert row.shape == (WIDTH,)
        times = np.clip((0.25 * k + 0.1 * np.arange(1, 4)) / 2.0, 0, 1)
        gate, expert, switch, mean, std = reference.step(row, min(0.25 * k / 2.0, 1.0), times)
        np.testing.assert_allclose(result.gate, gate, rtol=1e-6)
        np.testing.assert_allclose(result.waypoints, mean, rtol=1e-5, atol=1e-6)
        assert result.expert == expert and (result.switch is None) == (switch is None)
        assert result.t == pytest.approx(min(0.25 * k / 2.0, 1.0))


def test_without_a_timestamp_step_k_is_at_k_periods():
    a, b = make_policy(), make_policy()
    for k in range(6):
        obs = observation(k)
        ra, rb = a.step(obs), b.step({**obs, TIMESTAMP_KEY: 0.1 * k})
        assert ra.time_s == pytest.approx(0.1 * k)
        np.testing.assert_allclose(ra.waypoints, rb.waypoints, rtol=1e-6)


def test_reset_starts_a_new_episode():
    policy = make_policy()
    first = [policy.step(observation(k, time_s=k * 0.1)).gate for k in range(4)]
    with pytest.raises(PolicyError, match="does not move forward"):
        policy.step(observation(0, time_s=0.0))
    policy.reset()
    again = [policy.step(observation(k, time_s=k * 0.1)).gate for k in range(4)]
    np.testing.assert_array_equal(np.array(first), np.array(again))


def test_reset_with_a_seed_repeats_the_sampled_first_expert():
    sample = ConditioningPolicy(first_expert="sample", switch_margin=0.5)

    def firsts(policy: Policy, seeds) -> list[int]:
        found = []
        for seed in seeds:
            policy.reset(seed)
            found.append(policy.step(observation(0)).expert)
        return found

    policy = Policy(ScriptedNetwork([[0.4, 0.35, 0.25]]), camera_spec(), mean_colour_features, conditioning=sample)
    drawn = firsts(policy, range(40))
    assert len(set(drawn)) == EXPERTS  # the draws follow the gate, not its argmax
    assert firsts(policy, range(40)) == drawn  # the same seeds, the same draws
    unseeded = [Policy(ScriptedNetwork([[0.4, 0.35, 0.25]]), camera_spec(), mean_colour_features, conditioning=sample)]
    unseeded.append(
        Policy(ScriptedNetwork([[0.4, 0.35, 0.25]]), camera_spec(), mean_colour_features, conditioning=sample)
    )
    assert firsts(unseeded[0], [None] * 20) == firsts(unseeded[1], [None] * 20)  # one generator, seeded when made


def test_a_switch_is_reported_when_the_active_expert_changes():
    policy = make_policy(conditioning=ConditioningPolicy(window=1, anchors=0))
    results = [policy.step(observation(k, seed=3)) for k in range(40)]
    experts = [r.expert for r in results]
    changes = [k for k in range(1, 40) if experts[k] != experts[k - 1]]
    assert changes, "random observations with a window of 1 should move a confident gate"
    assert [r.step for r in results if r.switch is not None] == changes
    for k in changes:
        s = results[k].switch
        assert (s.from_expert, s.to_expert) == (experts[k - 1], experts[k]) and s.gate.shape == (EXPERTS,)
        assert s.timestamp_ns == round(results[k].time_s * 1e9)


BAD = [
    ("not a dict", lambda o: [o[STATE_KEY]], "dict"),
    ("no state", lambda o: {CAMERA: o[CAMERA]}, "no 'observation.state'"),
    ("state shape", lambda o: {**o, STATE_KEY: np.zeros(7)}, r"\(8,\) array"),
    ("state dtype", lambda o: {**o, STATE_KEY: np.array(["a"] * 8)}, "dtype"),
    ("state not finite", lambda o: {**o, STATE_KEY: np.r_[np.zeros(7), np.nan]}, "not finite \\(gripper\\)"),
    ("no image", lambda o: {STATE_KEY: o[STATE_KEY]}, "sees the camera"),
    ("float image HWC", lambda o: {**o, CAMERA: o[CAMERA] / 255.0}, "uint8"),
    ("float image out of range", lambda o: {**o, CAMERA: o[CAMERA].transpose(2, 0, 1) * 1.0}, r"in \[0, 1\]"),
    ("grey image", lambda o: {**o, CAMERA: o[CAMERA][..., 0]}, r"\(H, W, 3\)"),
    ("two cameras", lambda o: {**o, IMAGE_KEY_PREFIX + "side": o[CAMERA]}, "camera= to choose"),
    ("bad time", lambda o: {**o, TIMESTAMP_KEY: float("inf")}, "finite seconds"),
    ("negative time", lambda o: {**o, TIMESTAMP_KEY: -1.0}, ">= 0"),
    ("time text", lambda o: {**o, TIMESTAMP_KEY: "soon"}, "one number"),
    ("time a number as text", lambda o: {**o, TIMESTAMP_KEY: "1.5"}, "timestamp must be one number.*'1.5' \\(str\\)"),
    ("time true", lambda o: {**o, TIMESTAMP_KEY: True}, "one number"),
    ("time 1e300", lambda o: {**o, TIMESTAMP_KEY: 1e300}, "timestamp 1e\\+300 s is a day or more after"),
    ("time a clock's", lambda o: {**o, TIMESTAMP_KEY: 1.7e9}, "a day or more after the episode began"),
    ("state true and false", lambda o: {**o, STATE_KEY: np.ones(8, dtype=bool)}, "dtype bool"),
    ("x 1e30", lambda o: with_state(o, x=1e30), "observation.state: x = 1e\\+30 m is beyond the 1000 m"),
    ("z -2 km", lambda o: with_state(o, z=-2000.0), "z = -2000 m is beyond"),
    ("zero quaternion", lambda o: with_state(o, qx=0, qy=0, qz=0, qw=0), "has length 0, not 1.*no orientation"),
    ("quaternion of length 2", lambda o: with_state(o, qx=0, qy=0, qz=0, qw=2), "has length 2, not 1"),
    ("gripper 3e38", lambda o: with_state(o, gripper=3e38), "gripper = 3e\\+38 lies outside .* standard deviations"),
    ("gripper 1e300", lambda o: with_state(o, gripper=1e300), "gripper = 1e\\+300 lies outside"),
    ("gripper -3e38", lambda o: with_state(o, gripper=-3e38), "gripper = -3e\\+38 lies outside"),
    ("gripper inf", lambda o: with_state(o, gripper=np.inf), "not finite \\(gripper\\)"),
    ("gripper -inf", lambda o: with_state(o, gripper=-np.inf), "not finite \\(gripper\\)"),
    ("float image with a NaN", lambda o: {**o, CAMERA: nan_pixel(o[CAMERA])}, r"in \[0, 1\], got nan"),
]


def nan_pixel(image: np.ndarray) -> np.ndarray:
    """`image` (H, W, 3) uint8 as LeRobot hands it, (3, H, W) float in [0, 1], with one pixel NaN."""
    floats = image.transpose(2, 0, 1) / 255.0
    floats[0, 0, 0] = np.nan
    return floats


@pytest.mark.parametrize("case", BAD, ids=[c[0] for c in BAD])
def test_bad_observations_are_one_clear_error(case):
    _, broken, message = case
    policy = make_policy()
    with pytest.raises(PolicyError, match=message):
        policy.select_action(broken(observation(0, time_s=0.0)))


def test_lerobots_float_images_give_the_uint8_frames_result():
    """LeRobot hands images as (1, 3, H, W) float in [0, 1] (and states with a batch dimension)."""
    a, b = make_policy(), make_policy()
    for k in range(4):
        obs = observation(k)
        image = (obs[CAMERA].transpose(2, 0, 1) / 255.0).astype(np.float32)[None]  # (1, 3, H, W)
        lerobot = {CAMERA: image, STATE_KEY: obs[STATE_KEY][None]}
        np.testing.assert_array_equal(a.select_action(lerobot)[0], b.select_action(obs))


def test_a_named_camera_is_read_among_several():
    policy = make_policy(camera="front")
    obs = observation(0)
    policy.step({**obs, IMAGE_KEY_PREFIX + "side": np.zeros((2, 2, 3), np.uint8)})


def test_bad_policies_are_refused():
    spec = camera_spec()
    with pytest.raises(PolicyError, match="waypoints"):
        make_policy(waypoints=0)
    with pytest.raises(PolicyError, match="needs the feature network"):
        Policy(camera_network(), spec, None)
    with pytest.raises(PolicyError, match="no time base"):
        Policy(camera_network(), camera_spec(time_base=None), mean_colour_features)
    with pytest.raises(PolicyError, match="cover the model row"):
        PolicySpec(spec.columns, EXPERTS, (0, FEATURES - 1), spec.state, spec.time_base)
    policy = Policy(camera_network(), camera_spec(time_base=None), mean_colour_features, time_base=TimeBase(1, 0.5))
    assert policy.step(observation(1)).times_s.tolist() == [0.5 * w for w in range(1, 11)]


def test_the_spec_survives_its_dict_and_refuses_what_it_cannot_read():
    spec = camera_spec()
    again = PolicySpec.from_dict(spec.to_dict())
    assert again.to_dict() == spec.to_dict() and again.action_names == spec.action_names
    data = spec.to_dict()
    with pytest.raises(PolicyError, match="state vector"):
        PolicySpec.from_dict({**data, "state_names": ["x"]})
    with pytest.raises(PolicyError, match="incomplete"):
        PolicySpec.from_dict({k: v for k, v in data.items() if k != "normaliser"})


def test_the_time_base_maps_seconds_to_the_phase():
    tb = TimeBase.from_demonstrations([3.9, 4.0, 4.5], [40, 41, 46])
    assert tb.duration_s == 4.0 and tb.period_s == pytest.approx(0.1)
    assert tb.phase(2.0) == 0.5 and tb.phase(5.0) == 1.0 and tb.phase(-1.0) == 0.0
    assert TimeBase.from_dict(tb.to_dict()) == tb
    assert TimeBase.parse("3.9,0.1") == TimeBase(3.9, 0.1)
    bad_ones = (
        lambda: TimeBase(0, 0.1),
        lambda: TimeBase(1, 2),
        lambda: TimeBase.from_demonstrations([1], [1]),
        lambda: TimeBase.parse("3.9"),
        lambda: TimeBase.parse("3.9,x"),
        lambda: TimeBase.parse("0.1,3.9"),
    )
    for bad in bad_ones:
        with pytest.raises(PolicyError):
            bad()


def test_a_quaternion_slightly_off_unit_length_is_normalised_and_the_state_left_as_given():
    a, b = make_policy(), make_policy()
    for k in range(3):
        obs = observation(k, time_s=0.1 * k)
        given = np.array(obs[STATE_KEY])
        given[3:7] *= 1.05  # within the tolerance: a robot's rounding
        np.testing.assert_allclose(
            a.step(obs).waypoints, b.step({**obs, STATE_KEY: given}).waypoints, rtol=1e-5, atol=1e-6
        )
        assert np.linalg.norm(given[3:7]) == pytest.approx(1.05, rel=1e-6)  # the caller's array is not changed


def test_the_bounds_apply_to_the_state_entries_the_model_reads_only():
    columns = Columns(observed=((0, 4),), query=(), predicted=((0, 3),), loc=np.zeros(4), scale=np.ones(4))
    xyz_gripper = (((0, 3), (0, 3)), ((7, 8), (3, 4)))  # no orientation: x y z and the gripper
    policy = Policy(LinearNetwork(4, 0, 3), PolicySpec(columns, EXPERTS, None, xyz_gripper, TIME_BASE))
    unrotated = {STATE_KEY: np.r_[0.1, 0.2, 0.3, 0.0, 0.0, 0.0, 0.0, 1.0]}  # a zero quaternion, never read
    assert policy.step(unrotated).waypoints.shape == (10, 3)
    with pytest.raises(PolicyError, match="x = 1e\\+30 m"):
        policy.step(with_state(unrotated, x=1e30))


def test_the_gripper_may_lie_within_its_bound_of_the_training_spread_and_no_further():
    spec = camera_spec()
    loc, scale = float(spec.columns.loc[WIDTH - 1]), float(spec.columns.scale[WIDTH - 1])
    policy = make_policy()
    inside = loc + 0.99 * GRIPPER_DEVIATIONS * scale
    assert np.isfinite(policy.step(with_state(observation(0), gripper=inside)).waypoints).all()
    with pytest.raises(PolicyError, match="gripper = .* lies outside"):
        policy.step(with_state(observation(1), gripper=loc - 1.01 * GRIPPER_DEVIATIONS * scale))
    assert policy.step(observation(1)).step == 1  # the refused observation took no step


class Broken(LinearNetwork):
    """A network whose encoder (`where="encode"`) or decoder gives NaN from its `after`-th call on."""

    def __init__(self, where: str, after: int = 0) -> None:
        super().__init__(WIDTH, 0, 4)
        self.where, self.after, self.calls = where, after, 0

    def encode(self, obs):
        encoded = super().encode(obs)
        self.calls += self.where == "encode"
        return encoded * np.nan if self.where == "encode" and self.calls > self.after else encoded

    def decode(self, r, query):
        gate, mean, std = super().decode(r, query)
        self.calls += self.where == "decode"
        if self.where == "decode" and self.calls > self.after:
            mean[0, -1] = np.inf
        return gate, mean, std


@pytest.mark.parametrize("where", ["encode", "decode"])
def test_a_network_that_gives_values_that_are_not_finite_is_a_policy_error_never_an_action(where):
    policy = Policy(Broken(where, after=2), camera_spec(), mean_colour_features)
    for k in range(2):
        assert np.isfinite(policy.select_action(observation(k))).all()
    with pytest.raises(PolicyError, match="not finite"):
        policy.select_action(observation(2))


def test_an_encoding_that_is_not_finite_stays_out_of_the_conditioning_set():
    """The step is refused before its encoding joins the set: the next steps condition as if it never came."""
    broken, reference = Broken("encode", after=1), LinearNetwork(WIDTH, 0, 4)
    a = Policy(broken, camera_spec(), mean_colour_features)
    b = Policy(reference, camera_spec(), mean_colour_features)
    a.step(observation(0, time_s=0.0)), b.step(observation(0, time_s=0.0))
    with pytest.raises(PolicyError, match="left out of the conditioning set"):
        a.step(observation(1, time_s=0.1))
    broken.after = 10**9  # healthy again
    np.testing.assert_array_equal(a.step(observation(2, time_s=0.2)).gate, b.step(observation(2, time_s=0.2)).gate)


@pytest.mark.parametrize("seed", [-1, 1.5, True, "3", -(10**23)])
def test_an_episode_seed_that_is_not_an_integer_of_zero_or_more_is_one_clear_error(seed):
    policy = make_policy()
    with pytest.raises(PolicyError, match="an episode's seed is an integer >= 0"):
        policy.reset(seed)
    policy.reset(10**23)  # numpy's generators take any integer >= 0
    policy.reset(np.int64(7))
    assert policy.step(observation(0)).step == 0


TOP = IMAGE_KEY_PREFIX + "top"


def trained_on(image_key: str | None = TOP, image_size: tuple[int, int] | None = (48, 64)) -> Policy:
    """The fake policy whose spec says its training frames came from `image_key` at `image_size` (height, width)."""
    spec = replace(camera_spec(), image_key=image_key, image_size=image_size)
    return Policy(camera_network(), spec, mean_colour_features)


def test_a_policy_reads_the_training_cameras_key_and_refuses_another_camera_or_frame_size():
    obs = observation(0)
    frame = obs[CAMERA]  # (48, 64, 3)
    front_only = {STATE_KEY: obs[STATE_KEY], CAMERA: frame}
    with pytest.raises(PolicyError, match="needs 'observation.images.top' \\(the training recordings' camera\\)"):
        trained_on().step(front_only)
    reference = make_policy().step(front_only)
    for given in ({STATE_KEY: obs[STATE_KEY], TOP: frame}, {**front_only, TOP: frame}):  # the training camera's key
        np.testing.assert_array_equal(trained_on().step(given).waypoints, reference.waypoints)
    named = Policy(camera_network(), trained_on().spec, mean_colour_features, camera="front")
    np.testing.assert_array_equal(named.step(front_only).waypoints, reference.waypoints)  # camera= reads another
    with pytest.raises(PolicyError, match="a frame of 32x24 pixels, but this policy was trained on frames of 64x48"):
        trained_on().step({STATE_KEY: obs[STATE_KEY], TOP: frame[::2, ::2]})
    lerobot = {STATE_KEY: obs[STATE_KEY][None], TOP: (frame.transpose(2, 0, 1) / 255.0)[None]}  # (1, 3, 48, 64)
    assert trained_on().select_action(lerobot).shape == (1, 4)
    assert trained_on(image_key=None, image_size=None).step({**front_only}).step == 0  # older specs: any image


def test_the_spec_carries_the_tasks_and_the_camera_through_its_dict_and_reads_one_without_them():
    spec = replace(camera_spec(), tasks=("pick the red cup", "stack"), image_key=TOP, image_size=(48, 64))
    again = PolicySpec.from_dict(spec.to_dict())
    assert (again.tasks, again.image_key, again.image_size) == (spec.tasks, TOP, (48, 64))
    older = {k: v for k, v in spec.to_dict().items() if k not in ("tasks", "image_key", "image_size")}
    assert (PolicySpec.from_dict(older).tasks, PolicySpec.from_dict(older).image_size) == ((), None)
    for wrong in ({"image_size": [48]}, {"image_size": [0, 64]}, {"tasks": "stack"}, {"image_key": ""}):
        with pytest.raises(PolicyError):
            PolicySpec.from_dict({**spec.to_dict(), **wrong})
