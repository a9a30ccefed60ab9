"""Where is the demo's first read lost? Probes on the step-0 features and latents, the gate's read, its calibration.

    python examples/first_read.py DEMO_DIR [DEMO_DIR ...] [--extra N] [--json OUT] [--csv OUT]

Each DEMO_DIR is a folder made by `cnep demo --seed N --out DEMO_DIR`. Conditioned on the first step (t = 0) of a
held-out scene, its models should follow the behaviour the scene calls for. On the held-out scenes' first steps
(labels from the recorder's files) this measures how well each stage keeps the behaviours apart:

    features ridge, 1-NN  probes on the 1280 step-0 features: ridge regression onto one-hot targets (lambda RIDGE)
                          and the nearest neighbour, fitted on the first rows of the scene-decided training
                          demonstrations, standardised with those rows' mean and std; side, slot: the ridge probe
                          on the cup side and on the free slot alone
    latent ridge, 1-NN    the same probes on each model's latent r (its encoder on the step-0 context)
    CNEP gate             the gate's choice at step 0, right when it is the expert that takes the scene's
                          behaviour (pipeline.demo.measures.expert_purity, as in the demo's summary)
    path                  a model's motion generated from step 0 reads right when the training demonstration
                          nearest it shows the scene's behaviour (measures.nearest_behaviour: the demo's summary
                          counts the other scenes as read wrong)
    calibration           over every first read: the gate's largest probability p on wrong and on right reads,
                          the share of wrong reads at p >= CONFIDENT, and the shares of wrong and of right reads
                          that the replay shows unsure (p < SURE_GATE)
    motion / images       conditioned on every step of a held-out scene whose motion (every column but the image
                          features) is that of a training demonstration of another behaviour: the share of such
                          conflicts where the gate names the motion's expert, and where it names the images'

--extra N adds N new scenes per behaviour, drawn by the demo's generator from the demo's seed (its checkpoints
record it) on a stream the demo never drew from; only their first frame is rendered, and extracted with the
folder's extractor.pt as the demo's extract stage does. Each accuracy is then printed as "held-out / extra",
and the calibration pools both. Prints one markdown row per folder, then the mean over the folders (a
calibration mean leaves out folders with no wrong read); --json OUT writes every number per folder, --csv OUT the
per-folder table (docs/results/first-read.csv).
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from cnep.models import CNEP
from cnep.outputs import write_atomically
from cnep.perception import compatibility_key
from cnep.pipeline.demo.generator import SPLITS, make_demonstration
from cnep.pipeline.demo.measures import (
    expert_purity,
    first_step_prediction,
    gate_of,
    key,
    nearest_behaviour,
    recorded_labels,
    recorded_paths,
)
from cnep.pipeline.demo.scene import BEHAVIOURS, behaviour_parts
from cnep.pipeline.demo.stage import EXTRACTOR_FILE
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.extract.stage import ExtractConfig, build_extractor, features_of_frames
from cnep.pipeline.inputs import DEMONSTRATIONS, mcap_files
from cnep.pipeline.replay.viewer import SURE_GATE
from cnep.pipeline.train.checkpoint import TrainedModel, load_trained
from cnep.recordings import Trajectory, read_trajectory
from cnep.recordings.constants import BLOCK_FEATURES

# Small against a standardised row's squared norm (its width): near the least-squares fit of least norm, so the
# probe finds whatever a linear read of the rows separates.
RIDGE = 1.0
CONFIDENT = 0.9  # a read at this gate probability or more is a confident one
MODELS = ("CNEP", "CNMP")  # the demo's models, in checkpoints/<name in lower case>
NEEDED = ("recorded", "demos/train", "trajectories/train", "trajectories/heldout", EXTRACTOR_FILE)


@dataclass(frozen=True)
class Scenes:
    """The first steps of a set of scenes: each one's trajectory (the whole recording or its first step only), its
    source (the file, or what names an extra scene; for errors), its behaviour, and T, the steps of the motion
    generated for it."""

    trajectories: list[Trajectory]
    sources: list[Path]
    labels: np.ndarray  # (N,) behaviour names
    steps: int

    def first_rows(self, trained: TrainedModel) -> np.ndarray:
        """(N, model width) float32: each scene's step-0 row in the model's columns."""
        return np.stack([trained.rows(t, p)[0] for t, p in zip(self.trajectories, self.sources)])

    def features(self) -> np.ndarray:
        """(N, 1280) float32: each scene's step-0 features."""
        return np.stack([t.features[0] for t in self.trajectories])


