"""The training data: make sure the episode store exists, then train / val loaders.

Reads ``data/`` (store, windows); the loaders feed ``training/step.py`` from ``vla_gr.train``.
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

import torch
from torch.utils.data import DataLoader

from vla_gr.data.dataset import EpisodeWindowDataset
from vla_gr.data.store import EpisodeStore, fake_episode
from vla_gr.errors import ConfigError
from vla_gr.training.distributed import DistInfo, ResumableSampler, barrier

log = logging.getLogger(__name__)


def write_synthetic_store(path: Path, num_episodes: int, length: int, image_size: int, seed: int):
    """A store of ``fake_episode`` s (recognisable synthetic frames) for smoke runs."""
    store = EpisodeStore.create(path, image_size, overwrite=True, info={"synthetic": True})
    for e in range(num_episodes):
        store.append(fake_episode(e, length, image_size=image_size, seed=seed))
    log.info("wrote synthetic store %s: %d episodes x %d steps", path, num_episodes, length)
    return store


def prepare_store(cfg, dist: DistInfo) -> Path:
    """Path of ``training.dataset``, created first when missing per ``training.if_missing``.

    Rank 0 creates it; the other ranks wait at a barrier.
    """
    t = cfg.training
    path = Path(t.dataset)
    if not (path / "zarr.json").is_file():
        if t.if_missing == "error":
            raise FileNotFoundError(
                f"training.dataset={str(path)!r} does not exist; collect it with `vla-gr collect "
                f"collect.output={path}` or set training.if_missing=collect (or synthetic)"
            )
        if dist.is_main:
            if t.if_missing == "synthetic":
                write_synthetic_store(
                    path, t.synthetic_episodes, t.synthetic_length, cfg.model.image_size, cfg.seed
                )
            else:
                from vla_gr.data.collect import collect

                log.info("training.dataset %s is missing: collecting it first", path)
                collect_cfg = dataclasses.replace(
                    cfg, collect=dataclasses.replace(cfg.collect, output=str(path), split="train")
                )
                collect(collect_cfg)
        barrier()
    return path


def build_datasets(cfg, path: Path) -> tuple[EpisodeWindowDataset, EpisodeWindowDataset | None]:
    """Train and held-out windows (episode-level split by ``training.val_ratio``); a damaged
    store is refused, or its damaged episodes left out with ``training.on_corrupt=skip``."""
    m, t = cfg.model, cfg.training
    kwargs = dict(
        n_obs_steps=m.n_obs_steps,
        horizon=m.horizon,
        val_ratio=t.val_ratio,
        seed=cfg.seed,
        depth_float16=t.depth_float16,
    )
    store = EpisodeStore.open(path, mode="r", on_corrupt=t.on_corrupt)
    train = EpisodeWindowDataset(store, split="train", **kwargs)
    if tuple(train.store.image_size) != (m.image_size, m.image_size):
        raise ConfigError(
            f"training.dataset {path} holds {train.store.image_size} images but "
            f"model.image_size={m.image_size}"
        )
    val = EpisodeWindowDataset(store, split="val", **kwargs) if t.val_ratio > 0 else None
    if val is not None and len(val) == 0:
        val = None
    if len(train) < t.batch_size:
        raise ConfigError(
            f"training.dataset {path} has {len(train)} training windows, fewer than "
            f"training.batch_size={t.batch_size}"
        )
    return train, val


def make_loader(dataset, batch_size: int, sampler, num_workers: int, seed: int, pin: bool):
    """DataLoader with its own generator (so creating it never touches the global RNG)."""
    return DataLoader(
        dataset,
        batch_size=batch_size,
        sampler=sampler,
        num_workers=num_workers,
        pin_memory=pin,
        drop_last=True,
        generator=torch.Generator().manual_seed(seed),
        persistent_workers=num_workers > 0,
    )


def build_loaders(cfg, dist: DistInfo, train, val):
    """(train loader, its ResumableSampler, val loader or None)."""
    t = cfg.training
    pin = dist.device.type == "cuda"
    sampler = ResumableSampler(train, dist.world_size, dist.rank, shuffle=True, seed=cfg.seed)
    train_loader = make_loader(train, t.batch_size, sampler, t.num_workers, cfg.seed, pin)
    val_loader = None
    if val is not None:
        vs = ResumableSampler(
            val, dist.world_size, dist.rank, shuffle=True, seed=cfg.seed + 1, drop_last=False
        )
        val_loader = DataLoader(val, batch_size=t.batch_size, sampler=vs, num_workers=0)
    return train_loader, sampler, val_loader
