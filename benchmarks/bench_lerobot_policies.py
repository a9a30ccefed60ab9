"""LeRobot's ACT and Diffusion Policy trained on the CNEP's demonstrations and run in the CNEP's closed loop.

Run on demand:
    python -m benchmarks lerobot_policies [--run RUN] [--task obstacle] [--policies act,diffusion]
        [--variants features,images] [--steps N | --minutes M] [--episodes 10] [--venv DIR | --python PATH]
        [--device cpu] [--data-workers 0] [--loop-workers 1] [--latency-episodes 2] [--out DIR]

LeRobot runs in a virtual environment of its own (--venv: made with `python3 -m venv` and pip on first use, reused
after): lerobot 0.4.4 pins torch below 2.11 and rerun-sdk below 0.27, cnep needs rerun-sdk 0.41, so one environment
cannot hold both. The venv gets lerobot, MuJoCo and ONNX Runtime, then this repository and its LeRobot plugin
(integrations/lerobot_policy_cnep) without their dependencies: cnep.sim and cnep.runtime import none of cnep's others.
--python names an interpreter that imports all of them already instead (a prepared environment, a GPU machine's).

1. The CNEP's run, `cnep sim TASK --out RUN` (--run reuses one): RUN/demos are the demonstrations the CNEP trained on,
   RUN/trajectories their 1280-d features, RUN/policies the exported CNEP.
2. The datasets, `cnep to-lerobot RUN/demos`: `images` (the camera as video) and `features` (motion only, with the
   trajectories' features as `observation.environment_state` beside the pose: the CNEP's inputs).
3. `lerobot-train` of each policy on each dataset on --device (cpu: one CPU thread), LeRobot's defaults but two: the
   steps (--steps; with --minutes as many as fit in them at the time per step a short run measures; else as many
   passes over these frames as LeRobot's default steps and batch make over REFERENCE_FRAMES) and the data-loading
   worker processes (--data-workers, default none: the training's memory is then one process's peak RSS); ACT's
   image encoder from random weights unless --pretrained-backbone (Diffusion Policy's default); its wall time and the
   seconds per step.
4. The closed loop (benchmarks.lerobot_loop, in the venv): every policy and the CNEP on the run's task, environment
   version and reported episode seeds (its summary.json), online, on one thread per process (--loop-workers
   processes), a LeRobot policy on --device. Off the CPU, --latency-episodes more episodes of each LeRobot policy on
   one CPU thread give its step times (`cpu_ms`), the ones printed and written.
Writes OUT/results.json and OUT/results.csv (a row per policy and condition) and prints, per policy and variant,
success, collisions, behaviour entropy, step time p50/p99, training time and memory, and the training time extrapolated
to LeRobot's default steps (an estimate: seconds per step measured times the steps).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

IN_ALL = False  # `python -m benchmarks all` leaves it out: its defaults train for hours on a CPU
ROOT = Path(__file__).resolve().parents[1]
PLUGIN = ROOT / "integrations" / "lerobot_policy_cnep"
LEROBOT = "lerobot==0.4.4"
VENV_EXTRAS = ("mujoco", "onnxruntime")  # what cnep.sim and cnep.runtime need beside LeRobot's own packages
DEFAULT_STEPS, DEFAULT_BATCH = 100_000, 8  # lerobot.configs.train.TrainPipelineConfig's steps and batch_size
# The frames of the dataset LeRobot's ACT defaults come from (aloha_sim_insertion_human: 50 episodes of 500 frames):
# the default steps at the default batch are 32 passes over it, the passes --steps keeps by default.
REFERENCE_FRAMES = 25_000
# ACT's image encoder starts from ImageNet weights torchvision downloads; offline it starts from random ones, as
# Diffusion Policy's does by default.
RANDOM_BACKBONE = "--policy.pretrained_backbone_weights=null"
ENV_STATE_KEY = "observation.environment_state"
FEATURES = slice(0, 1280)  # the trajectory's feature columns (docs/architecture.md)
STATE = slice(1280, 1288)  # and its pose and gripper: observation.state's entries
# Every policy trains on one CPU thread, as `cnep train` does (models.threads): the same budget for each.
ONE_THREAD = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
TIMING_STEPS = 10  # --minutes: the steps of the run that measures a training step's time
STEP_LOG = re.compile(r"updt_s:([0-9.]+) data_s:([0-9.]+)")  # lerobot-train's log line of a training step's time


IMPORTS = "import lerobot, lerobot_policy_cnep, cnep.runtime, mujoco, onnxruntime"  # what LeRobot's side runs on


def ensure_venv(venv: Path) -> Path:
    """The Python of LeRobot's venv, made and installed if it does not import lerobot and the plugin yet."""
    python = venv / "bin" / "python"
    check = [str(python), "-c", IMPORTS]
    if python.exists() and subprocess.run(check, capture_output=True, cwd="/").returncode == 0:
        return python
    if not python.exists():
        subprocess.run(["python3", "-m", "venv", str(venv)], check=True)
    pip = [str(python), "-m", "pip", "install", "-q"]
    subprocess.run([*pip, LEROBOT, *VENV_EXTRAS], check=True)
    subprocess.run([*pip, "--no-deps", "-e", str(ROOT), "-e", str(PLUGIN)], check=True)
    subprocess.run(check, check=True, cwd="/")
    return python


