"""Stages that train one part of a dual-system agent on top of a checkpoint: S1
(:mod:`.s1`), S2's room-type classifier (:mod:`.room_type`) and its object-category
segmenter (:mod:`.object_category`).

Each reads the agent of a checkpoint, changes settings under one config key, trains that
part with the rest loaded from the checkpoint, and writes the whole agent as a new checkpoint
that ``vla-gr eval`` loads like any other. The two S2 checks learn from labelled stored frames
(:func:`labelled_frames`) with one loop (:func:`fit_part`), one stage
(:func:`train_frame_part`) and one command line (:func:`frame_part_parser`,
:func:`add_frame_training_arguments`, :func:`train_from_args`).
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import numpy as np
import torch

from vla_gr.checkpoint import load_model_state, read_checkpoint
from vla_gr.errors import UserError
from vla_gr.training.distributed import is_main_process
from vla_gr.training.part_training import ON_CPU, Compute, PartTrainer, rank_generator

log = logging.getLogger(__name__)

__all__ = [
    "build_agent_from",
    "finish_part",
    "fit_part",
    "graft_part",
    "labelled_frames",
    "part_setting",
    "train_frame_part",
    "write_agent",
]


def build_agent_from(
    init: str | Path,
    part: str,
    settings: Sequence[str],
    keep_part: bool,
    forced: Sequence[str],
    part_config: Mapping | None = None,
    reinit: Sequence[str] = (),
):
    """The agent of checkpoint ``init`` with ``model.<part>`` replaced by ``part_config`` (if
    given), changed by ``settings`` (each ``key=value`` with a key under ``<part>.``) and then
    ``forced``; every weight is loaded from ``init`` except, unless ``keep_part``, those of
    ``part``, and those under the prefixes ``reinit`` (fresh).

    Returns ``(policy, loaded checkpoint, its config with the merged model)``.
    """
    from omegaconf import OmegaConf

    from vla_gr.configs.model_schema import ModelConfig
    from vla_gr.policy import VLAGRPolicy, apply_peft
    from vla_gr.policy.factory import require_agent

    for item in settings:
        if "=" not in item or not item.split("=", 1)[0].strip().startswith(f"{part}."):
            raise UserError(f"setting {item!r} must be key=value with a key under {part}.")
    loaded = read_checkpoint(init)
    config = OmegaConf.create(loaded.config_yaml)
    require_agent(config.model.get("agent"), VLAGRPolicy, init)
    if part == "s1" and "s1" in config.model and "head" in config.model.s1:
        # the head's context width follows s1.dim: a saved width must not pin a new dim
        config.model.s1.head.context_dim = None
    merged = OmegaConf.merge(
        OmegaConf.structured(ModelConfig),
        config.model,
        {} if part_config is None else {part: part_config},
        OmegaConf.from_dotlist([*settings, *forced]),
    )
    policy = apply_peft(VLAGRPolicy(OmegaConf.to_object(merged)), merged.peft)
    prefix = f"{part}."
    fresh = {k: v for k, v in policy.state_dict().items() if k.startswith(prefix)}
    tensors = {
        k: v
        for k, v in loaded.model.items()
        if (not k.startswith(prefix) or keep_part) and not k.startswith(tuple(reinit))
    }
    load_model_state(policy, {**fresh, **tensors}, str(init))
    config.model = merged
    return policy, loaded, config


def write_agent(policy, loaded, config, out: str | Path, state_updates: dict) -> Path:
    """Write ``policy`` with ``config`` as checkpoint folder ``out`` (replaced), keeping the
    training state of ``loaded`` (without its RNG) plus ``state_updates``; verified by
    loading it back. Rank 0 writes; the other ranks of a torchrun job return ``out``."""
    from omegaconf import OmegaConf

    from vla_gr.policy.export import write_checkpoint_folder

    if not is_main_process():  # under torchrun every rank holds the same weights
        return Path(out)
    tensors = {k: v.detach().cpu().contiguous() for k, v in policy.state_dict().items()}
    return write_checkpoint_folder(out, loaded, tensors, OmegaConf.to_yaml(config), state_updates)


def graft_part(
    init: str | Path, donor: str | Path, part: str, out: str | Path, settings: Sequence[str] = ()
) -> Path:
    """Write to ``out`` the agent of ``init`` with ``model.<part>`` and its weights taken from
    checkpoint ``donor`` (e.g. a room-type classifier trained beside another goal head).

    ``settings`` are ``model.*`` keys without the prefix, applied last
    (``navigator.goal_checks.room_reject_threshold=0.2``)."""
    from omegaconf import OmegaConf

    given = read_checkpoint(donor)
    donor_model = OmegaConf.create(given.config_yaml).model
    if part not in donor_model:
        raise UserError(f"{donor} has no model.{part} to take")
    policy, loaded, config = build_agent_from(
        init, part, [], keep_part=False, forced=[], part_config=donor_model[part]
    )
    prefix = f"{part}."
    tensors = {k[len(prefix) :]: v for k, v in given.model.items() if k.startswith(prefix)}
    if not tensors:
        raise UserError(f"{donor} holds no {part} weights")
    getattr(policy, part).load_state_dict(tensors)
    config.model = OmegaConf.merge(config.model, OmegaConf.from_dotlist(list(settings)))
    return write_agent(policy, loaded, config, out, {f"{part}_from": str(donor)})


#: Episodes read from a store at a time (bounds the memory of a read).
_BLOCK = 64


def labelled_frames(
    store_path: str | Path,
    label_episode: Callable[[dict, dict[str, np.ndarray]], np.ndarray],
    first: int = 0,
    count: int | None = None,
    stride: int = 1,
) -> dict[str, np.ndarray]:
    """Every ``stride``-th frame of stored episodes ``[first, first + count)`` with its label.

    ``label_episode(spec, frames)`` gets an episode's spec and its selected ``rgb``, ``depth``
    and ``pose`` rows and returns their labels (t, ...); a frame whose label is negative
    everywhere is dropped. Returns ``rgb`` (N, 3, H, W) uint8, ``depth`` (N, 1, H, W) float32,
    ``label`` (N, ...) and ``house`` (N,) scene seed.
    """
    from vla_gr.data.store import EpisodeStore

    if stride < 1:
        raise UserError(f"stride={stride} must be >= 1")
    store = EpisodeStore.open(store_path)
    last = store.num_episodes if count is None else min(store.num_episodes, first + count)
    if not 0 <= first < last:
        raise UserError(
            f"store {store_path} has {store.num_episodes} episodes; first={first} count={count} "
            "selects none"
        )
    parts: dict[str, list[np.ndarray]] = {"rgb": [], "depth": [], "label": [], "house": []}
    for b in range(first, last, _BLOCK):
        episodes = range(b, min(b + _BLOCK, last))
        start, stop = store.episode_slice(episodes[0]).start, store.episode_slice(episodes[-1]).stop
        block = {k: store.data_array(k)[start:stop] for k in ("rgb", "depth", "pose")}
        for e in episodes:
            sl = store.episode_slice(e)
            rows = np.arange(sl.start, sl.stop, stride) - start  # (t,) within the block
            spec = store.spec(e)
            labels = np.asarray(label_episode(spec, {k: v[rows] for k, v in block.items()}))
            keep = (labels >= 0).reshape(len(rows), -1).any(axis=1)  # (t,)
            parts["rgb"].append(block["rgb"][rows[keep]].transpose(0, 3, 1, 2))  # (t, 3, H, W)
            parts["depth"].append(block["depth"][rows[keep]].transpose(0, 3, 1, 2))
            parts["label"].append(labels[keep])
            parts["house"].append(np.full(int(keep.sum()), int(spec["scene_seed"]), np.int64))
    out = {k: np.concatenate(v) for k, v in parts.items()}
    out["depth"] = out["depth"].astype(np.float32)
    return out


def fit_part(
    module: torch.nn.Module,
    frames: dict[str, np.ndarray],
    batch_loss: Callable[..., torch.Tensor],
    evaluate: Callable[[dict[str, np.ndarray]], dict],
    score: str,
    name: str,
    steps: int,
    batch_size: int,
    lr: float,
    seed: int,
    val_fraction: float = 0.1,
    eval_every: int = 250,
    compute: Compute = ON_CPU,
) -> tuple[dict, dict[str, np.ndarray]]:
    """Train ``module`` on ``frames`` (:func:`labelled_frames`), whole houses held out.

    Each step draws ``batch_size`` training frames (on each rank under torchrun), mirrors half
    of them left-right (labels with a width axis too) and minimises ``batch_loss(rgb=, depth=,
    label=)`` on ``compute``'s device and precision. Every ``eval_every`` steps
    ``evaluate(held-out frames)`` reports a row; the weights with the highest ``row[score]``
    are kept. Returns the summary and the held-out frames.
    """
    from vla_gr.training.optim import build_optimizer, build_scheduler

    houses = np.unique(frames["house"])
    if len(houses) < 2:
        raise UserError(f"{name} frames come from {len(houses)} house; training needs 2 or more")
    rng = np.random.default_rng(seed)
    n_val = min(len(houses) - 1, max(1, int(round(val_fraction * len(houses)))))
    held = np.isin(frames["house"], rng.permutation(houses)[:n_val])  # (N,)
    val = {k: v[held] for k, v in frames.items()}
    train_rows = np.flatnonzero(~held)
    log.info("%s frames: %d train / %d val (%d houses held out)", name, len(train_rows),
             int(held.sum()), n_val)  # fmt: skip
    module.requires_grad_(True)
    trainer = PartTrainer(module, batch_loss, compute)
    optimizer = build_optimizer(module, lr, 1e-4)
    scheduler = build_scheduler(optimizer, min(100, steps // 10), steps, 0.05)
    draws = rank_generator(rng, seed)
    best, best_state, history = -np.inf, None, []
    t0 = time.perf_counter()
    for step in range(1, steps + 1):
        rows = draws.choice(train_rows, size=batch_size)  # (B,)
        rgb = torch.from_numpy(frames["rgb"][rows])  # (B, 3, H, W) uint8
        depth = torch.from_numpy(frames["depth"][rows])  # (B, 1, H, W)
        label = torch.from_numpy(frames["label"][rows])  # (B,) or (B, H, W)
        flip = torch.from_numpy(draws.random(batch_size) < 0.5)  # (B,) mirrored frames
        rgb = torch.where(flip[:, None, None, None], rgb.flip(-1), rgb)
        depth = torch.where(flip[:, None, None, None], depth.flip(-1), depth)
        if label.dim() == 3:  # per-pixel labels mirror with their frames
            label = torch.where(flip[:, None, None], label.flip(-1), label)
        batch = {"rgb": rgb, "depth": depth, "label": label}
        loss = trainer.step(batch, optimizer, scheduler)
        if step % eval_every == 0 or step == steps:
            module.eval()
            row = {"step": step, "loss": round(loss, 4), **evaluate(val)}
            row["seconds"] = round(time.perf_counter() - t0, 1)
            history.append(row)
            log.info("%s %s", name, json.dumps(row))
            if row[score] > best:
                best = row[score]
                best_state = {k: v.clone() for k, v in module.state_dict().items()}
    module.load_state_dict(best_state)
    module.cpu().eval()
    return {f"best_val_{score}": best, "history": history}, val


def part_setting(config_cls, part: str, key: str, settings: Sequence[str]):
    """``model.<part>.<key>`` of config class ``config_cls`` after ``settings`` (each
    ``<part>.key=value``): what the frames are labelled in, before the agent is built."""
    from omegaconf import OmegaConf

    merged = OmegaConf.merge(
        OmegaConf.structured(config_cls),
        OmegaConf.from_dotlist([s.removeprefix(f"{part}.") for s in settings]),
    )
    return list(merged[key])


def finish_part(
    policy, loaded, config, out, part: str, summary: dict, evaluate, eval_frames
) -> dict:
    """Report ``evaluate(eval_frames)`` (when given) in ``summary`` and write the agent with
    ``<part>_training`` in its training state; returns ``summary``."""
    if eval_frames is not None:
        summary["eval"] = evaluate(eval_frames)
        log.info("%s on the evaluation store: %s", part, json.dumps(summary["eval"]))
    write_agent(policy.eval(), loaded, config, out, {f"{part}_training": summary})
    log.info("wrote %s", out)
    return summary


def train_frame_part(
    init: str | Path,
    out: str | Path,
    frames: dict[str, np.ndarray],
    labels: Sequence[str],
    settings: Sequence[str],
    reject_threshold: float,
    eval_frames: dict[str, np.ndarray] | None,
    part: str,
    labels_key: str,
    role: str,
    threshold_key: str,
    batch_loss: Callable[..., torch.Tensor],
    evaluate: Callable[[torch.nn.Module, dict[str, np.ndarray]], dict],
    score: str,
    name: str,
    seed: int,
    **fit,
) -> dict:
    """Train the fresh ``model.<part>`` of the agent of ``init`` on ``frames`` (labelled in
    ``labels``' order, which must be its ``<part>.<labels_key>``) and write the agent, with
    ``navigator.goal_checks.<threshold_key>`` set to ``reject_threshold``, to ``out``; returns
    the summary.

    ``batch_loss(module, rgb, depth, label)`` and ``evaluate(module, frames)`` get the part
    (the ``role`` named in errors); ``score``, ``name`` and ``fit`` (``steps``,
    ``batch_size``, ``lr``, ``val_fraction``, ``eval_every``) go to :func:`fit_part`.
    """
    torch.manual_seed(seed)
    policy, loaded, config = build_agent_from(
        init, part, settings, keep_part=False, forced=[f"{part}.enabled=true"]
    )
    predicted = list(getattr(getattr(policy.config, part), labels_key))
    if predicted != list(labels):
        raise UserError(
            f"frames are labelled in {list(labels)} but the {role} predicts "
            f"{predicted} ({part}.{labels_key})"
        )
    setattr(config.model.navigator.goal_checks, threshold_key, float(reject_threshold))
    module = getattr(policy, part)
    policy.requires_grad_(False)
    summary, _ = fit_part(
        module,
        frames,
        lambda rgb, depth, label: batch_loss(module, rgb, depth, label),
        lambda val: evaluate(module, val),
        score,
        name,
        seed=seed,
        **fit,
    )
    return finish_part(
        policy, loaded, config, out, part, summary,
        lambda frames: evaluate(module, frames), eval_frames,
    )  # fmt: skip
