"""What a policy's time base costs when the robot runs slower or faster than the demonstrations.

    python examples/policy_timebase.py POLICY RECORDING... [--speeds 1.0 1.2 0.8]

POLICY is an exported folder (`cnep export`); RECORDING demonstration files or folders with frames (e.g.
a demo's held-out demonstrations). Each recording is replayed at each duration factor s (1.2: the run
takes 20 % longer than the recording, 0.8: 20 % less): the camera keeps the recording's frame rate, so a
run of s times the duration has s times the frames; at run time tau the robot is where the recording
was at tau / s (pose and gripper interpolated linearly, the nearest frame). Each run goes through the
policy twice:
    time base   what a robot does: phase = tau / the demonstrations' median duration (the manifest's)
    oracle      the phase the run really is at: tau / (s x the recording's duration)
and the table gives, over all steps of all recordings: the RMSE (cm) of the first predicted waypoint
against where the run is at the next step, the share of steps whose active expert is the oracle's, and
the switches per run.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from cnep.pipeline.inputs import find_demonstration_files
from cnep.recordings import Demonstration, read_demonstration
from cnep.runtime import IMAGE_KEY_PREFIX, STATE_KEY, TIMESTAMP_KEY, Policy, TimeBase, load_policy
from cnep.runtime.frames import decode_frame


def resampled(demo: Demonstration, factor: float) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """The run at `factor` times the recording's duration: run times (s), states (n, 8), frame indices."""
    seconds = (demo.timestamps_ns - demo.timestamps_ns[0]) / 1e9  # (T,)
    period = float(np.median(np.diff(seconds)))
    run = np.arange(0.0, factor * seconds[-1] + 1e-9, period)  # (n,)
    source = run / factor  # where the recording was at each run step
    state = np.concatenate([demo.pose, demo.gripper[:, None]], axis=1)  # (T, 8)
    states = np.stack([np.interp(source, seconds, state[:, j]) for j in range(8)], axis=1)  # (n, 8)
    states[:, 3:7] /= np.linalg.norm(states[:, 3:7], axis=1, keepdims=True)
    frames = [int(np.abs(seconds - s).argmin()) for s in source]
    return run, states.astype(np.float32), frames


def replay(policy: Policy, demo: Demonstration, run: np.ndarray, states: np.ndarray, frames: list[int]):
    """Step the run through `policy`; (first waypoints (n, dy), experts (n,), switches)."""
    policy.reset()
    decoded = {k: decode_frame(demo.frames[k]) for k in set(frames)} if policy.uses_camera else {}
    waypoints, experts, switches = [], [], 0
    for k, tau in enumerate(run):
        observation = {STATE_KEY: states[k], TIMESTAMP_KEY: float(tau)}
        if policy.uses_camera:
            observation[IMAGE_KEY_PREFIX + "rgb"] = decoded[frames[k]]
        result = policy.step(observation)
        waypoints.append(result.waypoints[0])
        experts.append(result.expert)
        switches += result.switch is not None
    return np.array(waypoints), np.array(experts), switches


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("policy", type=Path, help="an exported policy folder")
    parser.add_argument("recordings", nargs="+", type=Path, help="demonstration files or folders with frames")
    parser.add_argument("--speeds", type=float, nargs="+", default=[1.0, 1.2, 0.8], help="duration factors")
    args = parser.parse_args(argv)
    paths = find_demonstration_files(args.recordings)
    demos = [read_demonstration(p) for p in paths]
    policy = load_policy(args.policy, threads=1, waypoints=1)
    xyz = [policy.action_names.index(name) for name in ("x", "y", "z")]
    rows = []
    print(f"{len(demos)} recordings; the time base's duration {policy.time_base.duration_s:.2f} s")
    print("| duration factor | time base | waypoint RMSE (cm) | expert as the oracle's | switches per run |")
    print("|---|---|---|---|---|")
    for factor in args.speeds:
        errors = {"time base": [], "oracle": []}
        agree, switches = [], {"time base": 0, "oracle": 0}
        for demo in demos:
            run, states, frames = resampled(demo, factor)
            duration = factor * (demo.timestamps_ns[-1] - demo.timestamps_ns[0]) / 1e9
            oracle = load_policy(args.policy, threads=1, waypoints=1, time_base=TimeBase(duration, run[1] - run[0]))
            experts = {}
            for name, p in (("time base", policy), ("oracle", oracle)):
                waypoints, experts[name], n = replay(p, demo, run, states, frames)
                errors[name].append(waypoints[:-1, xyz] - states[1:, :3])  # against the next step's position
                switches[name] += n
            agree.append(experts["time base"] == experts["oracle"])
        for name in ("time base", "oracle"):
            rmse = 100 * float(np.sqrt(np.mean(np.concatenate(errors[name]) ** 2)))
            same = float(np.mean(np.concatenate(agree))) if name == "time base" else 1.0
            rows.append({"factor": factor, "time_base": name, "rmse_cm": rmse, "same_expert": same,
                         "switches": switches[name] / len(demos)})  # fmt: skip
            print(f"| {factor:.2f} | {name} | {rmse:.2f} | {same:.1%} | {switches[name] / len(demos):.2f} |")
    return rows


if __name__ == "__main__":
    main()
