"""Train S2's room-type classifier (:mod:`vla_gr.core.grounding.room_type`) on expert stores.

Label of a frame: the type of the room the robot stands in, from the world. Each episode's
spec gives its house, regenerated from the scene seed, and its start pose. The stored pose,
relative to the start, gives the position. Frames outside every room (in a doorway) are left
out. Whole houses are held out for validation, and the weights with the best held-out
accuracy are kept. The rest of the agent comes from ``init`` and stays fixed. The result is
the agent with ``model.room_type.enabled=true`` and the room check on
(``navigator.room_reject_threshold``), a checkpoint that ``vla-gr eval`` loads like any other.

    python -m vla_gr.training.room_type checkpoints/vla_gr_cpu outputs/room_type/agent \
        --store data/big3.zarr --episodes 1200 --stride 8 --eval-store data/expert_val60.zarr
    # the same classifier on another goal head (it reads frames only):
    python -m vla_gr.training.room_type outputs/train/<run>/checkpoints/latest out/ \
        --classifier-from outputs/room_type/agent
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from vla_gr.errors import UserError
from vla_gr.training.agent_stage import build_agent_from, graft_part, write_agent
from vla_gr.training.optim import build_optimizer, build_scheduler

log = logging.getLogger(__name__)

__all__ = ["frame_rooms", "room_accuracy", "room_frames", "train_room_type"]

#: Episodes read from the store at a time (bounds the memory of a read).
_BLOCK = 64


def frame_rooms(spec: dict, poses: np.ndarray, room_types: Sequence[str], houses: dict):
    """Room-type index (T,) of each stored pose (T, 3) of one episode; -1 outside rooms."""
    from vla_gr.envs.episodes import EpisodeSpec
    from vla_gr.envs.house import generate_house
    from vla_gr.geometry.pose2d import robot_to_map

    s = EpisodeSpec.from_dict(spec)
    key = s.scene_key
    if key not in houses:
        houses.clear()  # episodes of one house are stored together: keep the last one only
        houses[key] = generate_house(s.scene_seed, num_rooms=s.num_rooms, clutter=s.clutter)
    house = houses[key]
    xy = robot_to_map(poses[:, :2].astype(np.float64), s.start_pose)  # (T, 2) world
    labels = np.full(len(xy), -1, np.int64)  # (T,)
    for t, (x, y) in enumerate(xy):
        room = house.room_of(float(x), float(y))
        if room is not None and room.room_type in room_types:
            labels[t] = list(room_types).index(room.room_type)
    return labels


def room_frames(
    store_path: str | Path,
    room_types: Sequence[str],
    first: int = 0,
    count: int | None = None,
    stride: int = 1,
) -> dict[str, np.ndarray]:
    """Every ``stride``-th frame of stored episodes ``[first, first + count)`` with its label.

    Returns ``rgb`` (N, 3, H, W) uint8, ``depth`` (N, 1, H, W) float32, ``label`` (N,) index
    in ``room_types`` and ``house`` (N,) scene seed; frames outside every room are dropped.
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
    houses: dict = {}
    for b in range(first, last, _BLOCK):
        episodes = range(b, min(b + _BLOCK, last))
        start, stop = store.episode_slice(episodes[0]).start, store.episode_slice(episodes[-1]).stop
        block = {k: store.data_array(k)[start:stop] for k in ("rgb", "depth", "pose")}
        for e in episodes:
            sl = store.episode_slice(e)
            rows = np.arange(sl.start, sl.stop, stride) - start  # (t,) within the block
            spec = store.spec(e)
            labels = frame_rooms(spec, block["pose"][rows], room_types, houses)  # (t,)
            keep = rows[labels >= 0]
            parts["rgb"].append(block["rgb"][keep].transpose(0, 3, 1, 2))  # (t, 3, H, W)
            parts["depth"].append(block["depth"][keep].transpose(0, 3, 1, 2))  # (t, 1, H, W)
            parts["label"].append(labels[labels >= 0])
            parts["house"].append(np.full(len(keep), int(spec["scene_seed"]), np.int64))
    out = {k: np.concatenate(v) for k, v in parts.items()}
    out["depth"] = out["depth"].astype(np.float32)
    return out


