"""Does the exported policy decide as the torch policy does? Both stepped through the same recordings.

    python examples/policy_parity.py CHECKPOINT EXPORTED RECORDING... [--extractor FILE]

CHECKPOINT is a folder of `cnep train`, EXPORTED its `cnep export` folder, RECORDING demonstration files or
folders with frames (e.g. a demo's held-out demonstrations). The torch policy (the checkpoint on
PyTorch, features by the eager torch network) and the exported one (ONNX Runtime, fp32 and, where the
folder has it, int8 features) take the same observations step by step, each recording from a new
episode. Printed per precision: the steps, the largest and the 99th percentile difference of the
predicted waypoints' positions (m, over all 10 waypoints of every step), the largest gate difference,
and at how many steps the active expert and the switches differ.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from cnep.pipeline.export.policy import checkpoint_policy
from cnep.pipeline.inputs import find_demonstration_files
from cnep.pipeline.run.stage import observations
from cnep.recordings import read_demonstration
from cnep.runtime import load_policy, read_manifest


def main(argv: list[str] | None = None) -> dict[str, dict]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint", type=Path)
    parser.add_argument("exported", type=Path)
    parser.add_argument("recordings", nargs="+", type=Path)
    parser.add_argument("--extractor", type=Path, help="the checkpoint's extractor weights (None: ImageNet)")
    args = parser.parse_args(argv)
    reference = checkpoint_policy(args.checkpoint, args.extractor, backend="eager", threads=1)
    exported = {p: load_policy(args.exported, precision=p, threads=1) for p in read_manifest(args.exported).features}
    xyz = [reference.action_names.index(name) for name in ("x", "y", "z")]
    found = {p: {"steps": 0, "xyz": [], "gate": 0.0, "expert": 0, "switch": 0} for p in exported}
    paths = find_demonstration_files(args.recordings)
    for path in paths:
        for policy in (reference, *exported.values()):
            policy.reset()
        for observation in observations(read_demonstration(path), path):
            a = reference.step(observation)
            for precision, policy in exported.items():
                b, f = policy.step(observation), found[precision]
                f["steps"] += 1
                f["xyz"].append(np.abs(a.waypoints[:, xyz] - b.waypoints[:, xyz]).max())
                f["gate"] = max(f["gate"], float(np.abs(a.gate - b.gate).max()))
                f["expert"] += a.expert != b.expert
                f["switch"] += (a.switch is None) != (b.switch is None)
    print(f"{len(paths)} recordings")
    print(
        "| precision | steps | waypoint xyz max diff (m) | p99 (m) | gate max diff | expert differs | switch differs |"
    )
    print("|---|---|---|---|---|---|---|")
    for precision, f in found.items():
        diffs = np.array(f["xyz"])
        f["xyz_max"], f["xyz_p99"] = float(diffs.max()), float(np.percentile(diffs, 99))
        print(f"| {precision} | {f['steps']} | {f['xyz_max']:.3g} | {f['xyz_p99']:.3g} | {f['gate']:.3g} | "
              f"{f['expert']} | {f['switch']} |")  # fmt: skip
    return found


if __name__ == "__main__":
    main()
