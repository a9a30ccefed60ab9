"""Frame to waypoints: a policy's step at 640x480, batch 1, one thread, against the eager PyTorch path.

Run on demand (do not run it next to other heavy work):
    python -m benchmarks.bench_policy [--steps 400] [--checkpoint CKPT --extractor FILE --calibration DEMOS]

Paths, each in its own fresh process (one thread everywhere: torch, ONNX Runtime, OpenCV), each step from
a 640x480 uint8 RGB frame and the 8-d state to the next 10 waypoints with the gate:
    eager       what a LeRobot policy runs: torchvision MobileNet-v2 in eager mode (resize and normalise
                with torchvision, NCHW float), then the torch CNEP (models.OnlineConditioner, its step and
                the 10 waypoints)
    torch       cnep's Policy on the checkpoint (runtime.Policy over the torch model; eager channels-last
                features)
    fp32, int8  cnep's Policy on the exported folder (cnep.runtime, ONNX Runtime), fp32 and int8 features
    features    the exported fp32 feature graph alone, resize included (what bounds the fp32 step)
    model       the exported policy with the feature graph replaced by a constant and 224x224 frames (the
                resize is a copy): the model and the glue alone
and, where OpenVINO is installed, fp32 and int8 on OpenVINO. Reported: p50 and p99 of the step (ms) after
a warm-up, episodes of 40 steps, in wall-clock time and in the step's own thread CPU time (on a loaded
machine the wall clock also counts the time other processes hold the core; with one thread everywhere
the step runs on its calling thread); the import time of the runtime (`import cnep.runtime, onnxruntime`)
against `import torch, torchvision`; the peak resident memory of each process. Every figure also as a
ratio to the eager path measured in the same run, and the issue's targets: fp32 p99 <= 6 ms and <= 0.6x
the eager p99, int8 p99 <= 3 ms, import < 1 s, memory <= 1/3 of the eager path's.

Without --checkpoint it builds a policy of the demo's size (layout scene: 1288 columns observed, pose and
gripper predicted; 4 experts of 128 x 128) from seeded random weights; the cost does not depend on them.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

TARGETS = {"fp32_p99_ms": 6.0, "fp32_vs_eager": 0.6, "int8_p99_ms": 3.0, "import_s": 1.0, "rss_vs_eager": 1 / 3}
EPISODE = 40  # steps per episode (the demo's)
WAYPOINTS = 10
PATHS = ("eager", "torch", "fp32", "int8", "features", "model")
OPENVINO_PATHS = ("fp32-openvino", "int8-openvino")


def frames_and_states(n: int = 10, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(n, 480, 640, 3) uint8 smooth scenes and (EPISODE, 8) states (a slow random walk, unit quaternion)."""
    import cv2

    rng = np.random.default_rng(seed)
    coarse = rng.integers(0, 256, (n, 15, 20, 3)).astype(np.uint8)
    frames = np.stack([cv2.resize(c, (640, 480), interpolation=cv2.INTER_LINEAR) for c in coarse])
    states = np.zeros((EPISODE, 8), np.float32)
    states[:, :3] = np.cumsum(rng.normal(scale=0.01, size=(EPISODE, 3)), axis=0)
    states[:, 6], states[:, 7] = 1.0, 0.5
    return frames, states


def observation(frames: np.ndarray, states: np.ndarray, k: int) -> dict:
    return {
        "observation.images.rgb": frames[k % len(frames)],
        "observation.state": states[k % EPISODE],
        "timestamp": (k % EPISODE) * 0.1,
    }


