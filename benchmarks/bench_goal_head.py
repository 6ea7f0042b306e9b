"""The goal head on unseen houses: per-pixel precision / recall / IoU, goal-visible accuracy,
predicted goal pixels on distractors, per instruction kind, and its latency at batch 1.

    python benchmarks/bench_goal_head.py --checkpoint outputs/train/<run>/checkpoints/best \
        [--episodes 60] [--split val] [--store data/expert_val.zarr] [--threads 1]

Collects ``--episodes`` expert episodes of ``--split`` (houses the training split never
shows) with goal and distractor masks into ``--store`` (a temporary folder by default; an
existing store is reused and completed), with the checkpoint's env and expert settings. Every
frame is scored: a pixel is predicted goal when its probability is >= the checkpoint's
``model.grounding.threshold``, a frame "goal visible" likewise; a frame shows the goal when
it covers >= ``model.grounding.min_pixels`` pixels. The instruction kind is what the
instruction uses to single out its object (``parse_instruction``): colour, room, relation or
a combination. Latency: one ``GoalHead.likelihood`` call at batch 1 on one thread, with the
instruction's embedding cached (it is constant over an episode). A head with a category output
also gets that output's pixel precision / recall / IoU against every instance of the
instructed category (goal | distractors). ``--paraphrase`` scores the same frames with each
instruction rewritten by :func:`vla_gr.envs.paraphrase.paraphrase` (synonyms and sentence
shapes the templates never use; one fixed rewrite per instruction), to tell whether the
paraphrase gap of the closed loop is the goal head's. Writes ``<out>.json`` and ``<out>.md``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import tempfile
import time
import zlib
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from omegaconf import OmegaConf

from vla_gr.agent.perception import confusion_metrics, mask_confusion
from vla_gr.checkpoint import read_checkpoint
from vla_gr.configs.schema import VLAGRConfig
from vla_gr.data.goal_frames import GoalFrameDataset
from vla_gr.data.store import EpisodeStore
from vla_gr.envs.instructions import parse_instruction
from vla_gr.machine import describe_machine
from vla_gr.policy import VLAGRPolicy

logger = logging.getLogger("bench_goal_head")

ROOT = Path(__file__).resolve().parent
DEFAULT_OUT = ROOT / "results" / "bench_goal_head"
KIND_WORDS = (("color", "colour"), ("room", "room"), ("near", "relation"))
SHOWN = ("pixel_precision", "pixel_recall", "pixel_iou", "visible_accuracy", "on_distractor")

#: rgb (B, 3, H, W) uint8, depth (B, 1, H, W), instructions -> (pixel prob (B, H, W), visible (B,))
#: (rgb, depth, instructions) -> (pixel (B, H, W), visible (B,)[, category (B, H, W)])
Predictor = Callable[[torch.Tensor, torch.Tensor, list[str]], tuple[torch.Tensor, ...]]


def instruction_kind(text: str) -> str:
    """What singles out the goal: 'colour', 'room', 'relation', 'colour+room', ... or 'category'."""
    parsed = parse_instruction(text)
    kind = "+".join(word for key, word in KIND_WORDS if parsed[key] is not None)
    return kind or "category"


def checkpoint_config(checkpoint: str | Path) -> VLAGRConfig:
    """The validated config a checkpoint was trained with."""
    saved = OmegaConf.create(read_checkpoint(checkpoint).config_yaml)
    return OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(VLAGRConfig), saved))


def held_out_store(
    cfg: VLAGRConfig, path: Path, split: str, episodes: int, workers: int
) -> EpisodeStore:
    """Episodes 0..episodes-1 of ``split`` at ``path`` (collected with masks where missing)."""
    from vla_gr.data.collect import collect

    c = dataclasses.replace(
        cfg.collect,
        split=split,
        num_episodes=episodes,
        first_episode=0,
        output=str(path),
        mode="append",
        workers=workers,
        progress=False,
    )
    collect(dataclasses.replace(cfg, collect=c))
    store = EpisodeStore.open(path)
    if "distractor_mask" not in store.frame_keys:
        store.data_array("distractor_mask")  # raises: the store predates distractor masks
    return store


def score_store(
    predict: Predictor,
    store: EpisodeStore,
    threshold: float,
    min_pixels: int,
    batch_size: int = 64,
) -> dict:
    """Metrics of ``predict`` on every frame of ``store``: overall and per instruction kind.

    Returns ``{"overall": {...}, "by_kind": {kind: {...}}}``; each entry holds the
    ``confusion_metrics`` ratios, the summed counts and ``episodes``. When ``predict`` also
    returns a category probability and the store has distractor masks, ``"category"`` holds
    its pixel metrics against goal | distractors.
    """
    frames = GoalFrameDataset(store, min_pixels=min_pixels)
    kinds = [instruction_kind(t) for t in frames.instructions]
    slot = frames.where[:, 0]  # (N,) instruction slot of each frame
    counts: dict[str, dict[str, int]] = {}
    with torch.no_grad():
        for start in range(0, len(frames), batch_size):
            items = [frames[i] for i in range(start, min(start + batch_size, len(frames)))]
            rgb = torch.stack([it["rgb"] for it in items])  # (B, 3, H, W)
            depth = torch.stack([it["depth"] for it in items])  # (B, 1, H, W)
            target = torch.stack([it["goal_mask"] for it in items])  # (B, H, W)
            others = (
                torch.stack([it["distractor_mask"] for it in items])  # (B, H, W)
                if frames.distractor_mask is not None
                else None
            )
            pixel, visible, *category = predict(rgb, depth, [it["instruction"] for it in items])
            if category and others is not None:
                part = mask_confusion(category[0], visible, target | others, threshold, min_pixels)
                total = counts.setdefault("category", dict.fromkeys(part, 0))
                for key, n in part.items():
                    total[key] += n
            batch_kinds = np.asarray([kinds[s] for s in slot[start : start + len(items)]])
            for kind in ("overall", *sorted(set(batch_kinds))):
                sel = torch.ones(len(items), dtype=torch.bool)
                if kind != "overall":
                    sel = torch.from_numpy(batch_kinds == kind)
                part = mask_confusion(
                    pixel[sel],
                    visible[sel],
                    target[sel],
                    threshold,
                    min_pixels,
                    others[sel] if others is not None else None,
                )
                total = counts.setdefault(kind, dict.fromkeys(part, 0))
                for key, n in part.items():
                    total[key] += n
    episodes = {k: sum(1 for x in kinds if x == k) for k in set(kinds)}
    episodes |= {"overall": len(kinds), "category": len(kinds)}
    summary = {
        kind: confusion_metrics(c) | {"counts": c, "episodes": episodes[kind]}
        for kind, c in counts.items()
    }
    result = {"overall": summary.pop("overall")}
    if "category" in summary:
        result["category"] = summary.pop("category")
    return result | {"by_kind": summary}


def latency(policy: VLAGRPolicy, repeats: int = 200, threads: int = 1) -> dict[str, float]:
    """p50 / p95 (ms) of one goal-head call at batch 1 on ``threads`` threads."""
    S = policy.config.image_size
    g = torch.Generator().manual_seed(0)
    rgb = torch.randint(0, 256, (1, 3, S, S), dtype=torch.uint8, generator=g)  # (1, 3, S, S)
    depth = torch.rand(1, 1, S, S, generator=g) * 5.0  # (1, 1, S, S)
    instruction = ["find the red chair in the kitchen"]
    previous = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        for _ in range(5):  # warm-up (and the instruction's embedding is cached)
            policy.goal_head.likelihood(rgb, depth, instruction)
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            policy.goal_head.likelihood(rgb, depth, instruction)
            times.append(time.perf_counter() - t0)
    finally:
        torch.set_num_threads(previous)
    ms = np.asarray(times) * 1e3
    return {
        "p50_ms": float(np.percentile(ms, 50)),
        "p95_ms": float(np.percentile(ms, 95)),
        "threads": threads,
        "repeats": repeats,
    }


def table(result: dict) -> str:
    """Markdown table: one row overall, one per instruction kind, then the latency."""
    head = "| frames of | episodes | precision | recall | IoU | visible acc. | on distractor |"
    lines = [head, "|---|---|---|---|---|---|---|"]
    rows = [("all", result["overall"])] + sorted(result["by_kind"].items())
    for name, m in rows:
        values = " | ".join(f"{m[k]:.3f}" for k in SHOWN)
        lines.append(f"| {name} | {m['episodes']} | {values} |")
    if "category" in result:
        c = result["category"]
        lines.append(
            f"\nCategory output vs every instance of the instructed category: precision "
            f"{c['pixel_precision']:.3f}, recall {c['pixel_recall']:.3f}, IoU {c['pixel_iou']:.3f}"
        )
    lat = result["latency"]
    lines.append(
        f"\nGoal head at batch 1, {lat['threads']} thread(s): "
        f"p50 {lat['p50_ms']:.2f} ms, p95 {lat['p95_ms']:.2f} ms"
    )
    return "\n".join(lines)


def write_results(result: dict, out: Path) -> None:
    """``<out>.json`` (NaN as null) and ``<out>.md``."""
    out.parent.mkdir(parents=True, exist_ok=True)

    def clean(value):
        if isinstance(value, dict):
            return {k: clean(v) for k, v in value.items()}
        if isinstance(value, float) and not np.isfinite(value):
            return None
        return value

    out.with_suffix(".json").write_text(json.dumps(clean(result), indent=2) + "\n")
    command = result["command"]
    out.with_suffix(".md").write_text(
        f"# Goal head on held-out houses\n\n`{command}`\n\n{table(result)}\n"
    )


def rewrite(instruction: str) -> str:
    """One fixed paraphrase of ``instruction`` (its rng is seeded by the text's CRC32)."""
    from vla_gr.envs.paraphrase import paraphrase

    return paraphrase(instruction, np.random.default_rng(zlib.crc32(instruction.encode())))


def run(args: argparse.Namespace) -> dict:
    """Collect (or reuse) the held-out store, score the checkpoint, time it; returns the result."""
    policy = VLAGRPolicy.from_pretrained(args.checkpoint)  # refuses a checkpoint without one
    cfg = checkpoint_config(args.checkpoint)
    g = policy.config.grounding
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(args.store) if args.store else Path(tmp) / f"{args.split}.zarr"
        store = held_out_store(cfg, path, args.split, args.episodes, args.workers)

        def predict(rgb, depth, instructions):
            if args.paraphrase:
                instructions = [rewrite(text) for text in instructions]
            probs = policy.goal_head.probabilities(rgb, depth, instructions)
            extra = (probs["category"],) if "category" in probs else ()  # (B, H, W)
            return probs["pixel"], probs["visible"], *extra

        result = score_store(predict, store, g.threshold, g.min_pixels, args.batch_size)
        result["frames"] = store.num_frames
    result["latency"] = latency(policy, args.repeats, args.threads)
    result["command"] = "python benchmarks/bench_goal_head.py " + " ".join(args.argv)
    result["checkpoint"] = str(args.checkpoint)
    result["split"], result["episodes"] = args.split, args.episodes
    result["paraphrase"] = bool(args.paraphrase)
    result["threshold"], result["min_pixels"] = g.threshold, g.min_pixels
    result["machine"] = describe_machine()
    return result


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--checkpoint", required=True, help="<run>/checkpoints/best")
    p.add_argument("--episodes", type=int, default=60, help="held-out episodes 0..N-1")
    p.add_argument("--split", default="val", choices=("val", "test", "train"))
    p.add_argument("--store", default=None, help="held-out store to reuse / fill (default: tmp)")
    p.add_argument("--workers", type=int, default=2, help="collection processes")
    p.add_argument("--batch-size", type=int, default=64)
    p.add_argument("--repeats", type=int, default=200, help="latency repetitions")
    p.add_argument("--threads", type=int, default=1, help="torch threads for the latency")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help="results path without suffix")
    p.add_argument("--paraphrase", action="store_true", help="score paraphrased instructions")
    args = p.parse_args(argv)
    args.argv = list(argv) if argv is not None else []
    return args


def main(argv: list[str] | None = None) -> dict:
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    import sys

    args = parse_args(argv if argv is not None else sys.argv[1:])
    result = run(args)
    write_results(result, args.out)
    print(table(result))
    return result


if __name__ == "__main__":
    main()
