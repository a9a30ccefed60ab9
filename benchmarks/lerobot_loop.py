"""A trained LeRobot policy (or an exported CNEP) in the project's closed loop, run inside LeRobot's environment.

    python -m benchmarks.lerobot_loop --policy DIR --task obstacle --env-version 1 --episodes 10 --episode-seed 5000 \
        --out rates.json [--features-from CNEP_POLICY_DIR] [--cnep] [--device cpu] [--workers 1]

bench_lerobot_policies runs this with the Python of LeRobot's environment, where lerobot and torch 2.10 import and the
project is installed without its dependencies (cnep.sim and cnep.runtime need none of them). Every policy runs
through cnep.sim.episode.run_episode on the task's environment, its seeds and its online protocol, scored by the
task's rates per condition (success, collisions, the side taken, behaviour entropy, the policy's step time p50/p99),
on one torch thread. A LeRobot policy acts as LeRobot runs it: `select_action` each step, a new chunk of actions
computed when the last one is spent (ACT, Diffusion Policy), and that step's time counted, on --device (cpu: one CPU
thread's time). --workers runs the episodes in that many processes, each on one thread, each episode with its own
seed as in one process, and scores them together.

--features-from: the features variant. The policy read `observation.environment_state`, the 1280-d features of the
CNEP's own feature network, which this computes from each frame with the CNEP's exported graph (the CNEP's
`features.onnx`, as the CNEP itself runs), beside the state.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from cnep.runtime import STATE_KEY, STATE_NAMES, load_policy
from cnep.runtime.exported import load_features
from cnep.runtime.frames import pixel_buffer, resize_frame
from cnep.sim.episode import ONLINE, run_episode
from cnep.sim.tasks import find_task

ENV_STATE_KEY = "observation.environment_state"  # LeRobot's key of a vector describing the scene


@dataclass(frozen=True)
class Read:
    """What the episode driver reads of a step (cnep.runtime.PolicyStep's fields it uses): waypoints (1, 8) the next
    action, gate (1,) and expert 0 (one behaviour model, no experts)."""

    waypoints: np.ndarray
    gate: np.ndarray
    expert: int


class LerobotPolicy:
    """A LeRobot policy folder (lerobot-train's `pretrained_model`) with the interface the episode driver steps
    (cnep.sim.episode: reset, step, action_names, gripper, n_experts); `features`: the CNEP's feature function for the
    features variant, None for the images variant (the frame goes in as LeRobot's image)."""

    action_names = tuple(STATE_NAMES)  # the action is the whole next state, the gripper as recorded
    gripper = None
    n_experts = 1

    def __init__(self, folder: Path, features=None, device: str = "cpu") -> None:
        from lerobot.configs.policies import PreTrainedConfig
        from lerobot.policies.factory import get_policy_class, make_pre_post_processors

        config = PreTrainedConfig.from_pretrained(folder)
        config.device = device
        self.policy = get_policy_class(config.type).from_pretrained(folder, config=config).eval()
        self.pre, self.post = make_pre_post_processors(
            config, pretrained_path=str(folder), preprocessor_overrides={"device_processor": {"device": device}}
        )
        self.images = [key for key in config.input_features if key.startswith("observation.images.")]
        self.features, self._pixels = features, pixel_buffer(1)

    def reset(self, seed: int | None = None) -> None:
        self.policy.reset()
        if seed is not None:
            torch.manual_seed(seed)  # Diffusion Policy's noise: the same episode on the same seed

    @torch.no_grad()
    def step(self, observation: dict) -> Read:
        batch = {STATE_KEY: torch.from_numpy(observation[STATE_KEY][None])}  # (1, 8)
        for key in self.images:
            frame = torch.from_numpy(observation[key]).permute(2, 0, 1)[None]  # (1, 3, H, W) uint8
            batch[key] = frame.float() / 255.0
        if self.features is not None:
            frame = next(v for k, v in observation.items() if k.startswith("observation.images."))
            resize_frame(frame, self._pixels[0])
            batch[ENV_STATE_KEY] = torch.from_numpy(self.features(self._pixels))  # (1, 1280)
        action = self.post(self.policy.select_action(self.pre(batch)))  # (1, 8), on the CPU after the postprocessor
        return Read(waypoints=action.cpu().numpy().astype(np.float32), gate=np.ones(1), expert=0)


def episodes(args: argparse.Namespace, seeds: list[int]) -> dict:
    """The rows of the episodes of `seeds` per condition ("all" for a task without), in this process."""
    torch.set_num_threads(1)
    task = find_task(args.task, args.env_version)
    if args.cnep:
        policy = load_policy(args.policy, threads=1, waypoints=task.max_steps)
    else:
        features = load_features(args.features_from, threads=1) if args.features_from else None
        policy = LerobotPolicy(args.policy, features, args.device)
    rows = {}
    for condition in task.conditions or (None,):  # the pick-and-place scenes: decided, free, changed
        env = task.make_env(condition, task.max_steps)
        try:
            rows[condition or "all"] = [task.row(run_episode(env, policy, seed, ONLINE)) for seed in seeds]
        finally:
            env.close()
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", type=Path, required=True, help="lerobot-train's pretrained_model, or a CNEP export")
    parser.add_argument("--cnep", action="store_true", help="--policy is a `cnep export` folder")
    parser.add_argument("--features-from", type=Path, help="the CNEP export whose feature graph makes the features")
    parser.add_argument("--task", default="obstacle")
    parser.add_argument("--env-version", type=int, required=True, help="the version of the task's environment")
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--episode-seed", type=int, default=0)
    parser.add_argument("--device", default="cpu", help="the torch device a LeRobot policy runs on (default cpu)")
    parser.add_argument("--workers", type=int, default=1, help="processes the episodes are shared out to (default 1)")
    parser.add_argument("--out", type=Path, required=True, help="the rates as JSON")
    args = parser.parse_args()
    parts = shared_out(list(range(args.episode_seed, args.episode_seed + args.episodes)), args.workers)
    if len(parts) == 1:
        rows = [episodes(args, parts[0])]
    else:  # spawned, not forked: a CUDA context or a renderer does not survive a fork
        with multiprocessing.get_context("spawn").Pool(len(parts)) as pool:
            rows = pool.starmap(episodes, [(args, part) for part in parts])
    task = find_task(args.task, args.env_version)
    results = {condition: task.rates(together) for condition, together in merged(rows).items()}
    args.out.write_text(json.dumps(results, indent=1) + "\n")


def shared_out(seeds: list[int], workers: int) -> list[list[int]]:
    """`seeds` dealt out to at most `workers` processes in turn (none left empty), so each gets early and late ones."""
    return [seeds[i::workers] for i in range(min(workers, len(seeds)))]


def merged(parts: list[dict]) -> dict:
    """The rows of every process's `episodes` per condition, in the order of their seeds."""
    return {
        condition: sorted((r for part in parts for r in part[condition]), key=lambda r: r["seed"])
        for condition in parts[0]
    }


if __name__ == "__main__":
    main()