def eager_step(checkpoint: Path):
    """The LeRobot-style step: torchvision eager features, then the torch CNEP's online step and waypoints."""
    import torch
    from torchvision.models import mobilenet_v2
    from torchvision.transforms.v2 import functional as tvf

    from cnep.models import OnlineConditioner, load_checkpoint
    from cnep.perception.constants import IMAGE_SIZE, IMAGENET_MEAN, IMAGENET_STD

    features = mobilenet_v2(weights=None).features.eval()
    model = load_checkpoint(checkpoint)
    online = OnlineConditioner(model, horizon=EPISODE)

    def step(obs: dict, k: int):
        if k % EPISODE == 0:
            online.reset()
        with torch.inference_mode():
            x = torch.from_numpy(obs["observation.images.rgb"]).permute(2, 0, 1)  # (3, 480, 640) uint8
            x = tvf.resize(x, [IMAGE_SIZE, IMAGE_SIZE], antialias=True).float() / 255.0
            x = tvf.normalize(x, list(IMAGENET_MEAN), list(IMAGENET_STD))
            feats = features(x[None]).mean(dim=(2, 3))[0]  # (1280,)
            row = torch.cat([feats, torch.from_numpy(obs["observation.state"])]).numpy()  # (1288,)
        result = online.step(row)
        online.predict(online.time_of(np.arange(k % EPISODE + 1, k % EPISODE + 1 + WAYPOINTS)))
        return result

    return step


def worker(path: str, checkpoint: Path, extractor: Path, exported: Path, steps: int) -> dict:
    """Time `steps` steps of `path` in this process (after a warm-up episode); its peak memory."""
    import cv2

    cv2.setNumThreads(1)
    start = time.perf_counter()
    if path == "eager":
        import torch

        torch.set_num_threads(1)
        step = eager_step(checkpoint)
    elif path == "torch":
        import torch

        from cnep.pipeline.export.policy import checkpoint_policy

        torch.set_num_threads(1)
        policy = checkpoint_policy(checkpoint, extractor, backend="eager", threads=1, waypoints=WAYPOINTS)
        step = policy_step(policy)
    elif path == "model":
        from cnep.runtime import ExportedNetwork, Policy, read_manifest
        from cnep.runtime.sessions import load_graph

        manifest = read_manifest(exported)
        network = ExportedNetwork(*(load_graph(str(exported / manifest.graphs[g]), threads=1) for g in manifest.graphs))
        constant = np.ones((1, 1280), np.float32)
        policy_only = policy_step(Policy(network, manifest.spec, lambda pixels: constant, waypoints=WAYPOINTS))

        def step(obs: dict, k: int):
            return policy_only({**obs, "observation.images.rgb": obs["observation.images.rgb"][:224, :224]}, k)

    elif path == "features":
        from cnep.runtime.frames import pixel_buffer, resize_frame
        from cnep.runtime.sessions import load_graph

        graph, pixels = load_graph(str(exported / "features.onnx"), threads=1), pixel_buffer(1)

        def step(obs: dict, k: int):
            return graph({"pixels": resize_frame(obs["observation.images.rgb"], pixels[0])[None]})

    else:
        from cnep.runtime import load_policy

        precision, _, backend = path.partition("-")
        policy = load_policy(exported, precision=precision, backend=backend or "onnxruntime", threads=1)
        step = policy_step(policy)
    load_s = time.perf_counter() - start
    frames, states = frames_and_states()
    for k in range(EPISODE):  # warm-up
        step(observation(frames, states, k), k)
    wall, cpu = np.empty(steps), np.empty(steps)
    for k in range(steps):
        obs = observation(frames, states, k)
        before, before_cpu = time.perf_counter(), time.thread_time()
        step(obs, k)
        wall[k], cpu[k] = time.perf_counter() - before, time.thread_time() - before_cpu
    return {
        "p50_ms": float(np.percentile(wall, 50) * 1e3),
        "p99_ms": float(np.percentile(wall, 99) * 1e3),
        "cpu_p50_ms": float(np.percentile(cpu, 50) * 1e3),
        "cpu_p99_ms": float(np.percentile(cpu, 99) * 1e3),
        "rss_mb": peak_rss_mb(),
        "load_s": load_s,
    }


