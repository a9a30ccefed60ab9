"""The exported policy runs where importing torch fails, and decides as the torch policy does (parity)."""

import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np

from cnep.pipeline.export.policy import checkpoint_policy
from cnep.pipeline.run.stage import observations
from cnep.recordings import read_demonstration
from cnep.runtime import IMAGE_KEY_PREFIX, STATE_KEY, TIMESTAMP_KEY

BLOCK_TORCH = """
import sys
class NoTorch:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in ("torch", "torchvision"):
            raise ImportError(f"{name} is not installed here")
sys.meta_path.insert(0, NoTorch())
"""


# What `pip install ./policy/runtime` leaves out besides torch: the rest of cnep and the MCAP reader.
BLOCK_ALL_BUT_THE_RUNTIME = """
import sys
class RuntimeOnly:
    def find_spec(self, name, path=None, target=None):
        top, _, rest = name.partition(".")
        if top in ("torch", "torchvision", "mcap") or (top == "cnep" and rest and not rest.startswith("runtime")):
            raise ModuleNotFoundError(f"No module named {name!r}")
sys.meta_path.insert(0, RuntimeOnly())
"""
RUN_A_POLICY = Path(__file__).resolve().parents[2] / "docs" / "how-to" / "run-a-policy.md"


def run_without_torch(code: str, cwd: Path, blocker: str = BLOCK_TORCH) -> subprocess.CompletedProcess:
    """`code` in a fresh interpreter in which every import of torch or torchvision (or what `blocker` names) fails."""
    script = blocker + textwrap.dedent(code) + "\nassert 'torch' not in sys.modules\n"
    return subprocess.run([sys.executable, "-c", script], cwd=cwd, capture_output=True, text=True, timeout=300)


def test_the_exported_policy_runs_without_torch_and_matches_the_torch_policy(policy_world, tmp_path):
    """fp32 parity on a held-out recording: every waypoint's position within 1e-4 m, the same expert at every step."""
    steps = list(observations(read_demonstration(policy_world.heldout), policy_world.heldout))
    np.savez(tmp_path / "obs.npz", frames=np.stack([o[IMAGE_KEY_PREFIX + "rgb"] for o in steps]),
             states=np.stack([o[STATE_KEY] for o in steps]), seconds=[o[TIMESTAMP_KEY] for o in steps])  # fmt: skip
    done = run_without_torch(
        f"""
        import numpy as np
        from cnep.runtime import load_policy
        data = np.load("obs.npz")
        out = {{}}
        for precision in ("fp32", "int8"):
            policy = load_policy({str(policy_world.exported)!r}, precision=precision, threads=1)
            results = [
                policy.step({{"observation.images.rgb": f, "observation.state": s, "timestamp": t}})
                for f, s, t in zip(data["frames"], data["states"], data["seconds"])
            ]
            out[precision + "_waypoints"] = np.stack([r.waypoints for r in results])
            out[precision + "_experts"] = np.array([r.expert for r in results])
            out[precision + "_gates"] = np.stack([r.gate for r in results])
        np.savez("out.npz", **out)
        """,
        tmp_path,
    )
    assert done.returncode == 0, done.stderr
    exported = np.load(tmp_path / "out.npz")
    policy = checkpoint_policy(policy_world.checkpoint, policy_world.extractor, backend="eager", threads=1)
    results = [policy.step(o) for o in steps]
    waypoints = np.stack([r.waypoints for r in results])  # (T, W, dy)
    np.testing.assert_allclose(exported["fp32_waypoints"][..., :3], waypoints[..., :3], atol=1e-4, rtol=0)
    np.testing.assert_array_equal(exported["fp32_experts"], [r.expert for r in results])
    np.testing.assert_allclose(exported["fp32_gates"], np.stack([r.gate for r in results]), atol=1e-4)
    # int8 features differ from fp32 ones by about 1%: the same shapes, finite, near the fp32 predictions
    assert np.isfinite(exported["int8_waypoints"]).all()
    spread = np.ptp(waypoints[..., :3])
    assert np.abs(exported["int8_waypoints"][..., :3] - waypoints[..., :3]).max() < 0.5 * spread


def test_importing_the_runtime_needs_no_torch(tmp_path):
    done = run_without_torch("import cnep.runtime; from cnep.runtime import load_policy, Policy", tmp_path)
    assert done.returncode == 0, done.stderr


def test_the_run_a_policy_page_runs_where_only_the_runtime_is_installed(quick_demo, policy_world, tmp_path):
    """The page's blocks that run on the robot (the control loop and its playback without hardware) run where only
    `cnep.runtime` is installed; the block that saves the playback runs where the project is."""
    from mktestdocs import grab_code_blocks

    blocks = grab_code_blocks(RUN_A_POLICY.read_text(), lang="python")
    on_the_project = [b for b in blocks if "cnep.recordings" in b]
    on_the_robot = [b for b in blocks if "run_episode" in b and b not in on_the_project]
    assert len(on_the_project) == 1 and len(on_the_robot) == 2  # the loop, the playback
    (tmp_path / "cnep-demo").symlink_to(quick_demo, target_is_directory=True)
    (tmp_path / "policy").symlink_to(policy_world.exported, target_is_directory=True)
    saved = subprocess.run([sys.executable, "-c", on_the_project[0]], cwd=tmp_path, capture_output=True, text=True)
    assert saved.returncode == 0 and (tmp_path / "playback.npz").is_file(), saved.stderr
    (tmp_path / "cnep-demo").unlink()  # the robot has the policy and the arrays, not the demo
    done = run_without_torch("\n".join(on_the_robot), tmp_path, blocker=BLOCK_ALL_BUT_THE_RUNTIME)
    assert done.returncode == 0, done.stderr
    assert "No module named" not in done.stderr
