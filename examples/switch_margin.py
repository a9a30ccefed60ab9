"""When should the active expert change? The demo's online gates under each switch margin and window.

    python examples/switch_margin.py DEMO_DIR [--scene-changes N] [--seed S] [--work DIR]

DEMO_DIR is a folder made by `cnep demo --out DEMO_DIR`. The replay conditions on the recorded steps, so its gate
does not depend on which expert is active: the gate traces are computed once (pipeline.demo.measures.online_gates)
and each rule (runtime.conditioning.hand_over, the argmax at the first step) is applied to them. Traces:

    scene change    the demo's scene-change recording and N new ones (the demo's generator, seed S, extracted with
                    DEMO_DIR/extractor.pt into --work): the block moves once the cup is lifted; latency = the first
                    switch at or after the change's step, minus that step (a recording that never switches counts
                    its steps left)
    held-out        the demo's held-out recordings: nothing changes, one behaviour from start to end
    free choice     the demo's held-out free-choice recordings: both slots free, the slot picked at the carry step,
                    so the recorded motion may leave the gate's first read once (a switch the evidence asks for)

Prints one row per rule: the latencies' sum, how many scene changes switch later than under the argmax, the demo's
own scene change's latency, the switches in the held-out and free-choice recordings (and the recordings with any),
and the free-choice switches beyond one per recording that ends on another expert than it starts on.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from cnep.pipeline.cli.main import main as cnep
from cnep.pipeline.demo.generator import SWITCH_KEY, DemoSetConfig, generate
from cnep.pipeline.demo.measures import online_gates
from cnep.pipeline.demo.stage import EXTRACTOR_FILE
from cnep.recordings import read_demonstration
from cnep.runtime.conditioning import ConditioningPolicy, hand_over

RULES = [(0.0, 0)] + [(m, w) for m in (0.1, 0.2, 0.3, 0.4, 0.5) for w in (0, 2, 3, 4)]  # (switch_margin, window)
STEPS = 40  # the full demo's episode length (pipeline.demo.config.FULL)


def active(gates: np.ndarray, policy: ConditioningPolicy) -> np.ndarray:
    """(T,) the active expert over a (T, d) gate trace under `policy`, from the argmax at step 0."""
    experts = [int(gates[0].argmax())]
    for k in range(1, len(gates)):
        experts.append(hand_over(policy, gates[max(0, k - policy.switch_window) : k + 1], experts[-1]))
    return np.array(experts)


def switches(experts: np.ndarray) -> np.ndarray:
    return np.flatnonzero(experts[1:] != experts[:-1]) + 1


def latency(experts: np.ndarray, change: int) -> int:
    later = [s for s in switches(experts) if s >= change]
    return int(later[0] - change) if later else len(experts) - change


def scene_changes(demo: Path, n: int, seed: int, work: Path) -> tuple[list[Path], list[int]]:
    """The demo's scene-change trajectories and `n` new ones (generated and extracted into `work` once), and the
    step of each one's change."""
    recorded, trajectories = work / "recorded", work / "trajectories"
    if n and not trajectories.is_dir():
        generate(DemoSetConfig(recorded, 0, 0, n, STEPS, seed=seed, quiet=True))
        code = cnep(["-q", "extract", str(recorded / "scene_change"), "--out", str(trajectories),
                     "--weights", str(demo / EXTRACTOR_FILE)])  # fmt: skip
        if code != 0:
            raise SystemExit(f"cnep extract exited {code}")
    pairs = [(p, recorded / "scene_change" / p.name) for p in sorted(trajectories.glob("*.mcap"))] if n else []
    own = sorted((demo / "trajectories" / "scene_change").glob("*.mcap"))  # the demo's own goes last
    pairs += [(p, demo / "recorded" / "scene_change" / p.name) for p in own]
    return [t for t, _ in pairs], [int(read_demonstration(r).episode.extra[SWITCH_KEY]) for _, r in pairs]


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("demo", type=Path, help="a folder made by `cnep demo`")
    parser.add_argument("--scene-changes", type=int, default=40, help="new scene-change recordings (default 40)")
    parser.add_argument("--seed", type=int, default=1000, help="their generator's seed (default 1000)")
    parser.add_argument("--work", type=Path, default=None, help="where they go (default DEMO_DIR/switch-margin)")
    args = parser.parse_args(argv)
    checkpoint = args.demo / "checkpoints" / "cnep"
    paths, changes = scene_changes(args.demo, args.scene_changes, args.seed, args.work or args.demo / "switch-margin")
    traces = {"change": online_gates(checkpoint, paths)}
    for split in ("heldout", "free_choice"):
        traces[split] = online_gates(checkpoint, sorted((args.demo / "trajectories" / split).glob("*.mcap")))
    base = [latency(active(g, ConditioningPolicy(switch_margin=0.0)), c) for g, c in zip(traces["change"], changes)]
    print(f"{len(changes)} scene changes, {len(traces['heldout'])} held-out, {len(traces['free_choice'])} free choice")
    print(
        "| margin | window | latency sum (steps) | later than the argmax | the demo's | held-out switches "
        "(recordings) | free-choice switches (recordings) | beyond one |"
    )
    print("|---|---|---|---|---|---|---|---|")
    rows = []
    for margin, window in RULES:
        policy = ConditioningPolicy(switch_margin=margin, switch_window=window)
        lat = [latency(active(g, policy), c) for g, c in zip(traces["change"], changes)]
        runs = {split: [active(g, policy) for g in traces[split]] for split in ("heldout", "free_choice")}
        count = {split: [len(switches(e)) for e in runs[split]] for split in runs}
        beyond = sum(n - (e[0] != e[-1]) for n, e in zip(count["free_choice"], runs["free_choice"]))
        later = sum(a > b for a, b in zip(lat, base))
        row = {"margin": margin, "window": window, "latency": sum(lat), "later": later, "demo": lat[-1]}
        row |= {"heldout": count["heldout"], "free_choice": count["free_choice"], "beyond": beyond}
        rows.append(row)
        print(
            f"| {margin:.1f} | {window} | {sum(lat)} | {later} of {len(lat)} | {lat[-1]} | "
            f"{sum(count['heldout'])} ({sum(map(bool, count['heldout']))}) | "
            f"{sum(count['free_choice'])} ({sum(map(bool, count['free_choice']))}) | {beyond} |"
        )
    return rows


if __name__ == "__main__":
    main()