def peak_rss_mb() -> float:
    """This process's peak resident memory (VmHWM; getrusage's maximum would carry the parent's over exec)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    raise RuntimeError("no VmHWM in /proc/self/status (Linux only)")


def policy_step(policy):
    def step(obs: dict, k: int):
        if k % EPISODE == 0:
            policy.reset()
        return policy.step(obs)

    return step


def import_seconds(modules: str, repeats: int = 3) -> float:
    """Median wall seconds of `import <modules>` in a fresh interpreter."""
    code = f"import time; t = time.perf_counter(); import {modules}; print(time.perf_counter() - t)"
    runs = [
        subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True) for _ in range(repeats)
    ]
    return float(np.median([float(done.stdout) for done in runs]))


def synthetic_checkpoint(folder: Path) -> tuple[Path, Path, Path]:
    """A checkpoint of the demo's size from seeded random weights, its extractor and demonstrations (calibration)."""
    import cv2
    import torch

    from cnep.models import CNEPConfig, build_model, save_checkpoint
    from cnep.perception import FeatureExtractor
    from cnep.pipeline.train.presets import resolve_preset
    from cnep.recordings import Demonstration, Episode, write_demonstration
    from cnep.runtime import TimeBase

    torch.set_num_threads(1)
    frames, states = frames_and_states(EPISODE, seed=1)
    extractor = FeatureExtractor("random", backend="onnxruntime", threads=1)
    extractor.calibrate(frames)
    extractor.save_weights(folder / "extractor.pt")
    demos = folder / "demos"
    demos.mkdir()
    jpegs = [cv2.imencode(".jpg", cv2.cvtColor(f, cv2.COLOR_RGB2BGR))[1].tobytes() for f in frames]
    write_demonstration(
        demos / "d0.mcap",
        Demonstration(Episode("d0", fps=10.0), np.arange(EPISODE) * 100_000_000, states[:, :7], states[:, 7], jpegs),
    )
    preset = resolve_preset("scene", 1288, demos / "d0.mcap")
    rows = np.concatenate([extractor(frames), states], axis=1)  # (EPISODE, 1288)
    model = build_model(CNEPConfig(columns=preset.roles, n_experts=4), [rows], seed=0)
    extra = {
        "layout": preset.to_dict(),
        "extractor": extractor.identity,
        "time_base": TimeBase(3.9, 0.1).to_dict(),
    }
    save_checkpoint(model, folder / "ckpt", extra)
    return folder / "ckpt", folder / "extractor.pt", demos


def export(checkpoint: Path, extractor: Path, calibration: Path, out: Path) -> None:
    from cnep.pipeline.export import ExportConfig, export

    export(ExportConfig(checkpoint, out, extractor=extractor, int8=True, calibration=(calibration,), quiet=True))


