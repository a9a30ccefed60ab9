"""The demo summary's measurements, on the trained checkpoints and the replay's decisions.

- `expert_purity`: per scene-decided behaviour, the expert most of its demonstrations go to, and how many do;
- `heldout_errors`: the motion generated from each held-out demonstration's first step against the
  demonstration (position and gripper errors, the behaviour of the nearest training demonstration:
  `nearest_behaviour`);
- `scene_change_switches`: the replay's active expert before and after each scene change;
- `online_gates` and `free_choice_commitment`: the online gate of the free-choice recordings, as the
  replay computes it, and how the replayed one's gate commits (the free-choice rules: `free_choice`).

Recordings are recognised across the stages' folders by `key` (split/file name); the behaviour labels
come from the recorder (`generator`, or its files: `recorded_labels`), never from the models.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np

from cnep.models import CNEP, ConditioningPolicy, Prediction
from cnep.models.threads import torch_threads
from cnep.pipeline.demo.free_choice import gate_commitment
from cnep.pipeline.demo.generator import CHOICE_KEY, CHOICE_STEP_KEY, LABEL_KEY
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.inputs import DEMONSTRATIONS, mcap_files
from cnep.pipeline.replay.conditioning import decide
from cnep.pipeline.replay.decisions import read_decisions
from cnep.pipeline.train.checkpoint import TrainedModel, load_trained
from cnep.pipeline.train.experts import gate_of
from cnep.recordings import DemonstrationReader, read_demonstration, read_trajectory
from cnep.recordings.constants import BLOCK_GRIPPER

POLICY = ConditioningPolicy()  # the replay's conditioning (models.online): the first step + the latest 10


def key(path: Path) -> str:
    """`split/file name`: how a demonstration is recognised across the stages' folders."""
    return f"{path.parent.name}/{path.name}"


def recorded_labels(recorded: Path) -> dict[str, str]:
    """The recorder's label of every demonstration file under `recorded` (a demo's `recorded/` folder), by `key`."""
    labels = {}
    for path in mcap_files(recorded, DEMONSTRATIONS):
        with DemonstrationReader(path) as reader:
            labels[key(path)] = reader.episode.extra[LABEL_KEY]
    return labels


def trained_rows(checkpoint: Path, paths: list[Path]) -> tuple[TrainedModel, list[np.ndarray]]:
    """The checkpoint, loaded with its column selection, and each file's (T, model width) rows."""
    trained = load_trained(checkpoint)
    return trained, [trained.rows(read_trajectory(p), p) for p in paths]


def online_gates(checkpoint: Path, paths: list[Path]) -> list[np.ndarray]:
    """Each recording's (T, d) gate rows as the replay computes them (online conditioning with POLICY, one
    torch thread like the replay: pipeline.workers)."""
    trained = load_trained(checkpoint)
    traces = []
    with torch_threads():
        for path in paths:
            trajectory = read_trajectory(path)
            rows = trained.rows(trajectory, path)
            traces.append(decide(trained.model, rows, trajectory.timestamps_ns, POLICY).gates)
    return traces


def expert_purity(checkpoint: Path, paths: list[Path], labels: dict[str, str]) -> dict[str, dict]:
    """Per behaviour: the CNEP expert most of its demonstrations go to and the fraction that do (purity).

    A demonstration goes to the expert with the highest gate probability when the model is conditioned
    on all of its steps.
    """
    trained, rows = trained_rows(checkpoint, paths)
    model = trained.model
    chosen: dict[str, list[int]] = {}
    for path, r in zip(paths, rows):
        chosen.setdefault(labels[key(path)], []).append(int(gate_of(model, r).argmax()))
    table = {}
    for behaviour in sorted(chosen):
        counts = Counter(chosen[behaviour])
        expert, n = counts.most_common(1)[0]
        table[behaviour] = {
            "n": len(chosen[behaviour]),
            "expert": expert,
            "purity": n / len(chosen[behaviour]),
            "experts": dict(sorted(counts.items())),
        }
    return table


def first_step_prediction(model: CNEP, rows: np.ndarray, steps: int | None = None) -> Prediction:
    """The model conditioned on a recording's first step (t = 0) and queried at each of its T steps.

    rows: (T, model width); the queries carry each step's own query columns when the model has any. A model
    without query columns needs only the first row: rows (1, model width) and `steps` = T.
    """
    T = len(rows) if steps is None else steps
    t = np.arange(T) / (T - 1)
    query = rows[:, model.query_columns.numpy()] if model.config.columns.query_dim else None
    if query is not None and len(query) != T:
        raise PipelineError(
            f"this model's queries carry columns of every step: give all {T} rows of the recording, got {len(rows)}"
        )
    return model.generate(t[:1], rows[:1, model.obs_columns.numpy()], t, query)


def recorded_paths(trained: TrainedModel, rows: list[np.ndarray]) -> list[np.ndarray]:
    """The recorded xyz path (T, 3) (m) of each recording, from its (T, model width) rows."""
    out_cols, xyz = trained.model.out_columns.numpy(), trained.mapping.predicted_xyz(trained.model)
    return [r[:, out_cols][:, xyz] for r in rows]


