"""examples/locate_probe.py: its ridge probe finds a position that the rows carry and not one they do not, and on a
task's scenes it probes every position the scene draws with each readout, the same seeds giving the same rows."""

import importlib.util
import json

import numpy as np
import pytest

import cnep.sim
from tests.test_examples import load

SIM = all(importlib.util.find_spec(name) for name in cnep.sim.EXTRA)


def test_the_probe_locates_what_the_rows_carry_and_falls_to_the_mean_without_it():
    probe = load("probes").probe
    rng = np.random.default_rng(0)
    y = rng.uniform(-0.05, 0.05, (120, 2))  # (m, 2) positions within +-5 cm
    x = np.concatenate([y @ rng.normal(size=(2, 100)), 0.1 * rng.normal(size=(120, 100))], axis=1)  # (m, 200)
    found = probe(x, y, 40)  # fewer fitting rows than columns, as 40 demonstrations' features
    assert found["probe_cm"] < 0.5 < 2 < found["mean_cm"]
    blind = probe(rng.normal(size=(120, 200)), y, 40)
    assert blind["probe_cm"] > 0.8 * blind["mean_cm"]  # nothing to find: no better than the mean


@pytest.mark.skipif(not SIM, reason="the sim extra is not installed")
def test_every_drawn_position_is_probed_with_each_readout_and_the_seeds_repeat(tmp_path, capsys, one_thread):
    example = load("locate_probe")
    out = tmp_path / "rows.json"
    rows = example.main(["obstacle", "--scenes", "8", "--fit", "5", "--json", str(out)])
    assert [(r["position"], r["readout"]) for r in rows] == [
        (position, readout)
        for readout in ("features (random)", "pixels 32x32")
        for position in ("box_xy", "goal_xy")  # what the v1 obstacle scene moves
    ]
    assert all(r["probe_cm"] >= 0 and r["mean_cm"] > 0 and r["lambda"] in load("probes").LAMBDAS for r in rows)
    assert json.loads(out.read_text()) == rows and "| goal_xy | pixels 32x32 |" in capsys.readouterr().out
    assert example.main(["obstacle", "--scenes", "8", "--fit", "5"]) == rows
    with pytest.raises(SystemExit):
        example.main(["obstacle", "--scenes", "8", "--fit", "8"])  # nothing left to score on


@pytest.mark.skipif(not SIM, reason="the sim extra is not installed")
def test_the_ablation_builds_the_default_weights_as_cnep_extract_does_and_adds_a_row_per_variant(one_thread):
    example = load("locate_probe")
    frames, positions = example.scenes("obstacle", 6, clean=False)
    default = example.ablated(frames, 5, {"default": (example.LOW_PASS_CHANNELS, example.ACTIVATION_BIAS)})
    np.testing.assert_allclose(
        default["default"], example.readouts(frames, 5, "random")["features (random)"], atol=1e-5
    )
    rows = example.main(["obstacle", "--scenes", "6", "--fit", "5", "--ablation"])
    assert [r["readout"] for r in rows[4:]] == [name for name in example.ABLATION for _ in positions]
