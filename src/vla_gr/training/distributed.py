"""torchrun / DDP plumbing: process group, device, seeding, a resumable DistributedSampler.

The same script runs single-process or under ``torchrun --nproc_per_node=N`` (which sets
``RANK``, ``WORLD_SIZE``, ``LOCAL_RANK``, ``MASTER_ADDR``, ``MASTER_PORT``): NCCL on GPU,
gloo on CPU. Logging and checkpoints happen on rank 0 only. Set up first by
``vla_gr.train`` (once for a whole staged recipe); ``training/data.py`` builds its sampler;
:func:`rank_share` splits a stage's episodes over the ranks.
"""

from __future__ import annotations

import contextlib
import datetime
import logging
import os
import random
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import torch
import torch.distributed as dist
from torch.utils.data import Dataset, DistributedSampler

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class DistInfo:
    """Where this process sits in the job."""

    rank: int = 0
    world_size: int = 1
    local_rank: int = 0
    device: torch.device = torch.device("cpu")
    backend: str | None = None  # None when not distributed

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    @property
    def distributed(self) -> bool:
        return self.world_size > 1


def resolve_device(preference: str, local_rank: int = 0) -> torch.device:
    """``auto`` -> ``cuda:<local_rank>`` when CUDA is available, else ``cpu``."""
    if preference == "cpu":
        return torch.device("cpu")
    if preference == "cuda" or (preference == "auto" and torch.cuda.is_available()):
        if not torch.cuda.is_available():
            raise ValueError(
                "training.device=cuda but CUDA is not available; use training.device=cpu"
            )
        return torch.device("cuda", local_rank)
    return torch.device("cpu")


def local_device(preference: str) -> torch.device:
    """:func:`resolve_device` for this process's GPU under torchrun (``LOCAL_RANK``)."""
    return resolve_device(preference, int(os.environ.get("LOCAL_RANK", "0")))


def setup_distributed(device: str = "auto", backend: str = "auto") -> DistInfo:
    """Initialise the process group when launched by torchrun; pick this rank's device."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    rank = int(os.environ.get("RANK", "0"))
    local_rank = int(os.environ.get("LOCAL_RANK", "0"))
    dev = resolve_device(device, local_rank)
    if world <= 1:
        return DistInfo(device=dev)
    if backend == "auto":
        backend = "nccl" if dev.type == "cuda" else "gloo"
    if backend == "nccl" and dev.type != "cuda":
        raise ValueError("training.ddp_backend=nccl needs CUDA; use gloo (or auto) on CPU")
    if dev.type == "cuda":
        torch.cuda.set_device(dev)
    if not dist.is_initialized():
        dist.init_process_group(backend=backend, rank=rank, world_size=world)
    log.info("rank %d/%d on %s (%s)", rank, world, dev, backend)
    return DistInfo(rank, world, local_rank, dev, backend)


@contextlib.contextmanager
def process_group(device: str = "auto", backend: str = "auto") -> Iterator[DistInfo]:
    """:func:`setup_distributed` for the block; the process group is destroyed at its end only
    when the block made it (a staged recipe sets it up once for all of its stages)."""
    made = not (dist.is_available() and dist.is_initialized())
    info = setup_distributed(device, backend)
    try:
        yield info
    finally:
        if made:
            cleanup_distributed()


def process_rank() -> tuple[int, int]:
    """(rank, world size) of this process in the initialised process group, else (0, 1)."""
    if dist.is_available() and dist.is_initialized():
        return dist.get_rank(), dist.get_world_size()
    return 0, 1


def is_main_process() -> bool:
    """Whether this process writes logs and outputs (rank 0, or no process group)."""
    return process_rank()[0] == 0


def rank_share(first: int, count: int, rank: int, world: int) -> range:
    """Rank ``rank``'s contiguous share of items ``first .. first + count - 1``: the shares of
    ranks 0 .. world - 1 follow one another, the first ``count % world`` one item longer."""
    if not 0 <= rank < world:
        raise ValueError(f"rank={rank} must be in [0, {world})")
    size, extra = divmod(count, world)
    start = first + rank * size + min(rank, extra)
    return range(start, start + size + (rank < extra))


def cleanup_distributed() -> None:
    """Destroy the process group if one is initialised."""
    global _WAIT_GROUP
    if dist.is_available() and dist.is_initialized():
        dist.destroy_process_group()
    _WAIT_GROUP = None


def barrier() -> None:
    """``dist.barrier()`` when distributed, else nothing."""
    if dist.is_available() and dist.is_initialized():
        dist.barrier()


#: The gloo group :func:`wait_for_ranks` waits in (made at its first call, on every rank).
_WAIT_GROUP = None
#: How long a rank waits for the others there: a stage that rank 0 runs alone may take hours,
#: where NCCL's default timeout is minutes.
WAIT_TIMEOUT = datetime.timedelta(days=2)


def wait_for_ranks() -> None:
    """A barrier for ranks that wait while others work alone (a stage of rank 0, a longer
    share of episodes): over a gloo group with :data:`WAIT_TIMEOUT`; nothing when not
    distributed."""
    global _WAIT_GROUP
    if not (dist.is_available() and dist.is_initialized()):
        return
    if _WAIT_GROUP is None:
        _WAIT_GROUP = dist.new_group(backend="gloo", timeout=WAIT_TIMEOUT)
    dist.barrier(group=_WAIT_GROUP)


def all_reduce_mean(x: torch.Tensor) -> torch.Tensor:
    """Mean of a tensor over ranks (identity when not distributed)."""
    if dist.is_available() and dist.is_initialized():
        x = x.clone()
        dist.all_reduce(x, op=dist.ReduceOp.SUM)
        x /= dist.get_world_size()
    return x


def seed_everything(seed: int) -> None:
    """Seed Python, NumPy and torch (all devices)."""
    random.seed(seed)
    np.random.seed(seed % 2**32)
    torch.manual_seed(seed)


class ResumableSampler(DistributedSampler):
    """``DistributedSampler`` that can start an epoch part-way (for exact resume).

    Works without a process group (``num_replicas``/``rank`` given explicitly). The
    epoch's order depends only on ``(seed, epoch)``; ``set_position(epoch, start)``
    skips the first ``start`` indices of this rank's share of that epoch.
    """

    def __init__(
        self,
        dataset: Dataset,
        num_replicas: int = 1,
        rank: int = 0,
        shuffle: bool = True,
        seed: int = 0,
        drop_last: bool = True,
    ) -> None:
        super().__init__(
            dataset, num_replicas, rank, shuffle=shuffle, seed=seed, drop_last=drop_last
        )
        self.start = 0

    def set_position(self, epoch: int, start: int = 0) -> None:
        """Next ``__iter__`` yields epoch ``epoch`` from index ``start`` of this rank's share."""
        if not 0 <= start <= self.num_samples:
            raise ValueError(f"start={start} must be in [0, {self.num_samples}]")
        self.set_epoch(epoch)
        self.start = start

    def __iter__(self) -> Iterator[int]:
        indices = list(super().__iter__())
        start, self.start = self.start, 0
        return iter(indices[start:])

    def __len__(self) -> int:
        return self.num_samples - self.start

    def state_dict(self) -> dict:
        return {"epoch": self.epoch, "seed": self.seed, "num_replicas": self.num_replicas}