def standardised(train: np.ndarray, *others: np.ndarray) -> list[np.ndarray]:
    """Rows (n, k) centred and scaled by the training rows' mean and std; a column (near) constant over the training
    rows becomes 0 everywhere (it tells the probes nothing, and scaling it up would only amplify noise)."""
    mean, std = train.mean(0), train.std(0)
    std = np.where(std > 1e-6 * std.max(), std, np.inf)
    return [(x - mean) / std for x in (train, *others)]


def ridge_probe(x: np.ndarray, y: np.ndarray, test: np.ndarray) -> np.ndarray:
    """The labels (m,) a ridge regression onto one-hot targets gives rows `test` (m, k), fitted on rows `x` (n, k, zero
    mean) with labels `y` (n,). Solved in the dual (n x n), as there are far fewer rows than columns."""
    classes = np.unique(y)
    onehot = (y[:, None] == classes[None]).astype(np.float64)  # (n, C)
    prior = onehot.mean(0)  # (C,): the intercept
    alpha = np.linalg.solve(x @ x.T + RIDGE * np.eye(len(x)), onehot - prior)  # (n, C)
    return classes[(test @ (x.T @ alpha) + prior).argmax(1)]


def nearest_probe(x: np.ndarray, y: np.ndarray, test: np.ndarray) -> np.ndarray:
    """The label (m,) of each test row's nearest training row (Euclidean): x (n, k), y (n,), test (m, k)."""
    distance = (test**2).sum(1)[:, None] - 2 * test @ x.T + (x**2).sum(1)[None]  # (m, n), squared
    return y[distance.argmin(1)]


PROBES: dict[str, Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]] = {
    "ridge": ridge_probe,
    "1nn": nearest_probe,
}


def probe_accuracy(train: np.ndarray, labels: np.ndarray, tests: dict[str, tuple[np.ndarray, np.ndarray]]) -> dict:
    """{probe: {set: accuracy}}: each probe fitted on the standardised `train` rows (n, k) with `labels` (n,) and
    scored on each set's (rows (m, k), labels (m,))."""
    x, *scaled = standardised(train, *(rows for rows, _ in tests.values()))
    return {
        name: {
            s: float(np.mean(probe(x, labels, rows) == truth))
            for s, rows, (_, truth) in zip(tests, scaled, tests.values())
        }
        for name, probe in PROBES.items()
    }


@torch.inference_mode()
def latents(model: CNEP, first: np.ndarray) -> np.ndarray:
    """The latent r (N, H) of `model` conditioned on each step-0 row (N, model width) alone, at t = 0."""
    values = torch.as_tensor(first[:, model.obs_columns.numpy()])  # (N, obs)
    obs = model.prepare(torch.zeros(len(first)), values, model.obs_columns)  # (N, 1 + obs)
    return model.encode(obs[:, None], torch.ones(len(first), 1, dtype=torch.bool)).numpy()  # (N, H)


def first_reads(trained: TrainedModel, first: np.ndarray, steps: int, train: Scenes) -> tuple[np.ndarray, np.ndarray]:
    """For each step-0 row (N, model width): the gate (N, d) and how the motion generated over `steps` steps reads
    (N,) (the behaviour of the nearest of the `train` demonstrations)."""
    xyz = trained.mapping.predicted_xyz(trained.model)
    train_paths = recorded_paths(trained, [trained.rows(t, p) for t, p in zip(train.trajectories, train.sources)])
    gates, reads = [], []
    for row in first:
        prediction = first_step_prediction(trained.model, row[None], steps)
        gates.append(prediction.gate)
        reads.append(nearest_behaviour(prediction.mean[:, xyz], train_paths, list(train.labels)))
    return np.stack(gates), np.array(reads)


def calibration(gates: np.ndarray, right: np.ndarray) -> dict:
    """How sure the gate (N, d) is of its reads, right (N,) bool or not: the largest probability p on wrong and on
    right reads, the share of wrong reads at p >= CONFIDENT, the shares of wrong and of right reads below SURE_GATE
    (None where there is no such read)."""
    p, wrong = gates.max(1), ~right

    def mean(values: np.ndarray) -> float | None:
        return float(values.mean()) if len(values) else None

    return {
        "reads": len(p),
        "wrong": int(wrong.sum()),
        "p_wrong": mean(p[wrong]),
        "p_right": mean(p[right]),
        "confident_wrong": mean(p[wrong] >= CONFIDENT),
        "unsure_wrong": mean(p[wrong] < SURE_GATE),
        "unsure_right": mean(p[right] < SURE_GATE),
    }