def cnep(*args: str) -> None:
    """A `cnep` command of this repository's environment, its output shown."""
    subprocess.run([sys.executable, "-m", "cnep.pipeline", *args], check=True)


def features_dataset(run: Path, out: Path) -> int:
    """RUN/demos as a motion-only LeRobot dataset at `out` with `observation.environment_state` (1280,) the
    trajectories' features, each episode matched to its trajectory by the pose; its number of frames."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from cnep.recordings import read_trajectory  # here, not above: a prepared --out needs none of cnep's packages
    from cnep.recordings.lerobot_stats import vector_stats

    cnep("to-lerobot", str(run / "demos"), "--out", str(out), "--camera", "")
    trajectories = [read_trajectory(p, frames=False).data for p in sorted((run / "trajectories").glob("*.mcap"))]
    every = []
    for path in sorted((out / "data").rglob("*.parquet")):
        table = pq.read_table(path)
        episodes = np.asarray(table["episode_index"])
        state = np.stack(table["observation.state"].to_numpy(zero_copy_only=False)).astype(np.float32)
        features = np.empty((len(episodes), FEATURES.stop), np.float32)
        for e in np.unique(episodes):
            rows, data = episodes == e, trajectories[e]
            if len(data) != rows.sum() or not np.allclose(data[:, STATE], state[rows], atol=1e-6):
                raise SystemExit(f"{path}: episode {e} is not trajectory {e} ({len(data)} vs {rows.sum()} steps)")
            features[rows] = data[:, FEATURES]
        column = pa.FixedSizeListArray.from_arrays(pa.array(features.reshape(-1)), FEATURES.stop)
        pq.write_table(table.append_column(ENV_STATE_KEY, column), path)
        every.append(features)
    info_path, stats_path = out / "meta" / "info.json", out / "meta" / "stats.json"
    info, stats = json.loads(info_path.read_text()), json.loads(stats_path.read_text())
    info["features"][ENV_STATE_KEY] = {"dtype": "float32", "shape": [FEATURES.stop], "names": None}
    stats[ENV_STATE_KEY] = {key: value.tolist() for key, value in vector_stats(np.concatenate(every)).items()}
    info_path.write_text(json.dumps(info, indent=4) + "\n")
    stats_path.write_text(json.dumps(stats, indent=4) + "\n")
    return int(info["total_frames"])


def train(python: Path, policy: str, dataset: Path, out: Path, steps: int, options: list[str]) -> dict:
    """lerobot-train of `policy` on `dataset` for `steps` with `options` (lerobot-train's); wall and CPU seconds (its
    start included), seconds per step (lerobot-train's own update and data times, averaged over its log lines), peak
    RSS in MiB, the folder."""
    command = [
        str(python), "-m", "lerobot.scripts.lerobot_train", f"--policy.type={policy}",
        "--policy.push_to_hub=false", f"--dataset.repo_id=local/{dataset.name}", f"--dataset.root={dataset}",
        "--dataset.video_backend=pyav", f"--output_dir={out}", f"--steps={steps}", f"--save_freq={steps}",
        f"--log_freq={max(1, steps // 10)}", "--wandb.enable=false", "--eval_freq=0", *options,
    ]  # fmt: skip
    log = out.parent / f"{out.name}.log"
    start = time.perf_counter()
    with open(log, "w") as sink:
        process = subprocess.Popen(command, stdout=sink, stderr=subprocess.STDOUT, cwd=ROOT, env=ONE_THREAD)
        _, status, usage = os.wait4(process.pid, 0)
    wall = time.perf_counter() - start
    if status != 0:
        raise SystemExit(f"lerobot-train {policy} failed (exit status {status}): see {log}")
    per_step = [float(u) + float(d) for u, d in STEP_LOG.findall(log.read_text())]
    return {
        "steps": steps,
        "wall_s": round(wall, 1),
        "cpu_s": round(usage.ru_utime + usage.ru_stime, 1),
        "s_per_step": round(float(np.mean(per_step)), 4) if per_step else None,
        "peak_mib": round(usage.ru_maxrss / 1024),
        "folder": str(out / "checkpoints" / "last" / "pretrained_model"),
    }


def training_steps(args: argparse.Namespace, python: Path, policy: str, dataset: Path, frames: int, options) -> int:
    """--steps; else with --minutes as many steps as fit in them at the seconds per step a TIMING_STEPS run measures
    (at most LeRobot's passes); else LeRobot's passes over these frames at its default batch."""
    passes = round(DEFAULT_STEPS * frames / REFERENCE_FRAMES)
    if args.steps or not args.minutes:
        return args.steps or passes
    timing = train(python, policy, dataset, args.out / f"timing-{policy}-{dataset.name}", TIMING_STEPS, options)
    steps = min(passes, int(args.minutes * 60 / timing["s_per_step"]))
    print(f"{policy} on {dataset.name}: {timing['s_per_step']} s/step, so {steps} steps in {args.minutes} minutes")
    return steps


def closed_loop(python: Path, args: list[str], out: Path) -> dict:
    """benchmarks.lerobot_loop in LeRobot's venv with `args`; its rates."""
    subprocess.run([str(python), "-m", "benchmarks.lerobot_loop", *args, "--out", str(out)], check=True, cwd=ROOT)
    return json.loads(out.read_text())


def lerobot_python(args: argparse.Namespace) -> Path:
    """--python, checked to import what LeRobot's side needs, else --venv's (made on first use)."""
    if args.python is None:
        return ensure_venv(args.venv)
    if subprocess.run([str(args.python), "-c", IMPORTS], cwd="/").returncode != 0:
        raise SystemExit(f"{args.python}: does not import what the benchmark runs ({IMPORTS})")
    return args.python


def row(name: str, rates: dict, training: dict | None) -> str:
    """One line of the printed table."""
    ms = cpu_ms(rates)
    entropy = "-" if rates.get("entropy") is None else f"{rates['entropy']:.2f}"
    trained = "-" if training is None else f"{training['wall_s']:.0f} s / {training['peak_mib']} MiB"
    return (
        f"{name:<22} {rates['success']:>7.0%} {rates['collision']:>9.0%} {entropy:>7} "
        f"{ms['p50']:>8.1f}/{ms['p99']:<8.1f} {trained}"
    )


CSV_COLUMNS = (
    "policy", "condition", "episodes", "success", "success_lo", "success_hi", "collision", "entropy", "step_ms_p50",
    "step_ms_p99", "train_steps", "train_wall_s", "train_peak_mib",
)  # fmt: skip


def cpu_ms(rates: dict) -> dict:
    """The policy's step time p50 and p99 on one CPU thread: the loop's own, or the timing episodes' off the CPU."""
    ms = rates.get("cpu_ms", rates["ms"])["policy"]
    return {"p50": ms["p50"], "p99": ms["p99"]}


def write_csv(results: dict, path: Path) -> None:
    """One row per policy and condition of `results` (main's), the CSV a results page quotes."""
    lines = [",".join(CSV_COLUMNS)]
    for name, result in results.items():
        t = result.get("training") or {}
        for condition, r in result["rates"].items():
            values = (
                name, condition, r["episodes"], r["success"], *r["success_ci"], r["collision"],
                "" if r.get("entropy") is None else round(r["entropy"], 3), *cpu_ms(r).values(), t.get("steps", ""),
                t.get("wall_s", ""), t.get("peak_mib", ""),
            )  # fmt: skip
            lines.append(",".join(map(str, values)))
    path.write_text("\n".join(lines) + "\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", type=Path, help="a `cnep sim TASK` output folder to reuse (default: one is made)")
    parser.add_argument("--task", default="obstacle", help="the task of the run made without --run")
    parser.add_argument("--policies", default="act,diffusion", help="LeRobot policy types, comma-separated")
    parser.add_argument("--variants", default="features,images", help="features, images or both")
    parser.add_argument("--steps", type=int, help="training steps (default: LeRobot's passes over these frames)")
    parser.add_argument(
        "--minutes", type=float, help="train each policy as many steps as fit in this many minutes (measured first)"
    )
    parser.add_argument("--episodes", type=int, default=10, help="closed-loop episodes per policy (and condition)")
    parser.add_argument(
        "--venv", type=Path, default=ROOT / "runs" / "lerobot-venv", help="LeRobot's virtual environment"
    )
    parser.add_argument("--python", type=Path, help="an interpreter with LeRobot's side installed (instead of --venv)")
    parser.add_argument("--device", default="cpu", help="the torch device LeRobot's policies train and run on")
    parser.add_argument("--data-workers", type=int, default=0, help="lerobot-train's data-loading processes")
    parser.add_argument("--loop-workers", type=int, default=1, help="processes the closed-loop episodes run in")
    parser.add_argument(
        "--latency-episodes", type=int, default=2, help="off the CPU: episodes that time each policy on one CPU thread"
    )
    parser.add_argument("--out", type=Path, default=ROOT / "runs" / "lerobot-policies")
    parser.add_argument(
        "--pretrained-backbone", action="store_true", help="ACT's ImageNet ResNet-18 (downloaded; default: random)"
    )
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    python = lerobot_python(args)
    run = args.run or args.out / "cnep-run"
    if args.run is None and not (run / "policies").is_dir():
        cnep("sim", args.task, "--offline", "--out", str(run), "--episodes", str(args.episodes))
    cnep_policy = sorted((run / "policies").glob("cnep-seed*"))[0]
    summary = json.loads((run / "summary.json").read_text())  # the run's task, environment and reported seeds
    first = str(summary["seeds"]["reported"]["first"])
    loop = [
        *("--task", summary["task"], "--env-version", str(summary["env_version"]), "--episode-seed", first),
        *("--episodes", str(args.episodes), "--workers", str(args.loop_workers)),
    ]
    results = {
        "cnep": {"rates": closed_loop(python, ["--policy", str(cnep_policy), "--cnep", *loop], args.out / "cnep.json")}
    }
    for variant in args.variants.split(","):
        dataset = args.out / f"dataset-{variant}"
        if variant == "features":
            frames = features_dataset(run, dataset) if not dataset.is_dir() else None
        else:
            if not dataset.is_dir():
                cnep("to-lerobot", str(run / "demos"), "--out", str(dataset), "--camera", "front")
            frames = None
        frames = frames or json.loads((dataset / "meta" / "info.json").read_text())["total_frames"]
        for policy in args.policies.split(","):
            name = f"{policy}-{variant}"
            options = [f"--policy.device={args.device}", f"--num_workers={args.data_workers}"]
            options += [] if args.pretrained_backbone or policy != "act" else [RANDOM_BACKBONE]
            steps = training_steps(args, python, policy, dataset, frames, options)
            training = train(python, policy, dataset, args.out / f"train-{name}", steps, options)
            training["default_steps_s_estimate"] = (
                round(training["s_per_step"] * DEFAULT_STEPS) if training["s_per_step"] else None
            )
            results[name] = {"frames": frames, "training": training, "rates": {}}
            (args.out / "results.json").write_text(json.dumps(results, indent=1) + "\n")  # kept if the loop stops
            extra = ["--features-from", str(cnep_policy)] if variant == "features" else []
            loop_args = ["--policy", training["folder"], *extra, *loop, "--device", args.device]
            results[name]["rates"] = closed_loop(python, loop_args, args.out / f"{name}.json")
            if args.device != "cpu":
                timed = [*loop_args[:-1], "cpu", "--episodes", str(args.latency_episodes), "--workers", "1"]
                for condition, rates in closed_loop(python, timed, args.out / f"{name}-cpu.json").items():
                    results[name]["rates"][condition]["cpu_ms"] = rates["ms"]
    print(f"{'policy':<22} {'success':>7} {'collision':>9} {'entropy':>7} {'step ms p50/p99':>17} training")
    for name, result in results.items():
        for condition, rates in result["rates"].items():
            print(row(name if condition == "all" else f"{name} {condition}", rates, result.get("training")))
    for name, result in results.items():
        if "training" in result:
            t = result["training"]
            print(
                f"{name}: {t['steps']} steps on {result['frames']} frames in {t['wall_s']} s ({t['cpu_s']} CPU s), "
                f"{t['s_per_step']} s/step; LeRobot's default {DEFAULT_STEPS} steps at that rate, on this machine as "
                f"loaded during the run: about {t['default_steps_s_estimate']} s (an estimate)"
            )
    (args.out / "results.json").write_text(json.dumps(results, indent=1) + "\n")
    write_csv(results, args.out / "results.csv")


if __name__ == "__main__":
    main()
