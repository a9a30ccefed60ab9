"""The demo's printed summary: behaviours -> experts, held-out errors, the scene change, the free choices, the files."""

from __future__ import annotations

import shlex
import shutil
import sys
from pathlib import Path

from cnep.pipeline.demo.free_choice import COMMIT_GATE, PLACE_TOLERANCE, SPLIT_GATE
from cnep.pipeline.demo.stage import REPLAYS_RRD, RRD_FILE, SUMMARY_FILE, DemoResult


def format_summary(result: DemoResult) -> str:
    """The printed summary: behaviours -> experts, held-out errors, the scene change, the files, the times."""
    lines = ["behaviour      demos  expert  purity  (demonstrations per expert)"]
    for name, row in result.behaviours.items():
        spread = ", ".join(f"{e}: {n}" for e, n in row["experts"].items())
        lines.append(f"{name:<14} {row['n']:>5}  {row['expert']:>6}  {row['purity']:>6.2f}  ({spread})")
    majority = {row["expert"] for row in result.behaviours.values()}
    lines.append(
        f"{len(result.behaviours)} behaviours -> {len(majority)} distinct majority expert(s) "
        f"(purity alone is 1.0 when every demonstration goes to one expert)"
    )
    lines.append("")
    lines.append(features_line(result.feature_weights, result.imagenet_unavailable))
    lines.extend(heldout_lines(result.heldout))
    lines.append("")
    for change in result.scene_change:
        moves = ", ".join(f"step {s}: {a} -> {b}" for s, a, b in change["switches"]) or "none"
        lines.append(
            f"scene change {change['behaviour']} at step {change['change_step']}: expert "
            f"{change['expert_before']} before, {change['expert_after']} after; switches: {moves}"
        )
    lines.append("")
    lines.append(
        f"held-out free-choice scenes (both slots free), conditioned on the first step: where the motion "
        f"ends (within {100 * PLACE_TOLERANCE:.0f} cm of a slot centre, or between):"
    )
    lines.append("model  in a slot  near  far  between  mean distance to a slot (cm)")
    for name, row in result.free_choice.items():
        lines.append(
            f"{name:<6} {row['valid']:>9.2f}  {row['near']:>4.2f}  {row['far']:>3.2f}  "
            f"{row['between']:>7.2f}  {100 * row['distance_m']:>10.1f} (n = {row['n']})"
        )
    for episode in result.free_choice_replay:
        lines.extend(replay_lines(episode, result.behaviours))
    lines.append("")
    if result.figure is not None:
        lines.append(f"summary figure: {result.figure}")
    lines.append(f"other replayed recordings: {result.out / Path(REPLAYS_RRD).parent}/")
    view = f"{shlex.quote(cnep_command())} view {shlex.quote(str(result.out / RRD_FILE))}"
    lines.append(
        f"open the view (the scene change): {view} (the Rerun viewer with a display, else its web viewer and the "
        "address to open)"
    )
    lines.append(f"checkpoints: {', '.join(str(p) for p in result.checkpoints.values())}")
    lines.append(f"summary: {result.out / SUMMARY_FILE}")
    lines.append("stage times (s): " + ", ".join(f"{k} {v:.1f}" for k, v in result.seconds.items()))
    return "\n".join(lines)


def heldout_lines(heldout: dict[str, dict]) -> list[str]:
    """The held-out table (`measures.heldout_errors` per model): how many scenes each model read as the wrong
    behaviour, apart from the error of those it read right."""
    lines = [
        "held-out demonstrations, conditioned on the first step (t = 0); read wrong: the generated motion lies",
        "nearest a training demonstration of another behaviour (such a motion misses by ~25 cm):",
        "model  read wrong  position RMSE (cm)  RMSE of those read right (cm)  median per demo (cm)  gripper MAE (mm)",
    ]
    for name, row in heldout.items():
        wrong = f"{row['wrong_behaviour']} of {row['n']}"
        right = row["position_rmse_read_right_m"]
        lines.append(
            f"{name:<6} {wrong:>10}  {100 * row['position_rmse_m']:>18.2f}  "
            f"{'-' if right is None else f'{100 * right:.2f}':>29}  {100 * row['position_rmse_median_m']:>20.2f}  "
            f"{1000 * row['gripper_mae_m']:>16.2f}"
        )
    return lines


def features_line(weights: str, imagenet_unavailable: str | None = None) -> str:
    """Which weights the features came from, from the extractor's weights name (perception.weights.Weights), and
    for random ones why ImageNet's were not used (`DemoResult.imagenet_unavailable`; None: random was asked for)."""
    if weights.startswith("random:"):
        why = (
            f"ImageNet weights not available: {imagenet_unavailable}"
            if imagenet_unavailable
            else "as asked (--weights random)"
        )
        said = f"seeded random weights calibrated on the training frames, {why}"
    elif weights.startswith("imagenet:"):
        said = "ImageNet weights"
    else:
        said = "the weights of a file"
    return f"features: MobileNet-v2 with {said} ({weights})"


def cnep_command() -> str:
    """How to run `cnep` from a fresh shell: `cnep` when it is on PATH, else the one installed beside this Python (a
    virtual environment that is not activated)."""
    if shutil.which("cnep"):
        return "cnep"
    beside = Path(sys.executable).parent / "cnep"
    try:
        return str(beside.relative_to(Path.cwd()))
    except ValueError:
        return str(beside)


def replay_lines(episode: dict, behaviours: dict[str, dict]) -> list[str]:
    """The summary's lines on one replayed free-choice episode (`free_choice_commitment`'s entry)."""
    census = episode["census"]

    def expert(e: int) -> str:
        names = [name for name, row in behaviours.items() if row["expert"] == e]
        return f"expert {e} ({', '.join(names) or 'no behaviour'}'s)"

    (e0, p0), (e1, p1) = episode["start"]
    split = "split" if p0 < SPLIT_GATE else "not split"
    if episode["step"] is None:
        commits = f"ends on {expert(episode['expert'])} below p = {COMMIT_GATE}, not committed"
    else:
        commits = f"holds {expert(episode['expert'])} at p >= {COMMIT_GATE} from step {episode['step']}"
    slot = "the behaviour picked" if episode["picked"] else "not the behaviour picked"
    chosen = (
        f"the least certain step 0 of the {census['split_commit']} that start split and commit"
        if census["split_commit"]
        else "none starts split and commits: the least certain step 0 of all"
    )
    return [
        f"online gate of the {census['n']} held-out free-choice episodes: {census['split']} start split (no expert at "
        f"p >= {SPLIT_GATE} at step 0), {census['split_commit']} of them then commit (p >= {COMMIT_GATE} to the end)",
        f"replayed free choice {episode['recording']} ({episode['scene']}, picked {episode['choice']}, carry from step "
        f"{episode['carry_step']}; {chosen}):",
        f"  gate at step 0 {expert(e0)} {p0:.2f}, {expert(e1)} {p1:.2f} ({split}); {commits}: {slot}",
    ]
