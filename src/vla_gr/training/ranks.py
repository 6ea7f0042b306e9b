"""The episode stages of a recipe under torchrun: run once, split across the ranks.

A ``collect`` or ``rollout`` stage with ``WORLD_SIZE`` > 1 gives each rank a disjoint,
contiguous share of the stage's episodes (:func:`~vla_gr.training.distributed.rank_share`); each
rank runs its share into a part of its own (``ranks/rank<r>.zarr``, ``ranks/rank<r>/``), then rank
0 merges the parts, in episode order, into the product a single process would have written and
the ranks wait for it. Every part resumes as a single-process stage does (the episodes it already
holds are kept). ``shares.json`` in the stage's folder records which episodes each rank ran.
Training stages use DDP instead (:mod:`vla_gr.train`, :mod:`.part_training`).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import shutil
from collections.abc import Callable
from pathlib import Path

from vla_gr.errors import UserError
from vla_gr.training.distributed import local_device, process_rank, rank_share, wait_for_ranks

log = logging.getLogger(__name__)

__all__ = ["collect_on_ranks", "rollout_on_ranks"]


def collect_on_ranks(cfg, store: Path, parts: Path) -> None:
    """``collect.*``'s episodes appended to ``store`` (a copy of the stage's input store, or
    none yet), each rank collecting its share into ``parts/rank<r>.zarr``; rank 0 merges the
    parts (then removes them)."""
    from vla_gr.data.collect import collect
    from vla_gr.data.store import EpisodeStore

    rank, world = process_rank()
    c = cfg.collect
    wanted = range(c.first_episode, c.first_episode + c.num_episodes)
    mine = rank_share(c.first_episode, c.num_episodes, rank, world)
    have = set(EpisodeStore.open(store).episode_indices.tolist()) if store.exists() else set()
    part = parts / f"rank{rank}.zarr"
    if len(mine) and not set(mine) <= have:
        share = dataclasses.replace(
            c, first_episode=mine.start, num_episodes=len(mine), output=str(part),
            mode="append", progress=c.progress and rank == 0,
        )  # fmt: skip
        parts.mkdir(parents=True, exist_ok=True)
        collect(dataclasses.replace(cfg, collect=share))
    wait_for_ranks()
    if rank == 0:
        shares = {p.stem: EpisodeStore.open(p).episode_indices.tolist() for p in _parts(parts)}
        _merge_stores([parts / f"{name}.zarr" for name in shares], store, wanted)
        _record_shares(parts.parent, shares)
        shutil.rmtree(parts, ignore_errors=True)  # the merged store holds every episode
    wait_for_ranks()


def _parts(parts: Path) -> list[Path]:
    """The ranks' parts in ``parts`` (``rank<r>.zarr`` or ``rank<r>/``), in rank order."""
    found = parts.glob("rank*") if parts.is_dir() else []
    return sorted(found, key=lambda p: int(p.name.removeprefix("rank").removesuffix(".zarr")))


def _record_shares(folder: Path, shares: dict[str, list[int]]) -> None:
    """``shares.json``: the episodes of each rank's part (merged with those already there: a
    part removed after an earlier merge keeps its record)."""
    path = folder / "shares.json"
    record = json.loads(path.read_text()) if path.is_file() else {}
    for name, episodes in shares.items():
        record[name] = sorted(set(record.get(name, [])) | set(episodes))
    path.write_text(json.dumps(record, indent=1))


def _merge_stores(parts: list[Path], store: Path, wanted: range) -> None:
    """Append to ``store`` the episodes of ``wanted``, in that order, that it lacks and a part
    holds (``store`` made like the first part when missing)."""
    from vla_gr.data.store import EpisodeStore
    from vla_gr.data.verify import copy_episodes, create_like

    sources = [EpisodeStore.open(p) for p in parts]
    if not sources:
        return
    target = (
        EpisodeStore.open(store, mode="a") if store.exists() else create_like(sources[0], store)
    )
    have = set(target.episode_indices.tolist())
    found = {
        int(index): (source, row)
        for source in sources
        for row, index in enumerate(source.episode_indices.tolist())
    }
    copied = 0
    for index in wanted:
        if index in found and index not in have:
            source, row = found[index]
            copied += copy_episodes(source, target, [row])
    log.info("merged %d episodes of %d ranks' parts into %s", copied, len(parts), store)


def rollout_on_ranks(cfg, out: Path, parts: Path, evaluate: Callable, merge: Callable) -> dict:
    """``eval.*``'s episodes run by the agent of ``cfg.eval``, each rank its share into
    ``parts/rank<r>/`` (on its own GPU when ``eval.device`` is ``cuda``); rank 0 merges the
    shares into the eval run folder ``out``. Returns the merged metrics.json on rank 0 and
    the rank's own share's elsewhere ({} for a rank without episodes)."""
    rank, world = process_rank()
    e = cfg.eval
    first = e.first_episode
    if e.num_episodes is None:
        raise UserError(
            "eval.num_episodes=None: under torchrun a rollout stage splits eval.num_episodes "
            "episodes over the ranks; set it in the stage's overrides"
        )
    mine = rank_share(first, e.num_episodes, rank, world)
    device = str(local_device("cuda")) if e.device == "cuda" else e.device
    metrics: dict = {}
    if len(mine):
        share = dataclasses.replace(
            e, first_episode=mine.start, num_episodes=len(mine), device=device,
            output_dir=str(parts / f"rank{rank}"), progress=e.progress and rank == 0,
        )  # fmt: skip
        metrics = evaluate(dataclasses.replace(cfg, eval=share))
    wait_for_ranks()
    if rank == 0:
        whole = dataclasses.replace(e, output_dir=str(out), device=device)
        shares = _parts(parts)
        metrics = merge(dataclasses.replace(cfg, eval=whole), shares)
        _record_shares(parts.parent, {p.name: _row_episodes(p) for p in shares})
    wait_for_ranks()
    return metrics


def _row_episodes(run: Path) -> list[int]:
    """The episode indices of an eval run folder's rows."""
    lines = (run / "episodes.jsonl").read_text().splitlines()
    return [json.loads(line)["episode_index"] for line in lines if line.strip()]
