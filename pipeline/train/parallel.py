"""Devices and torchrun for the train stage: one process, or DistributedDataParallel when torchrun started us.

Under `torchrun --nproc_per_node=N` (environment RANK, WORLD_SIZE, LOCAL_RANK, MASTER_ADDR/PORT) each
process joins a process group (gloo on CPU, nccl on CUDA), wraps the model in
DistributedDataParallel (gradients averaged over ranks at every step) and draws its own batches from
a generator seeded by its rank, out of its own share of the demonstrations (`share`: every world-size-th
one of the training, and of the validation, demonstrations, from its rank on: a pure function of the file
list, the same on every rank without coordination). Each rank reads and holds only its share; the
normaliser's statistics and the validation error are combined over the ranks, so best-model keeping and
early stopping agree on every rank. Only rank 0 writes the checkpoint.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import distributed as dist

from cnep.models import CNEP
from cnep.pipeline.errors import USER_ERRORS, PipelineError
from cnep.pipeline.train.constants import DEVICES

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Processes:
    """Where this process stands: its global rank, the number of processes and its rank on this machine."""

    rank: int = 0
    world_size: int = 1
    local_rank: int = 0

    @property
    def distributed(self) -> bool:
        return self.world_size > 1

    @property
    def is_main(self) -> bool:
        return self.rank == 0


def start_processes(device: str) -> tuple[Processes, torch.device]:
    """Join torchrun's process group if there is one; returns this process's place and its torch device."""
    if device not in DEVICES:
        raise PipelineError(f"unknown device {device!r}; choose one of {', '.join(DEVICES)}")
    if device == "cuda" and not torch.cuda.is_available():
        raise PipelineError("--device cuda was asked for but torch sees no CUDA device here; use --device cpu")
    world_size = int(os.environ.get("WORLD_SIZE", "1"))
    if world_size == 1:
        return Processes(), torch.device(device)
    procs = Processes(int(os.environ["RANK"]), world_size, int(os.environ.get("LOCAL_RANK", "0")))
    if device == "cuda":
        torch.cuda.set_device(procs.local_rank)
    dist.init_process_group(backend="nccl" if device == "cuda" else "gloo")
    log.info("rank %d of %d (local rank %d) on %s", procs.rank, world_size, procs.local_rank, device)
    return procs, torch.device(device, procs.local_rank) if device == "cuda" else torch.device("cpu")


def stop_processes(procs: Processes, wait: bool) -> None:
    """Leave the process group; with `wait`, only once every rank got there (rank 0 has written the checkpoint)."""
    if procs.distributed and dist.is_initialized():
        if wait:
            dist.barrier()
        dist.destroy_process_group()


def barrier(procs: Processes) -> None:
    """Wait until every rank got here (nothing without torchrun)."""
    if procs.distributed:
        dist.barrier()


def rank_seed(seed: int, rank: int) -> int:
    """Seed of rank `rank`'s batch generator: rank 0 keeps `seed` (a 1-process run is the plain run)."""
    return seed if rank == 0 else int(np.random.SeedSequence([seed, rank]).generate_state(1)[0])


def share(indices: Sequence[int], procs: Processes) -> list[int]:
    """Rank `procs.rank`'s share of `indices`: every world-size-th from its rank on; all of them where there are
    fewer than ranks (each rank then validates, or trains, on every one: `disjoint` says which)."""
    return list(indices[procs.rank :: procs.world_size]) if disjoint(indices, procs) else list(indices)


def disjoint(indices: Sequence[int], procs: Processes) -> bool:
    """Whether the ranks' shares of `indices` (`share`) are disjoint: there are at least as many as ranks."""
    return len(indices) >= procs.world_size


def mean_over_ranks(procs: Processes, value: float) -> float:
    """The mean of `value` over the ranks (itself without torchrun); one all-reduce in float64."""
    if not procs.distributed:
        return value
    on = torch.device("cuda", torch.cuda.current_device()) if dist.get_backend() == "nccl" else torch.device("cpu")
    total = torch.tensor([value], dtype=torch.float64, device=on)
    dist.all_reduce(total)
    return float(total.item()) / procs.world_size


def from_main(procs: Processes, work: Callable[[], Any]) -> Any:
    """Run `work` on rank 0 only and hand its result to every rank; a user error there is raised on every rank.

    Used for what touches the output folder (checks, the resumable state), so that other ranks never
    wait forever for a rank 0 that stopped on an error, and need no shared file system.
    """
    if not procs.distributed:
        return work()
    box: list[Any] = [None]
    if procs.is_main:
        try:
            box[0] = ("ok", work())
        except USER_ERRORS as exc:
            box[0] = ("error", str(exc))
            dist.broadcast_object_list(box, src=0)
            raise
    dist.broadcast_object_list(box, src=0)
    status, value = box[0]
    if status == "error":
        raise PipelineError(f"rank 0 stopped: {value}")
    return value


def gather(procs: Processes, value: Any) -> list[Any]:
    """`value` of every rank, in rank order (a list of one without torchrun)."""
    if not procs.distributed:
        return [value]
    out: list[Any] = [None] * procs.world_size
    dist.all_gather_object(out, value)
    return out


def any_rank_signal(procs: Processes, signum: int | None) -> int | None:
    """The signal any rank received (this rank's own if it has one), so that every rank stops after the same step;
    one all-reduce of a number per call under torchrun."""
    if not procs.distributed:
        return signum
    on = torch.device("cuda", torch.cuda.current_device()) if dist.get_backend() == "nccl" else torch.device("cpu")
    flag = torch.tensor([signum or 0], device=on)
    dist.all_reduce(flag, op=dist.ReduceOp.MAX)
    return signum or (int(flag.item()) or None)


class PlacedModel:
    """The CNEP as `models.Trainer` drives it: run on `device`, through DistributedDataParallel under torchrun.

    The Trainer draws batches on the CPU (seeded) and moves them to the parameters' device, where the
    forward pass and the loss run. Everything else (parameters, state_dict, gate, config) is the CNEP's own, so
    checkpoints and the Trainer's best state carry no DDP prefix.
    """

    def __init__(self, model: CNEP, device: torch.device, procs: Processes) -> None:
        self.cnep = model.to(device)
        self.net: torch.nn.Module = self.cnep
        if procs.distributed:  # rank 0's parameters and buffers are broadcast at construction
            ids = [device.index] if device.type == "cuda" else None
            self.net = torch.nn.parallel.DistributedDataParallel(self.cnep, device_ids=ids)

    def __call__(
        self,
        obs: torch.Tensor,
        obs_mask: torch.Tensor,
        query: torch.Tensor,
        latent: bool = False,
        keep: torch.Tensor | None = None,
    ):
        return self.net(obs, obs_mask, query, latent, keep)

    def train(self, mode: bool = True) -> PlacedModel:
        self.net.train(mode)
        return self

    def eval(self) -> PlacedModel:
        return self.train(False)

    def __getattr__(self, name: str) -> Any:  # only called for names this wrapper lacks
        if name == "cnep":  # not set yet (e.g. while copying): no recursion
            raise AttributeError(name)
        return getattr(self.cnep, name)
