"""`cnep sim pick-place` end to end on the smallest data that runs every stage (2 demonstrations, random features
calibrated on one batch of frames, 20 training steps, one episode per protocol and condition, each cut after 4
steps) on the environments' latest version: summary.json holds per model, protocol and condition the documented rates
and records the version, `cnep sim eval` of the exported CNEP (its task and version read from the policy) repeats the
run's rows with the same settings and episode seeds, and the examples turn the run into its table and probe its
features. (The v1 table changes during the carry, which policies trained this little never reach: the environment's
tests check the change, tests/sim/test_versions.py.) The stage's two pools (training, closed loop) run their jobs in
this process (tests/sim/conftest.py)."""

import importlib.util
import json

import pytest

import cnep.sim

if not all(importlib.util.find_spec(name) for name in cnep.sim.EXTRA):
    pytest.skip("the sim extra is not installed", allow_module_level=True)

from cnep.pipeline.cli.main import main  # noqa: E402
from cnep.pipeline.sim.baselines import COMPARED  # noqa: E402
from cnep.pipeline.sim.config import ENV_VERSIONS, PROTOCOLS, PickPlaceConfig  # noqa: E402
from cnep.pipeline.sim.partial import SUMMARY_FILE  # noqa: E402
from cnep.pipeline.sim.stage import run_sim  # noqa: E402
from cnep.pipeline.sim.validation import SelectionSettings  # noqa: E402
from cnep.recordings import read_demonstration  # noqa: E402
from cnep.sim.tasks.pick_place import scene as P  # noqa: E402
from tests.test_examples import load  # noqa: E402

# The rates every condition reports: success and the places, the switching without a change beside the prompt ones.
CHANGE_RATES = ("success", "places", "switching", "switched_unchanged", "switched_within", "switch_latency_p50")


def episode_rows(results: dict) -> dict:
    """protocol -> condition -> the episodes' rows without their timings."""
    return {
        protocol: {c: [{k: v for k, v in row.items() if k != "ms"} for row in r["per_episode"]] for c, r in by.items()}
        for protocol, by in results.items()
    }


@pytest.mark.slow  # MobileNet-v2 features, two trainings, two exports, six policies in the loop (one trained there)
def test_cnep_sim_pick_place_writes_the_documented_summary(
    tmp_path, monkeypatch, few_calibration_frames, sim_pools_in_process
):
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch"))
    out = tmp_path / "pick"
    config = PickPlaceConfig(
        out=out,
        demonstrations=2,
        train_steps=20,
        episodes=1,
        max_steps=4,
        record=1,
        offline=True,
        quiet=True,
        selection=SelectionSettings(candidates=1),  # no choice: tests/sim/test_selection.py tests it
        views=1,  # the views' path at a quarter of the rule's extraction
    )
    summary = run_sim(config)
    assert json.loads((out / SUMMARY_FILE).read_text()) == json.loads(json.dumps(summary))
    assert summary["demonstrations"]["n"] == 2 and summary["demonstrations"]["clean"] == 2
    assert summary["settings"]["max_steps"] == config.max_steps
    assert summary["seeds"]["reported"] == {"first": 0, "last": 0} and summary["selection"] == {}
    assert summary["env_version"] == summary["settings"]["env_version"] == ENV_VERSIONS[-1] == config.env_version
    assert read_demonstration(next((out / "demos").glob("*.mcap"))).episode.task == "pick-place-v1"
    assert set(summary["models"]) == {"CNEP", "CNMP", *COMPARED}
    for seeds in summary["models"].values():
        assert set(seeds) == {"0"} and list(seeds["0"]) == list(PROTOCOLS)
        for conditions in seeds["0"].values():
            assert list(conditions) == list(P.CONDITIONS)
            for rates in conditions.values():
                assert rates["episodes"] == 1 and set(CHANGE_RATES) <= set(rates)
                assert rates["per_episode"][0]["steps"] <= config.max_steps
                assert {"first_switch_step", "valid_switch_step"} <= set(rates["per_episode"][0])
    evaluated, steps = tmp_path / "eval", str(config.max_steps)
    assert main(["-q", "sim", "eval", str(out / "policies" / "cnep-seed0"), "--max-steps", steps, "--episodes", "1",
                 "--record", "0", "--out", str(evaluated)]) == 0  # fmt: skip
    again = json.loads((evaluated / SUMMARY_FILE).read_text())
    assert again["settings"]["task"] == "pick-place" and again["seeds"] == summary["seeds"]
    assert again["settings"]["task"] == "pick-place" and again["settings"]["env_version"] == config.env_version
    assert episode_rows(again["results"]) == episode_rows(summary["models"]["CNEP"]["0"])
    policies = 2 + len(COMPARED)
    assert len(list((out / "episodes").glob("*-planned-changed-seed0.rrd"))) == policies
    assert len(list((out / "episodes").glob("*.rrd"))) == policies * len(PROTOCOLS) * len(P.CONDITIONS)
    rows = load("pick_place_table").main([str(out / SUMMARY_FILE), "--csv", str(tmp_path / "pick.csv")])
    assert len(rows) == policies * len(PROTOCOLS) * len(P.CONDITIONS) and rows[0]["model"] == "CNEP"
    assert [r["protocol"] for r in rows[:4]] == [PROTOCOLS[0]] * 3 + [PROTOCOLS[1]]
    assert (tmp_path / "pick.csv").read_text().startswith("run,model,train_seed,protocol,condition,")
    probes = load("pick_place_probe").main([str(out), "--scenes", "9"])
    assert set(probes) >= {"orientation", "valid"} and all(0 <= p["ridge"] <= 1 for p in probes.values())