def nearest_behaviour(path: np.ndarray, train_paths: list[np.ndarray], train_labels: list[str]) -> str:
    """How a generated xyz path (T, 3) reads: the behaviour of the training demonstration of the same length whose
    recorded path (`recorded_paths`) lies nearest to it (mean distance)."""
    return min(
        (np.linalg.norm(d - path, axis=-1).mean(), label)
        for d, label in zip(train_paths, train_labels)
        if len(d) == len(path)
    )[1]


def heldout_errors(checkpoint: Path, heldout: list[Path], train_paths: list[Path], labels: dict[str, str]) -> dict:
    """Generated motion vs held-out demonstrations, conditioned on each one's first step (t = 0).

    The queries carry the demonstration's own features at each step when the layout has query columns.
    Two kinds of error: a demonstration is *read as the wrong behaviour* when the generated xyz path lies nearest
    (mean distance) to a training demonstration of another behaviour (`wrong_behaviour`, a count; such a path
    costs most of the whole motion), and the error of the paths read right.
    position_rmse_m: root mean squared xyz error (m) over all steps and demonstrations; position_rmse_read_right_m:
    the same over the demonstrations read right (None when there are none); position_rmse_median_m: the median
    over demonstrations of each one's RMSE (m); gripper_mae_m: mean absolute gripper error (m).
    """
    trained, rows = trained_rows(checkpoint, heldout)
    _, train_rows = trained_rows(checkpoint, train_paths)
    model, mapping = trained.model, trained.mapping
    xyz = mapping.predicted_xyz(model)
    out_cols = model.out_columns.numpy()
    g0, _ = mapping.blocks[BLOCK_GRIPPER]
    gripper = list(out_cols).index(g0)
    train_xyz = recorded_paths(trained, train_rows)
    train_labels = [labels[key(p)] for p in train_paths]
    sq, grip, hits = [], [], []
    for path, r in zip(heldout, rows):
        mean = first_step_prediction(model, r).mean  # (T, dy)
        truth = r[:, out_cols]  # (T, dy)
        sq.append(((mean[:, xyz] - truth[:, xyz]) ** 2).sum(-1))  # (T,)
        grip.append(np.abs(mean[:, gripper] - truth[:, gripper]))
        hits.append(nearest_behaviour(mean[:, xyz], train_xyz, train_labels) == labels[key(path)])
    read_right = [e for e, hit in zip(sq, hits) if hit]
    return {
        "n": len(heldout),
        "wrong_behaviour": len(hits) - sum(hits),
        "position_rmse_m": float(np.sqrt(np.concatenate(sq).mean())),
        "position_rmse_read_right_m": float(np.sqrt(np.concatenate(read_right).mean())) if read_right else None,
        "position_rmse_median_m": float(np.median([np.sqrt(e.mean()) for e in sq])),
        "gripper_mae_m": float(np.concatenate(grip).mean()),
    }


def scene_change_switches(
    rrd: Path, paths: list[Path], labels: dict[str, str], switch_steps: dict[str, int]
) -> list[dict]:
    """For each scene-change recording: the replay's active expert before and after the change, and its switches
    (`rrd`: the replay's `out_rrd`, which names its decisions file)."""
    records = {key(Path(r["recording"])): r for r in read_decisions(rrd)["recordings"]}
    found = []
    for path in paths:
        record, switch = records[key(path)], switch_steps[key(path)]
        experts = np.asarray(record["experts"])
        before = Counter(experts[:switch].tolist()).most_common(1)[0][0]
        after = Counter(experts[switch:].tolist()).most_common(1)[0][0]
        found.append(
            {
                "recording": path.name,
                "behaviour": labels[key(path)],
                "change_step": switch,
                "expert_before": before,
                "expert_after": after,
                "switches": [(s["step"], s["from"], s["to"]) for s in record["switches"]],
            }
        )
    return found


def free_choice_commitment(
    rrd: Path,
    paths: list[Path],
    recorded: list[Path],
    labels: dict[str, str],
    behaviours: dict[str, dict],
    census: dict,
) -> list[dict]:
    """For each replayed free-choice recording: its scene, the slot picked, the step its carry starts (the
    paths part there), the replay gate's `gate_commitment`, the behaviours whose majority expert the gate ends on
    (`ends_on`; `behaviours`: `expert_purity`'s table), whether one is the behaviour picked (`picked`), and
    `census` (`gate_census` of every held-out free-choice episode); `recorded`: the recorder's files."""
    records = {key(Path(r["recording"])): r for r in read_decisions(rrd)["recordings"]}
    sources = {key(p): p for p in recorded}
    found = []
    for path in paths:
        extra = read_demonstration(sources[key(path)]).episode.extra
        scene, choice = labels[key(path)], extra[CHOICE_KEY]
        committed = gate_commitment(np.asarray(records[key(path)]["gates"]))
        ends_on = [name for name, row in behaviours.items() if row["expert"] == committed["expert"]]
        picked = f"{scene.split('-')[0]}-{choice}"  # the behaviour performed: the cup's side, the slot picked
        found.append(
            {
                "recording": path.name,
                "scene": scene,
                "choice": choice,
                "carry_step": int(extra[CHOICE_STEP_KEY]),
                **committed,
                "ends_on": ends_on,
                "picked": picked in ends_on,
                "census": census,
            }
        )
    return found
