import gc
import os
import subprocess
import sys
import weakref
from pathlib import Path

import numpy as np
import pytest
import torch
from safetensors.torch import load_file
from torch import distributed as dist

from cnep.models import load_checkpoint, read_checkpoint_config
from cnep.pipeline.cli.main import main
from cnep.pipeline.train import stage
from cnep.pipeline.train.parallel import PlacedModel, Processes
from cnep.recordings import read_trajectory
from tests.pipeline.test_train import stage_config, write_set

pytestmark = pytest.mark.usefixtures("one_thread")  # tiny models run on one thread

ARGS = [
    "--steps",
    "20",
    "--val-every",
    "10",
    "--warmup-steps",
    "5",
    "--batch-size",
    "8",
    "--encoder-widths",
    "16,16",
    "--expert-widths",
    "16,16",
    "--save-every",
    "10",
    "--seed",
    "3",
]


@pytest.mark.slow  # ~20 s on 2 busy cores: three processes import torch
def test_two_process_torchrun_trains_a_loadable_checkpoint(tmp_path):
    paths = write_set(tmp_path / "data")
    out = tmp_path / "runs" / "ddp"
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(Path(__file__).parents[2])}
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "torch.distributed.run",
            "--standalone",
            "--nproc_per_node=2",
            "-m",
            "cnep.pipeline",
            "-q",
            "train",
            str(tmp_path / "data"),
            "--out",
            str(out),
            "--layout",
            "motion",
            *ARGS,
        ],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.count("best validation error") == 1  # only rank 0 reports
    assert [p.name for p in out.parent.iterdir()] == ["ddp"]  # only rank 0 wrote, and nothing is left over
    config = read_checkpoint_config(out)
    assert config["training"]["world_size"] == 2 and config["training"]["batch_size_total"] == 16
    model = load_checkpoint(out)
    prediction = model.generate(np.array([0.0]), read_trajectory(paths[0]).data[:1, 1280:], np.linspace(0, 1, 4))
    assert prediction.mean.shape == (4, 8) and np.isfinite(prediction.mean).all()

    # One process with the same seed: rank 0 draws exactly its batches, so equal weights would mean rank 1
    # contributed nothing new (averaging identical gradients changes nothing).
    alone = tmp_path / "alone"
    assert main(["-q", "train", str(tmp_path / "data"), "--out", str(alone), "--layout", "motion", *ARGS]) == 0
    single = read_checkpoint_config(alone)
    schedule = single["training"]["schedule"]  # its batch: the samples a step draws over every process
    schedule = {**schedule, "inputs": {**schedule["inputs"], "batch_size": 16}}
    assert {**single["training"], "world_size": 2, "batch_size_total": 16, "schedule": schedule} == config["training"]
    assert single["model"] == config["model"]
    two, one = load_file(out / "model.safetensors"), load_file(alone / "model.safetensors")
    assert any(not torch.equal(two[k], one[k]) for k in one)


def test_training_frees_its_ddp_wrapper_before_the_interpreter_exits(tmp_path, monkeypatch):
    """A wrapper left in a reference cycle is collected at interpreter exit, where gloo's threads abort the process.

    Rank 0 of a real gloo group of one process, whose model is told it is one of two so that it is wrapped in
    DistributedDataParallel; the cyclic garbage collector is off, so only reference counts free it.
    """
    wrappers = []

    class Recorded(torch.nn.parallel.DistributedDataParallel):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            wrappers.append(weakref.ref(self))

    dist.init_process_group("gloo", init_method=f"file://{tmp_path / 'store'}", rank=0, world_size=1)
    two = Processes(rank=0, world_size=2)
    monkeypatch.setattr(stage, "PlacedModel", lambda model, device, procs: PlacedModel(model, device, two))
    monkeypatch.setattr(torch.nn.parallel, "DistributedDataParallel", Recorded)
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        stage.train(stage_config(write_set(tmp_path / "data"), tmp_path / "out", steps=20))
    finally:
        if was_enabled:
            gc.enable()
        if dist.is_initialized():
            dist.destroy_process_group()
    assert len(wrappers) == 1 and wrappers[0]() is None
