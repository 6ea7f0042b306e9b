"""Latency of S2's goal head at batch 1, one thread: one pass, and the test-time flip run as two
passes or as one batch of two.

    python benchmarks/bench_goal_head_latency.py --checkpoint checkpoints/vla_gr_cpu \
        [--calls 200] [--rounds 5]

The variants run interleaved, round after round, on the same recorded `val` frames
(rgb, depth and instruction of real episodes), so their ratios are measured side by side:

- ``one_pass``: ``GoalHead.probabilities`` without the flip;
- ``flip_two_passes``: the frame and its mirror through the network one after the other, the
  mirrored maps flipped back and averaged (how the flip was first run);
- ``flip_batched``: ``GoalHead.probabilities`` with the flip (one forward on a batch of two);
- ``flip_batched_interpolate``: the same with the decoder upsampling through
  ``F.interpolate(mode="nearest")``, as it did before ``upsample_nearest_2x`` (same values).

Reports the median over rounds of each round's p50 / p95 (ms per call) and the ratio of each
variant's p50 to ``one_pass``'s in the same round. Writes ``<out>.json`` and ``<out>.md``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from vla_gr.agent.observations import env_obs_to_frame
from vla_gr.agent.perception import goal_head as goal_head_module
from vla_gr.data.collect import make_env
from vla_gr.machine import describe_machine, machine_line
from vla_gr.policy import VLAGRPolicy

logger = logging.getLogger("bench_goal_head_latency")

ROOT = Path(__file__).resolve().parent
DEFAULT_OUT = ROOT / "results" / "bench_goal_head_latency"
VARIANTS = ("one_pass", "flip_two_passes", "flip_batched", "flip_batched_interpolate")


def recorded_frames(count: int, split: str) -> list[dict]:
    """``count`` frames (batch 1) from the first steps of ``split`` episodes, turning in place."""
    env = make_env({"split": split, "semantic": False})
    frames = []
    try:
        episode = 0
        while len(frames) < count:
            obs, _ = env.reset(options={"episode": episode})
            for _ in range(10):
                frames.append(env_obs_to_frame(obs))
                obs, *_ = env.step(np.array([0.0, 1.0, -1.0], np.float32))
            episode += 1
    finally:
        env.close()
    return frames[:count]


@contextmanager
def flip_set(head, on: bool):
    """``head`` with ``test_time_flip`` set to ``on`` inside the block, as it was after."""
    saved = head.config
    head.config = dataclasses.replace(saved, test_time_flip=on)
    try:
        yield head
    finally:
        head.config = saved


def two_passes(head, frame: dict) -> dict[str, torch.Tensor]:
    """The flip as two forwards of batch 1 (the mirror's maps flipped back, then the mean)."""
    with flip_set(head, False):
        own = head.probabilities(frame["rgb"], frame["depth"], frame["instruction"])
        mirrored = head.probabilities(
            frame["rgb"].flip(-1), frame["depth"].flip(-1), frame["instruction"]
        )
    return {k: 0.5 * (v + (mirrored[k].flip(-1) if v.dim() > 1 else mirrored[k]))
            for k, v in own.items()}  # fmt: skip


@contextmanager
def interpolated_upsampling():
    """The goal head's decoder upsampling through ``F.interpolate`` inside the block."""
    saved = goal_head_module.upsample_nearest_2x
    goal_head_module.upsample_nearest_2x = lambda h: F.interpolate(
        h, scale_factor=2, mode="nearest"
    )
    try:
        yield
    finally:
        goal_head_module.upsample_nearest_2x = saved


def one_call(head, variant: str, frame: dict) -> None:
    """One S2 perception call of ``variant``."""
    if variant == "flip_two_passes":
        two_passes(head, frame)
        return
    if variant == "flip_batched_interpolate":
        with interpolated_upsampling(), flip_set(head, True):
            head.probabilities(frame["rgb"], frame["depth"], frame["instruction"])
        return
    with flip_set(head, variant == "flip_batched"):
        head.probabilities(frame["rgb"], frame["depth"], frame["instruction"])


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=200, help="calls per variant per round")
    parser.add_argument("--rounds", type=int, default=5, help="rounds of the variants")
    parser.add_argument("--checkpoint", default="checkpoints/vla_gr_cpu")
    parser.add_argument("--split", default="val", help="the episodes the frames come from")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    torch.set_num_threads(args.threads)
    head = VLAGRPolicy.from_pretrained(args.checkpoint).goal_head.eval()
    frames = recorded_frames(args.calls, args.split)
    with torch.no_grad():
        with flip_set(head, True):
            frame = frames[0]
            batched = head.probabilities(frame["rgb"], frame["depth"], frame["instruction"])
        reference = two_passes(head, frames[0])
        for key, value in reference.items():  # the two ways compute the same maps
            torch.testing.assert_close(batched[key], value, rtol=1e-4, atol=1e-5)
        with interpolated_upsampling(), flip_set(head, True):
            before = head.probabilities(frame["rgb"], frame["depth"], frame["instruction"])
        for key, value in before.items():  # the two upsamplings give the same values
            if not torch.equal(batched[key], value):
                raise AssertionError(f"{key}: upsample_nearest_2x differs from F.interpolate")
        for frame in frames[:10]:  # warm-up
            for variant in VARIANTS:
                one_call(head, variant, frame)
        rounds: dict[str, list[dict]] = {v: [] for v in VARIANTS}
        for _ in range(args.rounds):
            for variant in VARIANTS:
                times = []
                for frame in frames:
                    t0 = time.perf_counter()
                    one_call(head, variant, frame)
                    times.append((time.perf_counter() - t0) * 1e3)
                p50, p95 = np.percentile(times, [50, 95])
                rounds[variant].append({"p50": float(p50), "p95": float(p95)})
    results = {}
    for variant in VARIANTS:
        ratios = [r["p50"] / o["p50"] for r, o in zip(rounds[variant], rounds["one_pass"])]
        results[variant] = {
            "p50": float(np.median([r["p50"] for r in rounds[variant]])),
            "p95": float(np.median([r["p95"] for r in rounds[variant]])),
            "ratio_to_one_pass": float(np.median(ratios)),
            "rounds": rounds[variant],
        }
    meta = {
        "checkpoint": args.checkpoint,
        "calls": args.calls,
        "rounds": args.rounds,
        "threads": args.threads,
        "machine": describe_machine(),
    }
    lines = [
        "| variant | p50 ms | p95 ms | p50 / one pass |",
        "|---|---|---|---|",
        *(
            f"| {v} | {r['p50']:.2f} | {r['p95']:.2f} | {r['ratio_to_one_pass']:.2f} |"
            for v, r in results.items()
        ),
    ]
    table = "\n".join(lines)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".json").write_text(
        json.dumps({"meta": meta, "results": results}, indent=2) + "\n"
    )
    args.out.with_suffix(".md").write_text(
        f"# Goal-head latency, batch 1, {args.threads} thread(s); medians of {args.rounds} "
        f"rounds of {args.calls} calls\n\n`python benchmarks/bench_goal_head_latency.py "
        f"--checkpoint {args.checkpoint} --calls {args.calls} --rounds {args.rounds}`\n\n"
        f"{machine_line(meta['machine'])}\n\n{table}\n"
    )
    logger.info("\n%s", table)
    return results


if __name__ == "__main__":
    main()
