"""Ownership on random histories (tests/pipeline/ownership_machine.py): a user's files beside and inside cnep's outputs,
cnep commands with and without --force, some stopped by a signal at a random moment and run again. Seeded, a few
histories here; `python -m benchmarks ownership` runs many more (the number from CNEP_OWNERSHIP_EXAMPLES and
CNEP_OWNERSHIP_STEPS, the quick demo run whole with CNEP_OWNERSHIP_DEMO=1)."""

from __future__ import annotations

import os

import pytest

from cnep.recordings import write_demonstration
from tests.outputs.test_outputs import dead_pid
from tests.pipeline.ownership_machine import World, run_machine
from tests.pipeline.preloaded import Preloaded
from tests.recordings.factories import demonstration_factory

EXAMPLES = int(os.environ.get("CNEP_OWNERSHIP_EXAMPLES", "4"))
STEPS = int(os.environ.get("CNEP_OWNERSHIP_STEPS", "8"))
DEMO_RUNS = os.environ.get("CNEP_OWNERSHIP_DEMO") == "1"


@pytest.fixture(scope="module")
def server():
    """The server that forks the `cnep` processes the histories stop (tests/pipeline/preloaded.py)."""
    started = Preloaded()
    yield started
    started.close()


def test_no_history_loses_a_user_byte_or_leaves_an_output_half_made(
    motion_world, quick_demo, server, tmp_path, one_thread
):
    big = write_demonstration(tmp_path / "big.mcap", demonstration_factory(200, frames=True, frame_size=128))
    truncated = tmp_path / "truncated.mcap"
    truncated.write_bytes(big.read_bytes()[: int(big.stat().st_size * 0.7)])  # cut in its second chunk
    w = motion_world
    world = World(w.src, w.demos, w.trajs, w.ckpt, truncated, quick_demo, dead_pid())
    (tmp_path / "histories").mkdir()
    seen = run_machine(world, tmp_path / "histories", EXAMPLES, STEPS, server, DEMO_RUNS)
    print(dict(seen))
    ended = {how for command, how in seen if command != "signal sent"}
    assert {"done", "refused"} <= ended and any(command == "signal sent" for command, _ in seen), seen