def extra_scenes(folder: Path, seed: int, per_behaviour: int, like: Trajectory) -> Scenes:
    """`per_behaviour` new scenes of each behaviour with as many steps and the frame rate of `like`, drawn by the
    demo's generator from `seed`; their first frame extracted with the folder's extractor, as the demo's extract
    stage does (an int8 folder is quantised on its training frames)."""
    stream = np.random.SeedSequence(seed).spawn(len(SPLITS) + 1)[-1]  # the demo's splits take the first spawns
    K = len(BEHAVIOURS)
    demos = [
        make_demonstration(
            i % K, like.n_steps, like.episode.fps, np.random.default_rng(s), f"extra/demo_{i:03d}", rendered=1
        )
        for i, s in enumerate(stream.spawn(per_behaviour * K))
    ]
    weights = folder / EXTRACTOR_FILE
    config = ExtractConfig(
        inputs=(), out=folder, weights=str(weights), threads=1, precision=like.extractor.get("precision", "fp32")
    )
    extractor = build_extractor(config, mcap_files(folder / "demos" / "train", DEMONSTRATIONS))
    if compatibility_key(extractor.identity) != compatibility_key(like.extractor):
        raise PipelineError(
            f"{weights}: its features are not those of the folder's trajectories ({like.extractor.get('weights')}); "
            f"measure a folder as `cnep demo` left it"
        )
    features = features_of_frames([d.frames[0] for d in demos], extractor, weights)  # (N, 1280)
    return Scenes(
        [Trajectory.from_demonstration(d, f[None], extractor.identity) for d, f in zip(demos, features)],
        [folder / d.episode.episode_id for d in demos],
        np.array([BEHAVIOURS[i % K] for i in range(len(demos))]),
        like.n_steps,
    )


def read_scenes(paths: list[Path], labels: dict[str, str]) -> Scenes:
    """The trajectory files `paths` with their behaviours (`labels`, by measures.key)."""
    trajectories = [read_trajectory(p) for p in paths]
    return Scenes(trajectories, paths, np.array([labels[key(p)] for p in paths]), trajectories[0].n_steps)


def load_models(folder: Path) -> dict[str, TrainedModel]:
    """The demo's CNEP and CNMP; refused when a model's queries carry features (it reads more than step 0)."""
    found = {}
    for name in MODELS:
        trained = load_trained(folder / "checkpoints" / name.lower())
        if trained.model.config.columns.query_dim:
            raise PipelineError(
                f"{trained.path}: its queries carry each step's inputs; this measures models that read the scene "
                f"from step 0 alone, as the demo's do"
            )
        found[name] = trained
    return found


def feature_probes(train: Scenes, sets: dict[str, Scenes]) -> dict:
    """The probes on the step-0 features: {"ridge", "1nn": the behaviours; "side", "slot": the ridge probe on the cup
    side and on the free slot alone}, each {set: accuracy}."""

    def parts(scenes: Scenes, part: int) -> np.ndarray:  # part 0: the cup side, 1: the free slot
        return np.array([behaviour_parts(BEHAVIOURS.index(b))[part] for b in scenes.labels])

    features = {s: scenes.features() for s, scenes in sets.items()}  # (N, 1280) each
    found = probe_accuracy(train.features(), train.labels, {s: (features[s], v.labels) for s, v in sets.items()})
    for part, name in enumerate(("side", "slot")):
        tests = {s: (features[s], parts(v, part)) for s, v in sets.items()}
        found[name] = probe_accuracy(train.features(), parts(train, part), tests)["ridge"]
    return found


def model_reads(models: dict[str, TrainedModel], train: Scenes, sets: dict[str, Scenes], experts: dict) -> dict:
    """Per model the probes on its latent and its path reads, and the CNEP gate's reads (right when its expert is
    `experts[behaviour]`) and calibration over all of them."""
    found: dict = {"latent": {}, "path": {}}
    gates, gate_right = [], []
    for name, trained in models.items():
        first = {s: v.first_rows(trained) for s, v in sets.items()}  # (N, model width) each
        tests = {s: (latents(trained.model, first[s]), v.labels) for s, v in sets.items()}
        found["latent"][name] = probe_accuracy(latents(trained.model, train.first_rows(trained)), train.labels, tests)
        found["path"][name] = {}
        for s, scenes in sets.items():
            gate, reads = first_reads(trained, first[s], scenes.steps, train)
            found["path"][name][s] = float(np.mean(reads == scenes.labels))
            if name == "CNEP":
                gates.append(gate)
                gate_right.append(gate.argmax(1) == np.array([experts[b] for b in scenes.labels]))
    found["gate"] = {s: float(right.mean()) for s, right in zip(sets, gate_right)}
    found["calibration"] = calibration(np.concatenate(gates), np.concatenate(gate_right))
    return found