def target_line(name: str, value: float, target: float, unit: str) -> str:
    """`- name: value unit, met` or `... missed by <distance> unit`."""
    met = "met" if value <= target else f"missed by {value - target:.3g} {unit}"
    return f"- {name}: {value:.3g} {unit}, {met}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=400, help="timed steps per path (after a warm-up episode)")
    parser.add_argument("--checkpoint", type=Path, help="a checkpoint (default: one of the demo's size, random)")
    parser.add_argument("--extractor", type=Path, help="the checkpoint's extractor weights")
    parser.add_argument("--calibration", type=Path, help="demonstrations for the int8 graph's calibration")
    parser.add_argument("--worker", help=argparse.SUPPRESS)
    parser.add_argument("--exported", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        result = worker(args.worker, args.checkpoint, args.extractor, args.exported, args.steps)
        print(json.dumps(result))
        return

    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    with tempfile.TemporaryDirectory(prefix="bench-policy-") as tmp:
        folder = Path(tmp)
        if args.checkpoint is None:
            checkpoint, extractor, calibration = synthetic_checkpoint(folder)
        else:
            checkpoint, extractor, calibration = args.checkpoint, args.extractor, args.calibration
        export(checkpoint, extractor, calibration, folder / "exported")
        paths = [*PATHS, *(OPENVINO_PATHS if _has("openvino") else ())]
        load = os.getloadavg()[0]
        results = {}
        for path in paths:
            command = [sys.executable, "-m", "benchmarks.bench_policy", "--worker", path, "--steps", str(args.steps)]
            command += ["--checkpoint", str(checkpoint), "--extractor", str(extractor)]
            command += ["--exported", str(folder / "exported")]
            done = subprocess.run(command, capture_output=True, text=True, env=env, check=True)
            results[path] = json.loads(done.stdout.strip().splitlines()[-1])
    imports = {"runtime": import_seconds("cnep.runtime, onnxruntime"), "torch": import_seconds("torch, torchvision")}
    report(results, imports, args.steps, load, os.getloadavg()[0])


def _has(module: str) -> bool:
    import importlib.util

    return importlib.util.find_spec(module) is not None


def report(results: dict, imports: dict, steps: int, load_before: float, load_after: float) -> None:
    eager = results["eager"]
    print(
        f"policy step, 640x480 frame -> {WAYPOINTS} waypoints + gate, batch 1, 1 thread, {steps} steps per path; "
        f"load average {load_before:.2f} before, {load_after:.2f} after"
    )
    print(
        "| path | p50 ms | p99 ms | p99 / eager p99 | CPU p50 ms | CPU p99 ms | CPU p99 / eager | peak RSS MB "
        "| RSS / eager | load s |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for path, r in results.items():
        print(
            f"| {path} | {r['p50_ms']:.2f} | {r['p99_ms']:.2f} | {r['p99_ms'] / eager['p99_ms']:.2f}x | "
            f"{r['cpu_p50_ms']:.2f} | {r['cpu_p99_ms']:.2f} | {r['cpu_p99_ms'] / eager['cpu_p99_ms']:.2f}x | "
            f"{r['rss_mb']:.0f} | {r['rss_mb'] / eager['rss_mb']:.2f}x | {r['load_s']:.2f} |"
        )
    ratio = imports["runtime"] / imports["torch"]
    print(f"\nimport cnep.runtime, onnxruntime: {imports['runtime']:.3f} s; import torch, torchvision: "
          f"{imports['torch']:.3f} s ({ratio:.2f}x)")  # fmt: skip
    fp32, int8, features, model = results["fp32"], results["int8"], results["features"], results["model"]
    print(f"the model and the glue alone (constant features, no resize): CPU p50 {model['cpu_p50_ms']:.3f} ms, "
          f"p99 {model['cpu_p99_ms']:.3f} ms; wall p50 {model['p50_ms']:.3f} ms")  # fmt: skip
    rel, rss = fp32["p99_ms"] / eager["p99_ms"], fp32["rss_mb"] / eager["rss_mb"]
    cpu_rel = fp32["cpu_p99_ms"] / eager["cpu_p99_ms"]
    print(f"\ntargets (wall clock; in CPU time: fp32 p99 {fp32['cpu_p99_ms']:.2f} ms, {cpu_rel:.2f}x the eager "
          f"path's, int8 p99 {int8['cpu_p99_ms']:.2f} ms):")  # fmt: skip
    print(target_line(f"fp32 p99 <= {TARGETS['fp32_p99_ms']} ms", fp32["p99_ms"], TARGETS["fp32_p99_ms"], "ms"))
    print(target_line(f"fp32 p99 <= {TARGETS['fp32_vs_eager']}x the eager p99", rel, TARGETS["fp32_vs_eager"], "x"))
    print(target_line(f"int8 p99 <= {TARGETS['int8_p99_ms']} ms", int8["p99_ms"], TARGETS["int8_p99_ms"], "ms"))
    print(target_line(f"import < {TARGETS['import_s']} s", imports["runtime"], TARGETS["import_s"], "s"))
    print(target_line("peak memory <= 1/3 of the eager path's", rss, TARGETS["rss_vs_eager"], "x"))
    print(
        f"what bounds the fp32 step: the feature graph alone takes {features['cpu_p50_ms']:.2f} ms CPU p50, "
        f"{features['cpu_p99_ms']:.2f} ms CPU p99 ({features['cpu_p50_ms'] / fp32['cpu_p50_ms']:.0%} of the step's)"
    )


if __name__ == "__main__":
    main()
