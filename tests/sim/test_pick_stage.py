"""`cnep sim pick-place` end to end on the smallest data that runs every stage (2 demonstrations, random features
calibrated on one batch of frames, 20 training steps, one episode per protocol and condition, each cut after the step
at which a changed table has changed at the latest): summary.json holds per model, protocol and condition the
documented rates, `cnep sim eval` of the exported CNEP (its task read from the policy) repeats the run's rows with the
same settings and episode seeds, and the examples turn the run into its table and probe its features. The stage's two
pools (training, closed loop) run their jobs in this process (tests/sim/conftest.py)."""

import importlib.util
import json

import pytest

import cnep.sim

if not all(importlib.util.find_spec(name) for name in cnep.sim.EXTRA):
    pytest.skip("the sim extra is not installed", allow_module_level=True)

from cnep.pipeline.cli.main import main  # noqa: E402
from cnep.pipeline.sim.baselines import COMPARED  # noqa: E402
from cnep.pipeline.sim.config import PROTOCOLS, PickPlaceConfig  # noqa: E402
from cnep.pipeline.sim.stage import SUMMARY_FILE, run_sim  # noqa: E402
from cnep.runtime import ConditioningPolicy  # noqa: E402
from cnep.sim.tasks.pick_place import scene as P  # noqa: E402
from tests.test_examples import load  # noqa: E402


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
    # The conditioning the exported policies carry: `cnep sim eval`, which runs a policy's own, repeats the run's rows.
    own = ConditioningPolicy()
    config = PickPlaceConfig(
        out=out,
        demonstrations=2,
        train_steps=20,
        window=own.window,
        anchors=own.anchors,
        episodes=1,
        max_steps=P.CHANGE_STEPS[1] + 1,
        record=1,
        offline=True,
        quiet=True,
    )
    summary = run_sim(config)
    assert json.loads((out / SUMMARY_FILE).read_text()) == json.loads(json.dumps(summary))
    assert summary["demonstrations"]["n"] == 2 and summary["demonstrations"]["clean"] == 2
    assert summary["settings"]["max_steps"] == config.max_steps
    assert set(summary["models"]) == {"CNEP", "CNMP", *COMPARED}
    for seeds in summary["models"].values():
        assert set(seeds) == {"0"} and list(seeds["0"]) == list(PROTOCOLS)
        for conditions in seeds["0"].values():
            assert list(conditions) == list(P.CONDITIONS)
            for rates in conditions.values():
                assert rates["episodes"] == 1 and {"success", "collision", "places", "switched_within"} <= set(rates)
                assert rates["per_episode"][0]["steps"] <= config.max_steps
            assert conditions[P.CHANGED]["per_episode"][0]["change_step"] is not None  # the table changed in time
    evaluated, steps = tmp_path / "eval", str(config.max_steps)
    assert main(["-q", "sim", "eval", str(out / "policies" / "cnep-seed0"), "--max-steps", steps, "--episodes", "1",
                 "--record", "0", "--out", str(evaluated)]) == 0  # fmt: skip
    again = json.loads((evaluated / SUMMARY_FILE).read_text())
    assert again["settings"]["task"] == "pick-place"
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