def motion_or_images(trained: TrainedModel, train: Scenes, heldout: Scenes, experts: dict) -> dict:
    """Whom the CNEP gate follows when a scene's images and its motion disagree: each held-out scene conditioned on
    all its steps, with the motion (the model's columns outside the image features) of the first training
    demonstration of each other behaviour -> {"motion", "images": the share of those conflicts where the gate names
    the motion's behaviour's expert, the images'}."""
    model, (a, b) = trained.model, trained.mapping.blocks[BLOCK_FEATURES]
    donors = {}
    for t, p, label in zip(train.trajectories, train.sources, train.labels):
        donors.setdefault(label, trained.rows(t, p))
    named = []  # (expert the gate names, the motion's expert, the images' expert)
    for t, p, label in zip(heldout.trajectories, heldout.sources, heldout.labels):
        rows = trained.rows(t, p)
        for other, motion in donors.items():
            if other == label:
                continue
            T = min(len(rows), len(motion))
            mixed = np.concatenate([motion[:T, :a], rows[:T, a:b], motion[:T, b:]], axis=1)
            named.append((int(gate_of(model, mixed).argmax()), experts[other], experts[label]))
    chosen, motion_expert, images_expert = np.array(named).T
    return {"motion": float(np.mean(chosen == motion_expert)), "images": float(np.mean(chosen == images_expert))}


def check_folder(folder: Path) -> None:
    """Refuse a folder that lacks what `cnep demo` leaves and this reads."""
    needed = (*NEEDED, *(f"checkpoints/{m.lower()}" for m in MODELS))
    missing = [name for name in needed if not (folder / name).exists()]
    if missing:
        raise PipelineError(f"{folder}: no {', '.join(missing)}; give a folder made by `cnep demo --out`")


def measure(folder: Path, extra: int) -> dict:
    """Every number of one demo folder (see the module docstring; `check_folder` first), with `extra` new scenes per
    behaviour."""
    start = time.perf_counter()
    labels = recorded_labels(folder / "recorded")
    models = load_models(folder)
    seed = int(models["CNEP"].config["training"]["seed"])  # the demo trains with its own seed
    train_files = sorted((folder / "trajectories" / "train").glob("*.mcap"))
    decided = [p for p in train_files if labels[key(p)] in BEHAVIOURS]  # free-choice scenes have no behaviour
    heldout = sorted((folder / "trajectories" / "heldout").glob("*.mcap"))
    train = read_scenes(decided, labels)
    sets = {"heldout": read_scenes(heldout, labels)}
    if extra:
        sets["extra"] = extra_scenes(folder, seed, extra, sets["heldout"].trajectories[0])
    behaviours = expert_purity(models["CNEP"].path, decided + heldout, labels)  # as the demo's summary
    experts = {b: row["expert"] for b, row in behaviours.items()}
    follows = motion_or_images(models["CNEP"], train, sets["heldout"], experts)
    return {
        "demo": str(folder),
        "seed": seed,
        "n": {"train": len(decided), **{s: len(v.labels) for s, v in sets.items()}},
        "experts": {
            "of": experts,
            "distinct": len(set(experts.values())),
            "purity_min": min(row["purity"] for row in behaviours.values()),
        },
        "features": feature_probes(train, sets),
        **model_reads(models, train, sets, experts),
        "gate_follows": follows,
        "seconds": round(time.perf_counter() - start, 1),
    }


