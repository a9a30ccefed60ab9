"""Each task's rates on hand-made rows: every share with its Wilson interval, the behaviour entropy where the scene
leaves a choice and None where it does not, the switching without a change beside the switching after one; the
tables and the results' CSVs (examples/closed_loop_csv.py, examples/pick_place_table.py) show them; a policy's
episodes give the same rows as a rerun and the documented rates of them."""

import importlib.util
import json

import pytest

import cnep.sim

if not all(importlib.util.find_spec(name) for name in cnep.sim.EXTRA):
    pytest.skip("the sim extra is not installed", allow_module_level=True)

from cnep.pipeline.sim.config import LoopSettings  # noqa: E402
from cnep.pipeline.sim.loop import evaluate_policy  # noqa: E402
from cnep.pipeline.sim.summary import format_table  # noqa: E402
from cnep.sim.episode import PLANNED  # noqa: E402
from cnep.sim.statistics import wilson  # noqa: E402
from cnep.sim.tasks import find_task  # noqa: E402
from cnep.sim.tasks.obstacle.scoring import rates  # noqa: E402
from cnep.sim.tasks.pick_place.scoring import pick_rates  # noqa: E402
from tests.sim.scripted import scripted_policy  # noqa: E402
from tests.test_examples import load  # noqa: E402

MS = {name: {"p50": 1.0, "p99": 2.0} for name in ("policy", "render", "physics")}
OBSTACLE_ROW_KEYS = {"seed", "success", "collision", "side", "cue_side", "cue_step", "clearance_m",
                     "distance_to_goal_m", "steps", "first_switch_step", "cue_switch_step", "switches",
                     "ms"}  # fmt: skip


def obstacle_row(side: str, success: bool = True, cue_side: str | None = None, switches: int = 0, **cued) -> dict:
    row = {"success": success, "collision": not success, "side": side, "cue_side": cue_side, "switches": switches,
           "clearance_m": 0.05, "cue_step": None, "first_switch_step": 3 if switches else None,
           "cue_switch_step": None, "ms": MS}  # fmt: skip
    return {**row, **cued}


def pick_row(place: str | None, valid: list[str], success: bool = True, **changed) -> dict:
    row = {"success": success, "collision": False, "lifted": True, "dropped": False, "place": place, "valid": valid,
           "switches": 0, "change_step": None, "first_switch_step": None, "switch_step": None,
           "valid_switch_step": None, "grasp_offset_m": None, "ms": MS}  # fmt: skip
    return {**row, **changed}


def rounded(interval: tuple[float, float]) -> list[float]:
    return [round(bound, 4) for bound in interval]


def test_the_obstacle_rates_carry_an_interval_per_share_and_the_entropy_of_the_successful_sides():
    rows = [*[obstacle_row("left")] * 3, obstacle_row("right"), obstacle_row("right", success=False, switches=2)]
    r = rates(rows)
    assert r["success"] == 0.8 and r["success_ci"] == rounded(wilson(4, 5))
    assert r["collision_ci"] == rounded(wilson(1, 5)) and r["left_ci"] == rounded(wilson(3, 5))
    assert r["switching"] == 0.2 and r["switching_ci"] == rounded(wilson(1, 5))
    assert r["entropy"] == 0.8113  # 3 left : 1 right over the successful episodes; the failed one does not count
    assert r["followed_cue"] is None and r["followed_cue_ci"] is None


def test_with_a_cue_the_obstacle_has_no_entropy_and_the_followed_cue_share_its_interval():
    rows = [obstacle_row("left", cue_side="left"), obstacle_row("left", cue_side="right")]
    r = rates([*rows, obstacle_row("right", cue_side="right")])
    assert r["entropy"] is None and r["followed_cue"] == 0.6667 and r["followed_cue_ci"] == rounded(wilson(2, 3))


def test_the_pick_place_entropy_is_over_the_free_scenes_valid_places_per_grasp():
    along_y, along_x = ["left", "right"], ["far_left", "far_right"]
    free = [pick_row("left", along_y), pick_row("right", along_y), *[pick_row("far_left", along_x)] * 3]
    assert pick_rates(free)["entropy"] == 0.5  # grasp along y: 1.0, along x: 0.0, averaged
    assert pick_rates([*free, pick_row(None, along_x, success=False)])["entropy"] == 0.5
    decided = pick_rates([pick_row("left", ["left"]), pick_row("right", ["right"])])
    assert decided["entropy"] is None and decided["switched_within"] is None and decided["switched_within_ci"] is None


