"""Train S2's room-type classifier (:mod:`vla_gr.agent.perception.room_type`) on expert stores.

Label of a frame: the type of the room the robot stands in, from the world. Each episode's
spec gives its house, regenerated from the scene seed, and its start pose. The stored pose,
relative to the start, gives the position. Frames outside every room (in a doorway) are left
out. Whole houses are held out for validation, and the weights with the best held-out
accuracy are kept. The rest of the agent comes from ``init`` and stays fixed. The result is
the agent with ``model.room_type.enabled=true`` and the room check on
(``navigator.goal_checks.room_reject_threshold``), a checkpoint that ``vla-gr eval`` loads like
any other.

A recipe's ``room_type`` stage runs it (``training.room_type.*``); a ``graft`` stage
takes a classifier trained beside another agent.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from vla_gr.training.agent_stage import (
    labelled_frames,
    part_setting,
    train_frame_part,
)
from vla_gr.training.part_training import ON_CPU, Compute

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
    device = next(classifier.parameters()).device
    probs = []
    for i in range(0, len(frames["label"]), batch_size):
        rgb = torch.from_numpy(frames["rgb"][i : i + batch_size]).to(device)  # (b, 3, H, W)
        depth = torch.from_numpy(frames["depth"][i : i + batch_size]).to(device)  # (b, 1, H, W)
        probs.append(classifier.probabilities(rgb, depth).cpu())  # (b, R)
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
    compute: Compute = ON_CPU,
) -> dict:
    """Train the classifier on ``frames`` (labelled in ``room_types``' order) and write the
    agent to ``out``; returns the summary."""
    return train_frame_part(
        init, out, frames, room_types, settings, reject_threshold, eval_frames,
        part="room_type", labels_key="room_types", role="classifier",
        threshold_key="room_reject_threshold",
        batch_loss=lambda classifier, rgb, depth, label: F.cross_entropy(
            classifier(rgb, depth), label
        ),
        evaluate=room_accuracy, score="accuracy", name="room type", seed=seed, steps=steps,
        batch_size=batch_size, lr=lr, val_fraction=val_fraction, eval_every=eval_every,
        compute=compute,
    )  # fmt: skip


def labels(settings: Sequence[str]) -> list[str]:
    """``room_type.room_types`` after ``settings`` (the classes frames are labelled in)."""
    from vla_gr.agent.perception import RoomTypeConfig

    return part_setting(RoomTypeConfig, "room_type", "room_types", settings)
