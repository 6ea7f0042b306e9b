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
import logging
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from vla_gr.errors import UserError
from vla_gr.training.agent_stage import (
    build_agent_from,
    finish_part,
    fit_part,
    graft_part,
    labelled_frames,
    part_setting,
)
from vla_gr.training.command import run_command

log = logging.getLogger(__name__)

__all__ = ["frame_rooms", "room_accuracy", "room_frames", "train_room_type"]


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
    houses: dict = {}
    return labelled_frames(
        store_path,
        lambda spec, frames: frame_rooms(spec, frames["pose"], room_types, houses),
        first,
        count,
        stride,
    )


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
    policy.requires_grad_(False)
    summary, _ = fit_part(
        classifier,
        frames,
        lambda rgb, depth, label: F.cross_entropy(classifier(rgb, depth), label),
        lambda val: room_accuracy(classifier, val),
        "accuracy",
        "room type",
        steps,
        batch_size,
        lr,
        seed,
        val_fraction,
        eval_every,
    )
    return finish_part(
        policy, loaded, config, out, "room_type", summary,
        lambda frames: room_accuracy(classifier, frames), eval_frames,
    )  # fmt: skip


def _room_types(settings: Sequence[str]) -> list[str]:
    """``room_type.room_types`` after ``settings`` (the classes frames are labelled in)."""
    from vla_gr.core.grounding import RoomTypeConfig

    return part_setting(RoomTypeConfig, "room_type", "room_types", settings)


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

    def work(args: argparse.Namespace) -> None:
        if args.classifier_from:
            threshold = f"navigator.room_reject_threshold={args.reject_threshold}"
            graft_part(args.init, args.classifier_from, "room_type", args.out, [threshold])
            return
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

    return run_command(parser, argv, work, limit_threads=True)


if __name__ == "__main__":
    sys.exit(main())