@torch.no_grad()
def room_accuracy(classifier, frames: dict[str, np.ndarray], batch_size: int = 512) -> dict:
    """Accuracy of ``classifier`` on ``frames`` (:func:`room_frames`): overall, per room
    type, and of its confident answers (probability >= 0.8) with their share."""
    classifier.eval()
    probs = []
    for i in range(0, len(frames["label"]), batch_size):
        rgb = torch.from_numpy(frames["rgb"][i : i + batch_size])  # (b, 3, H, W)
        depth = torch.from_numpy(frames["depth"][i : i + batch_size])  # (b, 1, H, W)
        probs.append(classifier.probabilities(rgb, depth))  # (b, R)
    p = torch.cat(probs).numpy()  # (N, R)
    label = frames["label"]
    right = p.argmax(1) == label  # (N,)
    confident = p.max(1) >= 0.8  # (N,)
    room_types = classifier.config.room_types
    return {
        "frames": int(len(label)),
        "accuracy": round(float(right.mean()), 4),
        "confident_share": round(float(confident.mean()), 4),
        "confident_accuracy": round(float(right[confident].mean()), 4) if confident.any() else None,
        "per_room": {
            r: round(float(right[label == k].mean()), 4)
            for k, r in enumerate(room_types)
            if (label == k).any()
        },
    }


