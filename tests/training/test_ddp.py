"""DDP over gloo on CPU: a 2-process step equals one process on the global batch."""

from __future__ import annotations

import copy
import datetime

import pytest
import torch
import torch.distributed as dist
import torch.multiprocessing as mp
from safetensors.torch import load_file, save_file
from torch.nn.parallel import DistributedDataParallel

from tests.helpers import fake_batch, split_batch, tiny_model_config, tiny_policy
from vla_gr.training.distributed import ResumableSampler, rank_share
from vla_gr.training.step import train_step

WORLD = 2
GLOBAL_BATCH = 8


def _step(model, micro):
    opt = torch.optim.SGD([p for p in model.parameters() if p.requires_grad], lr=0.5)
    return train_step(model, micro, opt, grad_clip=0.0)


ACCUMS = (1, 2)


def _worker(rank: int, out_dir: str) -> None:
    torch.set_num_threads(1)
    # A file rendezvous needs no free port (a TCP store on a just-probed port hung at times).
    dist.init_process_group(
        "gloo",
        init_method=f"file://{out_dir}/rendezvous",
        rank=rank,
        world_size=WORLD,
        timeout=datetime.timedelta(seconds=120),
    )
    try:
        _steps_on_rank(rank, out_dir)
    finally:
        # The DDP models were freed when _steps_on_rank returned: destroying the group while
        # a DDP reducer is still alive can hang its destructor.
        dist.destroy_process_group()


def _steps_on_rank(rank: int, out_dir: str) -> None:
    batch = fake_batch(tiny_model_config(), GLOBAL_BATCH, seed=5)
    local = split_batch(batch, WORLD)[rank]  # this rank's share of the global batch
    for accum in ACCUMS:
        model = DistributedDataParallel(tiny_policy(0))
        out = _step(model, split_batch(local, accum))
        loss = torch.tensor([out["loss"]])
        dist.all_reduce(loss)
        if rank == 0:
            state = {k: v.contiguous() for k, v in model.module.state_dict().items()}
            state["__loss__"] = loss / WORLD
            save_file(state, f"{out_dir}/accum{accum}.safetensors")


@pytest.fixture(scope="module")
def ddp_results(tmp_path_factory):
    out = tmp_path_factory.mktemp("ddp")
    mp.spawn(_worker, args=(str(out),), nprocs=WORLD, join=True)
    return {a: load_file(str(out / f"accum{a}.safetensors")) for a in ACCUMS}


@pytest.mark.parametrize("accum", ACCUMS)
def test_two_process_gloo_step_equals_single_process(ddp_results, accum):
    """accum=1: 2 ranks x 4 samples; accum=2: 2 ranks x 2 micro-batches x 2 (no_sync path)."""
    ddp = dict(ddp_results[accum])
    single = tiny_policy(0)
    init = copy.deepcopy(single.state_dict())
    out = _step(single, [fake_batch(tiny_model_config(), GLOBAL_BATCH, seed=5)])
    assert ddp.pop("__loss__").item() == pytest.approx(out["loss"], abs=1e-6)
    moved = 0.0
    for name, value in single.state_dict().items():
        torch.testing.assert_close(ddp[name], value, atol=1e-6, rtol=0, msg=name)
        moved = max(moved, (value - init[name]).abs().max().item())
    assert moved > 1e-4


def test_resumable_sampler_partitions_and_resumes():
    data = list(range(21))
    shares = [list(ResumableSampler(data, 2, r, seed=3)) for r in range(2)]
    assert not set(shares[0]) & set(shares[1])
    assert len(shares[0]) == len(shares[1]) == 10  # drop_last: 20 of 21 used
    s = ResumableSampler(data, 2, 1, seed=3)
    s.set_position(epoch=0, start=4)
    assert list(s) == shares[1][4:]
    assert list(s) == shares[1]  # the offset applies to one pass only
    s.set_position(epoch=1)
    assert list(s) != shares[1] and sorted(list(s)) != []  # another epoch, another order


def test_rank_shares_are_contiguous_disjoint_and_cover_every_item():
    for count, world in [(10, 3), (2, 2), (1, 2), (0, 4), (7, 1)]:
        shares = [rank_share(5, count, r, world) for r in range(world)]
        assert [k for s in shares for k in s] == list(range(5, 5 + count))  # in rank order
        assert max(map(len, shares)) - min(map(len, shares)) <= 1
    assert rank_share(0, 10, 0, 3) == range(0, 4) and rank_share(0, 10, 2, 3) == range(7, 10)
    with pytest.raises(ValueError, match="rank=2 must be in"):
        rank_share(0, 4, 2, 2)
