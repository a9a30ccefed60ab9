import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from safetensors.torch import load_file

from models import load_checkpoint, read_checkpoint_config
from pipeline.cli.main import main
from recordings import read_trajectory
from tests.pipeline.test_train import write_set

pytestmark = pytest.mark.usefixtures("one_thread")  # tiny models run on one thread

ARGS = ["--steps", "20", "--val-every", "10", "--warmup-steps", "5", "--batch-size", "8", "--encoder-widths", "16,16",
        "--expert-widths", "16,16", "--save-every", "10", "--seed", "3"]


@pytest.mark.slow  # ~20 s on 2 busy cores: three processes import torch
def test_two_process_torchrun_trains_a_loadable_checkpoint(tmp_path):
    paths = write_set(tmp_path / "data")
    out = tmp_path / "runs" / "ddp"
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(Path(__file__).parents[2])}
    done = subprocess.run([sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=2",
                           "-m", "pipeline", "-q", "train", str(tmp_path / "data"), "--out", str(out),
                           "--layout", "motion", *ARGS], env=env, capture_output=True, text=True, timeout=120)
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
    assert {**single["training"], "world_size": 2, "batch_size_total": 16} == config["training"]
    assert single["model"] == config["model"]
    two, one = load_file(out / "model.safetensors"), load_file(alone / "model.safetensors")
    assert any(not torch.equal(two[k], one[k]) for k in one)