def test_the_pick_place_grasp_offset_is_the_median_of_the_episodes_whose_gripper_closed():
    rows = [pick_row("left", ["left"], grasp_offset_m=m) for m in (0.01, 0.05, 0.02)]
    assert pick_rates([*rows, pick_row(None, ["left"], success=False)])["grasp_offset_p50_m"] == 0.02
    assert pick_rates([pick_row(None, ["left"], success=False)])["grasp_offset_p50_m"] is None


def test_the_pick_place_switching_has_its_interval_with_and_without_a_change():
    one = pick_row("left", ["left"], switches=1, first_switch_step=30)
    unchanged = pick_rates([one, *[pick_row("left", ["left"])] * 19])
    assert unchanged["switching"] == 0.05 and unchanged["switching_ci"] == rounded(wilson(1, 20))
    assert unchanged["switched_unchanged"] == 0.05 and unchanged["switched_unchanged_ci"] == rounded(wilson(1, 20))
    changed = [
        pick_row("right", ["right"], switches=1, change_step=10, first_switch_step=12, valid_switch_step=12),
        pick_row("right", ["right"], switches=1, change_step=10, first_switch_step=18, valid_switch_step=18),
        pick_row("left", ["right"], success=False, change_step=10),
    ]
    r = pick_rates(changed)
    assert r["switched_within"] == 0.3333 and r["switched_within_ci"] == rounded(wilson(1, 3))
    assert r["switching"] == 0.6667 and r["switching_ci"] == rounded(wilson(2, 3))
    assert r["switched_unchanged"] == 0.0 and r["switch_latency_p50"] == 5.0


def test_only_a_switch_to_a_valid_places_expert_after_the_change_counts_and_one_before_it_is_unprompted():
    changed = [
        # switched at once, but to the expert of the place just taken; to a valid place's 6 steps later
        pick_row("right", ["right"], switches=2, change_step=10, first_switch_step=11, switch_step=11,
                 valid_switch_step=17),
        # switched before the policy could see the change (its read at step 11 is the first to show it)
        pick_row("right", ["right"], switches=1, change_step=10, first_switch_step=10, switch_step=10),
        pick_row("right", ["right"], switches=1, change_step=10, first_switch_step=13, switch_step=13,
                 valid_switch_step=13),
    ]  # fmt: skip
    r = pick_rates(changed)
    assert r["switched_within"] == 0.3333 and r["switch_latency_p50"] == 5.0  # 7 and 3 steps: counted, not prompt
    assert r["switched_unchanged"] == 0.3333 and r["switched_unchanged_ci"] == rounded(wilson(1, 3))


def test_a_re_route_within_an_expert_counts_beside_the_switches_and_older_rows_have_none():
    changed = [
        pick_row("right", ["right"], change_step=10, reroute_step=14),  # the same expert's plan moved
        pick_row("right", ["right"], switches=1, change_step=10, first_switch_step=12, valid_switch_step=12,
                 reroute_step=12),
        pick_row("left", ["right"], success=False, change_step=10, reroute_step=20),  # too late
        pick_row("left", ["right"], success=False, change_step=10),  # an older run's row
    ]  # fmt: skip
    r = pick_rates([*changed, pick_row("left", ["left"], reroute_step=None)])
    assert r["switched_within"] == 0.25 and r["rerouted_within"] == 0.5  # over the 4 changed rows
    assert r["rerouted_within_ci"] == rounded(wilson(2, 4))
    assert pick_rates([pick_row("left", ["left"])])["rerouted_within"] is None  # nothing changed


