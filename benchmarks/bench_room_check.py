"""S2's room check on expert episodes of unseen houses: how often it would reject a goal in
the instructed room, and how often one in a room of another type, per threshold.

    python benchmarks/bench_room_check.py --checkpoint outputs/room_type/agent \
        --store data/expert_val60.zarr [--ticks 3 --plan-every 3] [--out PATH]

The check (``navigator.goal_checks.room_reject_threshold``) takes the mean, over the last
``--ticks`` S2 ticks (one every ``--plan-every`` control steps), of the classifier's probability
that the robot stands in a room of the type the instruction names. For every stored episode whose
instruction names a room (``instructed_room``):

- *right room*: the window of the episode's last ticks. The expert ends beside the goal, in
  its room, where S2 would ask to STOP. A rejection there is a false one.
- *other room*: every window, earlier in the episode, whose ticks all stand in a room of
  another type. This is where a same-category twin in another room would be, and a
  rejection there is the one wanted.

The classifier's per-frame accuracy on the store (every 4th frame) is reported too. Writes
``<out>.json`` and ``<out>.md``.
"""

from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path

import numpy as np
import torch

from vla_gr.agent.perception import instructed_room
from vla_gr.data.store import EpisodeStore
from vla_gr.machine import describe_machine
from vla_gr.policy import VLAGRPolicy
from vla_gr.training.room_type import frame_rooms, room_accuracy, room_frames

logger = logging.getLogger("bench_room_check")

ROOT = Path(__file__).resolve().parent
DEFAULT_OUT = ROOT / "results" / "bench_room_check"
THRESHOLDS = (0.05, 0.1, 0.2, 0.3, 0.5)


def windows(store: EpisodeStore, classifier, room_types, ticks: int, plan_every: int) -> dict:
    """Mean P(instructed room) of the right-room windows (R,) and other-room windows (O,)."""
    right, other, houses = [], [], {}
    for e in range(store.num_episodes):
        index = instructed_room(store.instruction(e), room_types)
        if index is None:
            continue
        frames = store.episode(e, ["rgb", "depth", "pose"])
        rows = np.arange(len(frames["pose"]) - 1, -1, -plan_every)[::-1]  # S2 ticks, last one
        labels = frame_rooms(store.spec(e), frames["pose"][rows], room_types, houses)  # (t,)
        rgb = torch.from_numpy(frames["rgb"][rows].transpose(0, 3, 1, 2))  # (t, 3, H, W)
        depth = torch.from_numpy(frames["depth"][rows].transpose(0, 3, 1, 2).astype(np.float32))
        p = classifier.probabilities(rgb, depth)[:, index].numpy()  # (t,)
        if len(p) >= ticks:
            right.append(float(p[-ticks:].mean()))
        for t in range(ticks, len(p) - ticks + 1):
            window = labels[t - ticks : t]
            if (window >= 0).all() and (window != index).all():
                other.append(float(p[t - ticks : t].mean()))
    return {"right": np.asarray(right), "other": np.asarray(other)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", required=True, help="an agent with model.room_type")
    parser.add_argument("--store", required=True, help="expert episodes of unseen houses")
    parser.add_argument("--ticks", type=int, default=3)
    parser.add_argument("--plan-every", type=int, default=3)
    parser.add_argument("--out", default=str(DEFAULT_OUT))
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    torch.set_num_threads(1)
    policy = VLAGRPolicy.from_pretrained(args.checkpoint)
    if policy.room_type is None:
        raise SystemExit(f"{args.checkpoint} has no room-type classifier (model.room_type)")
    classifier, room_types = policy.room_type, policy.config.room_type.room_types
    store = EpisodeStore.open(args.store)
    with torch.no_grad():
        accuracy = room_accuracy(classifier, room_frames(args.store, room_types, stride=4))
        w = windows(store, classifier, room_types, args.ticks, args.plan_every)
    rows = [
        {
            "threshold": th,
            "rejected_right_room": float((w["right"] < th).mean()),
            "rejected_other_room": float((w["other"] < th).mean()),
        }
        for th in THRESHOLDS
    ]
    result = {
        "checkpoint": args.checkpoint,
        "store": args.store,
        "ticks": args.ticks,
        "plan_every": args.plan_every,
        "right_room_windows": int(len(w["right"])),
        "other_room_windows": int(len(w["other"])),
        "classifier": accuracy,
        "rows": rows,
        "machine": describe_machine(),
    }
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(result, indent=1) + "\n")
    lines = [
        f"# S2's room check on `{args.store}` (`{args.checkpoint}`)",
        "",
        f"Classifier, every 4th frame ({accuracy['frames']} frames): accuracy "
        f"{accuracy['accuracy']:.3f}; per room {accuracy['per_room']}; "
        f"{accuracy['confident_share']:.0%} of frames at p >= 0.8, "
        f"{accuracy['confident_accuracy']:.3f} of them right.",
        "",
        f"Mean P(instructed room) over the last {args.ticks} S2 ticks (every "
        f"{args.plan_every} steps); {len(w['right'])} right-room windows (episode ends), "
        f"{len(w['other'])} other-room windows.",
        "",
        "| threshold | rejected in the instructed room (false) | rejected in another room |",
        "|---|---|---|",
    ]
    lines += [
        f"| {r['threshold']} | {r['rejected_right_room']:.3f} | {r['rejected_other_room']:.3f} |"
        for r in rows
    ]
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
