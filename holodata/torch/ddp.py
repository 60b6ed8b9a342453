"""Data-parallel training on torch's own engine (``torch.distributed`` + ``DistributedDataParallel``).

``holodata train`` started by ``torchrun --nproc-per-node N`` finds torchrun's environment
(``RANK``, ``WORLD_SIZE``, ``LOCAL_RANK``, ``MASTER_ADDR``/``MASTER_PORT``) and joins a process
group: gloo on CPU, NCCL on CUDA (each process on ``cuda:LOCAL_RANK``). What stays as in one
process:

* **the global batch**: every rank draws the same seeded permutation of the training set; rank r
  of N takes samples r, r+N, … of each global batch of ``batch_size``, so the union of one
  step's local batches is the one-process batch (``batch_size`` must divisible by N). Sample
  augmentation is keyed by (seed, epoch, sample) (:class:`holodata.torch.data.EpochAugment`), so
  a sample is cropped and rolled the same on whichever rank reads it.
* **the step**: DDP averages the ranks' gradients, i.e. the gradient of the mean of their local
  batch losses — the one-process loss up to how the masked means weigh pixels between the two
  halves of a batch (equal when each half has as many returns).
* **the seed and the logs**: the per-epoch metrics are sums over all ranks.
* **one writer**: only rank 0 writes checkpoints and logs; stage two (not data-parallel) runs on
  rank 0 alone.

Without torchrun's environment (``WORLD_SIZE`` unset or 1) everything here is a no-op.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from datetime import timedelta

import torch
import torch.distributed as dist

from holodata.errors import InputError


@dataclass(frozen=True)
class Ddp:
    """This process's place in the group: ``rank`` of ``world`` processes, ``local_rank`` on its node."""

    rank: int = 0
    world: int = 1
    local_rank: int = 0

    @property
    def enabled(self) -> bool:
        return self.world > 1

    @property
    def main(self) -> bool:
        """The process that writes checkpoints and logs and prints."""
        return self.rank == 0


def from_env() -> Ddp:
    """The group torchrun described in the environment (a single process when it did not)."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    return Ddp(int(os.environ.get("RANK", "0")), world, int(os.environ.get("LOCAL_RANK", "0")))


def setup(device: str, batch_size: int) -> tuple[Ddp, str]:
    """Join torchrun's process group (once per process) and return it with this rank's device:
    ``cuda`` becomes ``cuda:LOCAL_RANK``. InputError when ``batch_size`` does not split evenly."""
    ctx = from_env()
    if not ctx.enabled:
        return ctx, device
    if batch_size % ctx.world:
        raise InputError(f"batch size {batch_size} does not split over {ctx.world} processes "
                         f"(the global batch is kept: give a multiple of {ctx.world})")
    cuda = device.startswith("cuda")
    if cuda:
        device = f"cuda:{ctx.local_rank}"
        torch.cuda.set_device(ctx.local_rank)
    if not dist.is_initialized():
        # a long timeout: rank 0 alone may write checkpoints or run stage two while others wait
        dist.init_process_group("nccl" if cuda else "gloo", timeout=timedelta(hours=6))
    return ctx, device


def wrap(model: torch.nn.Module, ctx: Ddp, device: str) -> torch.nn.Module:
    """``model`` under DistributedDataParallel when the group has several processes."""
    if not ctx.enabled:
        return model
    dev = torch.device(device)
    ids = [dev.index] if dev.type == "cuda" else None
    return torch.nn.parallel.DistributedDataParallel(model, device_ids=ids)


def local_batches(order: list[int], batch_size: int, ctx: Ddp) -> list[list[int]]:
    """This rank's share of each global batch of ``order`` (sample indices, already shuffled):
    ``batch[rank::world]``. A last global batch with fewer samples than processes is dropped
    (every rank must step together); with one process nothing is dropped."""
    batches = [order[i:i + batch_size] for i in range(0, len(order), batch_size)]
    if ctx.enabled and batches and len(batches[-1]) < ctx.world:
        batches = batches[:-1]
    return [b[ctx.rank::ctx.world] for b in batches]


def sum_over_ranks(sums: dict[str, float], ctx: Ddp) -> dict[str, float]:
    """Key-wise sum of every rank's ``sums`` (ranks may hold different keys)."""
    if not ctx.enabled:
        return sums
    everyone: list = [None] * ctx.world
    dist.all_gather_object(everyone, sums)
    total: dict[str, float] = {}
    for part in everyone:
        for k, v in part.items():
            total[k] = total.get(k, 0.0) + float(v)
    return total


def barrier(ctx: Ddp) -> None:
    if ctx.enabled:
        dist.barrier()


def close(ctx: Ddp) -> None:
    """Leave the process group (after the data-parallel part of a run)."""
    if ctx.enabled and dist.is_initialized():
        dist.destroy_process_group()