# The table: header -> the numbers of a folder's cell (one per scene set, or as the header names them).
COUNTS = "gate wrong / reads"  # the one column of counts: summed, not averaged, in the mean row
COLUMNS: dict[str, Callable[[dict], list]] = {
    "features ridge": lambda f: list(f["features"]["ridge"].values()),
    "features 1-NN": lambda f: list(f["features"]["1nn"].values()),
    "features side": lambda f: list(f["features"]["side"].values()),
    "features slot": lambda f: list(f["features"]["slot"].values()),
    "CNEP latent ridge": lambda f: list(f["latent"]["CNEP"]["ridge"].values()),
    "CNEP latent 1-NN": lambda f: list(f["latent"]["CNEP"]["1nn"].values()),
    "CNMP latent ridge": lambda f: list(f["latent"]["CNMP"]["ridge"].values()),
    "CNMP latent 1-NN": lambda f: list(f["latent"]["CNMP"]["1nn"].values()),
    "CNEP gate": lambda f: list(f["gate"].values()),
    "CNEP path": lambda f: list(f["path"]["CNEP"].values()),
    "CNMP path": lambda f: list(f["path"]["CNMP"].values()),
    COUNTS: lambda f: [f["calibration"]["wrong"], f["calibration"]["reads"]],
    "gate p, wrong / right": lambda f: [f["calibration"]["p_wrong"], f["calibration"]["p_right"]],
    f"wrong at p >= {CONFIDENT}": lambda f: [f["calibration"]["confident_wrong"]],
    f"unsure (p < {SURE_GATE}), wrong / right": lambda f: [
        f["calibration"]["unsure_wrong"],
        f["calibration"]["unsure_right"],
    ],
    "gate follows motion / images": lambda f: [f["gate_follows"]["motion"], f["gate_follows"]["images"]],
}


def cell(values: list) -> str:
    """Numbers joined by " / ": counts as they are, shares to 2 decimals, - for None."""
    return " / ".join("-" if v is None else f"{v}" if isinstance(v, int) else f"{v:.2f}" for v in values)


def mean_cells(rows: list[dict]) -> list[str]:
    """The mean over folders of each column's numbers (None left out); the read counts are summed."""
    cells = []
    for header, numbers in COLUMNS.items():
        columns = list(zip(*(numbers(f) for f in rows)))
        if header == COUNTS:
            cells.append(cell([sum(c) for c in columns]))
        else:
            cells.append(
                cell([float(np.mean(known)) if (known := [v for v in c if v is not None]) else None for c in columns])
            )
    return cells


def csv_names(header: str, values: int) -> list[str]:
    """The CSV columns of one table column of `values` numbers: "features ridge" -> "features ridge (held-out)",
    "features ridge (extra)"; "gate p, wrong / right" -> "gate p, wrong", "gate p, right"."""
    if " / " in header:
        left, right = header.split(" / ")
        return [left, f"{left.rsplit(' ', 1)[0]} {right}"]
    return [header] if values == 1 else [f"{header} (held-out)", f"{header} (extra)"]


def csv_table(rows: list[dict]) -> str:
    """The per-folder table as CSV: a `seed` column, then one column per number (empty for None)."""
    header = ["seed"] + [n for h, numbers in COLUMNS.items() for n in csv_names(h, len(numbers(rows[0])))]
    lines = [",".join(f'"{name}"' if "," in name else name for name in header)]
    for f in rows:
        values = [v for numbers in COLUMNS.values() for v in numbers(f)]
        lines.append(
            ",".join(
                [str(f["seed"])] + ["" if v is None else f"{v}" if isinstance(v, int) else f"{v:.2f}" for v in values]
            )
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("demos", nargs="+", type=Path, help="folders made by `cnep demo --out`")
    parser.add_argument("--extra", type=int, default=0, help="new scenes per behaviour to read too (default 0)")
    parser.add_argument("--json", type=Path, help="write every number per folder to this file")
    parser.add_argument("--csv", type=Path, help="write the per-folder table to this CSV file (docs/results/)")
    args = parser.parse_args(argv)
    if args.extra < 0:
        parser.error(f"--extra must be >= 0, got {args.extra}")
    for folder in args.demos:  # all of them before the first one's work
        try:
            check_folder(folder)
        except PipelineError as exc:
            parser.error(str(exc))
    torch.set_num_threads(1)
    sets = "held-out / extra scenes" if args.extra else "held-out scenes"
    print(f"accuracies on the {sets}; the gate's calibration over all its reads")
    print("| seed | " + " | ".join(COLUMNS) + " |")
    print("|---" * (len(COLUMNS) + 1) + "|")
    found = []
    for folder in args.demos:
        found.append(measure(folder, args.extra))
        print(
            f"| {found[-1]['seed']} | " + " | ".join(cell(numbers(found[-1])) for numbers in COLUMNS.values()) + " |",
            flush=True,
        )
    print(f"| mean ({len(found)}) | " + " | ".join(mean_cells(found)) + " |")
    print(f"{len(found)} folder(s) in {sum(f['seconds'] for f in found):.0f} s")
    if args.json:
        write_atomically(args.json, json.dumps(found, indent=1).encode())
    if args.csv:
        write_atomically(args.csv, csv_table(found).encode())
    return found


if __name__ == "__main__":
    main()