def test_the_obstacle_cue_during_the_motion_is_its_change_and_a_cue_from_the_reset_is_none():
    rows = [
        obstacle_row("left", cue_side="left", switches=1, cue_step=6, first_switch_step=8, cue_switch_step=8),
        obstacle_row("left", cue_side="left", switches=1, cue_step=6, first_switch_step=4),  # before the cue
        obstacle_row("left", cue_side="left", cue_step=6),  # never switched
        obstacle_row("right", cue_side="right", switches=1, cue_step=0, first_switch_step=2),  # v0: from the reset
    ]
    r = rates(rows)
    assert r["switched_within"] == 0.3333 and r["switched_within_ci"] == rounded(wilson(1, 3))
    assert r["switched_unchanged"] == 0.5 and r["switch_latency_p50"] == 2.0
    line = format_table({"CNEP-seed0": {PLANNED: r}}, find_task("obstacle", 1)).splitlines()[2]
    assert "50% [15-85]" in line and "33% [6-79]" in line


def test_the_tables_show_the_intervals_and_the_entropy_compactly():
    rows = [*[obstacle_row("left")] * 23, *[obstacle_row("right")] * 23, *[obstacle_row("left", success=False)] * 4]
    table = format_table({"CNEP-seed0": {PLANNED: rates(rows)}}, find_task("obstacle", 0)).splitlines()
    assert table[0].split()[:6] == ["policy", "protocol", "episodes", "success", "collision", "left"]
    assert "92% [81-97]" in table[2] and " 1.00 " in table[2] and "0% [0-7]" in table[2]
    assert len(table[0]) <= 130
    pick = {PLANNED: {"free": pick_rates([pick_row("left", ["left", "right"])] * 10)}}
    line = format_table({"CNEP-seed0": pick}, find_task("pick-place", 0)).splitlines()[2]
    assert "100% [72-100]" in line and " 0.00 " in line and "left:10" in line


def test_a_policy_s_episodes_give_the_same_rows_again_and_the_rates_of_them():
    task, settings = find_task("obstacle", 0), LoopSettings(episodes=4, max_steps=12, protocol=PLANNED, record=0)
    policy = scripted_policy(gate=(0.5, 0.5), first_expert="sample")
    first, again = (evaluate_policy(policy, task, settings, label="scripted")[PLANNED] for _ in range(2))
    rows = first["per_episode"]
    assert all(set(row) == OBSTACLE_ROW_KEYS for row in rows)
    assert [{**row, "ms": None} for row in rows] == [{**row, "ms": None} for row in again["per_episode"]]
    assert first["left"] == round(sum(row["side"] == "left" for row in rows) / len(rows), 4)
    assert first["left_ci"] == rounded(wilson(sum(row["side"] == "left" for row in rows), len(rows)))


def test_the_results_csvs_carry_the_intervals_and_the_entropy(tmp_path):
    obstacle = rates([*[obstacle_row("left")] * 3, obstacle_row("right")])
    run = tmp_path / "set0"
    run.mkdir()
    settings = {"seed": 0, "cue": False, "first_expert": "sample", "train_steps": 10}
    (run / "summary.json").write_text(
        json.dumps({"settings": settings, "models": {"CNEP": {"0": {PLANNED: obstacle}}}})
    )
    (row,) = load("closed_loop_csv").main([str(run), "--csv", str(tmp_path / "closed-loop.csv")])
    assert [row["success_lo"], row["success_hi"]] == obstacle["success_ci"] and row["entropy"] == 0.8113
    assert row["switched_unchanged"] == 0.0 and row["switched_within_5"] == "" and row["env_version"] == 0
    free = pick_rates([pick_row("left", ["left", "right"]), pick_row("right", ["left", "right"])])
    pick = tmp_path / "pick" / "summary.json"
    pick.parent.mkdir()
    pick.write_text(json.dumps({"models": {"CNEP": {"0": {PLANNED: {"free": free}}}}}))
    (row,) = load("pick_place_table").main([str(pick), "--csv", str(tmp_path / "pick.csv")])
    assert [row["switching"], row["switching_lo"], row["switching_hi"]] == [0.0, 0.0, free["switching_ci"][1]]
    assert row["entropy"] == 1.0 and "switching_lo" in (tmp_path / "pick.csv").read_text().splitlines()[0]
    assert [row["switched_unchanged"], row["switched_unchanged_hi"]] == [0.0, free["switched_unchanged_ci"][1]]