def train_room_type(
    init: str | Path,
    out: str | Path,
    frames: dict[str, np.ndarray],
    room_types: Sequence[str],
    steps: int = 2000,
    batch_size: int = 256,
    lr: float = 2e-3,
    seed: int = 0,
    settings: Sequence[str] = (),
    reject_threshold: float = 0.2,
    val_fraction: float = 0.1,
    eval_every: int = 250,
    eval_frames: dict[str, np.ndarray] | None = None,
) -> dict:
    """Train the classifier on ``frames`` (labelled in ``room_types``' order) and write the
    agent to ``out``; returns the summary."""
    torch.manual_seed(seed)
    policy, loaded, config = build_agent_from(
        init, "room_type", settings, keep_part=False, forced=["room_type.enabled=true"]
    )
    if list(policy.config.room_type.room_types) != list(room_types):
        raise UserError(
            f"frames are labelled in {list(room_types)} but the classifier predicts "
            f"{list(policy.config.room_type.room_types)} (room_type.room_types)"
        )
    config.model.navigator.room_reject_threshold = float(reject_threshold)
    classifier = policy.room_type
    houses = np.unique(frames["house"])
    if len(houses) < 2:
        raise UserError(f"room frames come from {len(houses)} house; training needs 2 or more")
    rng = np.random.default_rng(seed)
    n_val = min(len(houses) - 1, max(1, int(round(val_fraction * len(houses)))))
    held = np.isin(frames["house"], rng.permutation(houses)[:n_val])  # (N,)
    val = {k: v[held] for k, v in frames.items()}
    train_rows = np.flatnonzero(~held)
    log.info("room frames: %d train / %d val (%d houses held out)", len(train_rows),
             int(held.sum()), n_val)  # fmt: skip
    policy.requires_grad_(False)
    classifier.requires_grad_(True)
    optimizer = build_optimizer(classifier, lr, 1e-4)
    scheduler = build_scheduler(optimizer, min(100, steps // 10), steps, 0.05)
    best, best_state, history = -1.0, None, []
    t0 = time.perf_counter()
    for step in range(1, steps + 1):
        classifier.train()
        rows = rng.choice(train_rows, size=batch_size)  # (B,)
        rgb = torch.from_numpy(frames["rgb"][rows])  # (B, 3, H, W) uint8
        depth = torch.from_numpy(frames["depth"][rows])  # (B, 1, H, W)
        flip = torch.from_numpy(rng.random(batch_size) < 0.5)  # (B,) mirrored frames
        rgb = torch.where(flip[:, None, None, None], rgb.flip(-1), rgb)
        depth = torch.where(flip[:, None, None, None], depth.flip(-1), depth)
        loss = F.cross_entropy(classifier(rgb, depth), torch.from_numpy(frames["label"][rows]))
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        scheduler.step()
        if step % eval_every == 0 or step == steps:
            row = {
                "step": step,
                "loss": round(float(loss.detach()), 4),
                **room_accuracy(classifier, val),
            }
            row["seconds"] = round(time.perf_counter() - t0, 1)
            history.append(row)
            log.info("room type %s", json.dumps(row))
            if row["accuracy"] > best:
                best = row["accuracy"]
                best_state = {k: v.clone() for k, v in classifier.state_dict().items()}
    classifier.load_state_dict(best_state)
    summary = {"best_val_accuracy": best, "history": history}
    if eval_frames is not None:
        summary["eval"] = room_accuracy(classifier, eval_frames)
        log.info("room type on the evaluation store: %s", json.dumps(summary["eval"]))
    write_agent(policy.eval(), loaded, config, out, {"room_type_training": summary})
    log.info("wrote %s", out)
    return summary


def _room_types(settings: Sequence[str]) -> list[str]:
    """``room_type.room_types`` after ``settings`` (the classes frames are labelled in)."""
    from omegaconf import OmegaConf

    from vla_gr.core.grounding import RoomTypeConfig

    merged = OmegaConf.merge(
        OmegaConf.structured(RoomTypeConfig),
        OmegaConf.from_dotlist([s.removeprefix("room_type.") for s in settings]),
    )
    return list(merged.room_types)


def main(argv: Sequence[str] | None = None) -> int:
    prog = "python -m vla_gr.training.room_type"
    parser = argparse.ArgumentParser(prog=prog, description=__doc__)
    parser.add_argument("init", help="the dual-system agent checkpoint (kept but the classifier)")
    parser.add_argument("out", help="the checkpoint folder to write (replaced)")
    parser.add_argument("--store", help="expert store with the training frames")
    parser.add_argument(
        "--classifier-from", default=None, help="take this checkpoint's classifier, no training"
    )
    parser.add_argument("--first", type=int, default=0, help="first stored episode to read")
    parser.add_argument("--episodes", type=int, default=None, help="stored episodes to read")
    parser.add_argument("--stride", type=int, default=8, help="every stride-th frame")
    parser.add_argument("--eval-store", default=None, help="a store of unseen houses to report on")
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--batch-size", type=int, default=256)
    parser.add_argument("--lr", type=float, default=2e-3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--reject-threshold", type=float, default=0.2,
                        help="navigator.room_reject_threshold written with the agent")  # fmt: skip
    parser.add_argument("--set", nargs="*", default=[], help="room_type.* settings")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    torch.set_num_threads(max(1, min(2, os.cpu_count() or 1)))
    try:
        if args.classifier_from:
            threshold = f"navigator.room_reject_threshold={args.reject_threshold}"
            graft_part(args.init, args.classifier_from, "room_type", args.out, [threshold])
            return 0
        if not args.store:
            raise UserError("--store is required unless --classifier-from names a checkpoint")
        room_types = _room_types(args.set)
        frames = room_frames(args.store, room_types, args.first, args.episodes, args.stride)
        eval_frames = (
            room_frames(args.eval_store, room_types, stride=args.stride)
            if args.eval_store
            else None
        )
        train_room_type(
            args.init, args.out, frames, room_types, steps=args.steps, batch_size=args.batch_size,
            lr=args.lr, seed=args.seed, settings=args.set,
            reject_threshold=args.reject_threshold, eval_frames=eval_frames,
        )  # fmt: skip
    except UserError as err:
        sys.stderr.write(f"{parser.prog}: error: {err}\n")
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
