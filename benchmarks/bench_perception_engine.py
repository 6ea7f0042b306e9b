"""S2's perception under each inference engine, side by side: PyTorch vs ONNX Runtime, one thread.

    python benchmarks/bench_perception_engine.py --checkpoint checkpoints/vla_gr_cpu \
        [--episodes 3] [--steps 30] [--rounds 5] [--int8]

Records the observations of the checkpoint's S2 ticks (its first ``--steps`` steps of
``--episodes`` ``val`` episodes), then times, interleaved round after round on those frames,
each network as S2 runs it on the episode's request (``goal_head``: the frame and its mirror
as one batch of 2 with the shipped ``test_time_flip``; ``room_type``; ``object_category``)
and the whole ``perceive`` (the checks the request calls for), under ``torch`` and
``onnxruntime`` (the checkpoint's export). Reports the median over rounds
of each round's p50 / p95 (ms per call), the ratio of each p50 to PyTorch's and the largest
difference of the export's outputs from PyTorch's. With ``--int8`` it adds each export
quantised by ONNX Runtime's ``quantize_dynamic`` (int8 weights), with the decisions it keeps
against fp32: IoU of the goal mask (likelihood >= the navigator's pixel threshold), the
segmenter's argmax and the room argmax agreement. Writes ``<out>.json`` and ``<out>.md``.
"""

from __future__ import annotations

import argparse
import json
import logging
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from vla_gr.agent.observations import env_obs_to_frame
from vla_gr.agent.perception.engine import OnnxNetwork
from vla_gr.checkpoint import read_checkpoint
from vla_gr.machine import describe_machine, machine_line
from vla_gr.policy import VLAGRPolicy
from vla_gr.policy.onnx_export import RECORD, tick_observations

logger = logging.getLogger("bench_perception_engine")

ROOT = Path(__file__).resolve().parent
DEFAULT_OUT = ROOT / "results" / "bench_perception_engine"


def network_inputs(policy: VLAGRPolicy, obs: dict) -> dict[str, tuple[torch.Tensor, ...]]:
    """Each perception network's inputs for ``obs`` as S2 builds them (the goal head's with
    the mirrored frame when ``test_time_flip`` is on)."""
    frame = env_obs_to_frame({**obs, "instruction": policy.read(obs["instruction"]).phrase})
    rgb, depth, said = frame["rgb"], frame["depth"], frame["instruction"]
    out = {}
    for name, module in policy.perception_networks().items():
        if name == "goal_head":
            flip = module.config.test_time_flip
            both = (torch.cat([rgb, rgb.flip(-1)]), torch.cat([depth, depth.flip(-1)]))
            out[name] = module.network_inputs(*(both if flip else (rgb, depth)), said * (1 + flip))
        else:
            out[name] = module.network_inputs(rgb, depth)
    return out


def quantised(checkpoint: str, folder: Path) -> dict[str, OnnxNetwork]:
    """Each ONNX export of ``checkpoint`` with int8 weights (``quantize_dynamic``), run like
    the fp32 one."""
    from onnxruntime.quantization import QuantType, quantize_dynamic

    out = {}
    for name, entry in read_checkpoint(checkpoint).manifest[RECORD]["networks"].items():
        target = folder / f"{name}.int8.onnx"
        quantize_dynamic(Path(checkpoint) / entry["file"], target, weight_type=QuantType.QInt8)
        out[name] = OnnxNetwork(target)
    return out


def decisions(policy: VLAGRPolicy, ref: dict, got: dict) -> dict[str, float]:
    """What the navigator would decide from ``got`` against ``ref`` (one frame's outputs of
    every network): goal-mask IoU, segmenter and room argmax agreement."""
    threshold = policy.config.navigator.confirmation.pixel_threshold
    head = policy.goal_head

    def mask(out):
        p = head.pixel_probability(out)
        return (p[:1] + p[1:].flip(-1)) / 2 if len(p) == 2 else p  # the flip's mean

    a, b = mask(ref["goal_head"]) >= threshold, mask(got["goal_head"]) >= threshold
    union = int((a | b).sum())
    seg = ref["object_category"]["logits"].argmax(1) == got["object_category"]["logits"].argmax(1)
    room = ref["room_type"]["logits"].argmax(-1) == got["room_type"]["logits"].argmax(-1)
    return {
        "goal_iou": 1.0 if union == 0 else int((a & b).sum()) / union,
        "with_goal_pixels": float(union > 0),
        "segmenter_agreement": float(seg.float().mean()),
        "room_agreement": float(room.float().mean()),
    }


def time_calls(calls: dict, frames: list, rounds: int) -> dict[str, dict]:
    """``calls`` (variant -> fn(frame)) timed interleaved, ``rounds`` times over ``frames``
    (here (observation, network inputs) pairs):
    per variant the median over rounds of p50 / p95 (ms) and the p50 of every round."""
    per_round: dict[str, list] = {name: [] for name in calls}
    for frame in frames[:5]:  # warm-up
        for fn in calls.values():
            fn(frame)
    for _ in range(rounds):
        for name, fn in calls.items():
            times = []
            for frame in frames:
                t0 = time.perf_counter()
                fn(frame)
                times.append((time.perf_counter() - t0) * 1e3)
            per_round[name].append(np.percentile(times, [50, 95]).tolist())
    return {
        name: {
            "p50": float(np.median([r[0] for r in rows])),
            "p95": float(np.median([r[1] for r in rows])),
            "p50_rounds": [round(r[0], 3) for r in rows],
        }
        for name, rows in per_round.items()
    }


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", default="checkpoints/vla_gr_cpu")
    parser.add_argument("--episodes", type=int, default=3)
    parser.add_argument("--steps", type=int, default=30, help="steps recorded per episode")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--int8", action="store_true", help="add the int8-quantised exports")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(asctime)s %(name)s: %(message)s")
    logger.setLevel(logging.INFO)  # the quantiser logs each tensor at INFO on the root logger
    torch.set_num_threads(1)
    engines = {
        engine: VLAGRPolicy.from_pretrained(
            args.checkpoint, overrides=[f"perception.engine={engine}"]
        )
        for engine in ("torch", "onnxruntime")
    }
    reference, onnx = engines["torch"], engines["onnxruntime"]
    frames = tick_observations(onnx, range(args.episodes), args.steps)
    inputs = [network_inputs(reference, obs) for obs in frames]
    runners = {"torch": reference.perception_networks(), "onnxruntime": onnx.perception.networks}
    with tempfile.TemporaryDirectory() as tmp:
        if args.int8:
            runners["onnxruntime_int8"] = quantised(args.checkpoint, Path(tmp))
        calls = {}
        for engine, nets in runners.items():
            for name, net in nets.items():
                run = net.network if engine == "torch" else net
                calls[f"{name}/{engine}"] = lambda x, run=run, name=name: run(*x[1][name])
        for engine, policy in engines.items():  # the whole perceive, one reading per request
            forks = {}
            for obs in frames:
                if obs["instruction"] not in forks:
                    forks[obs["instruction"]] = policy.perception.fork()
                    forks[obs["instruction"]].read(obs["instruction"])
            calls[f"perceive/{engine}"] = lambda x, f=forks: f[x[0]["instruction"]].perceive(x[0])
        worst: dict[str, dict] = {engine: {} for engine in runners if engine != "torch"}
        kept: dict[str, list] = {engine: [] for engine in worst}
        with torch.no_grad():
            for x in inputs:
                ref = {name: net.network(*x[name]) for name, net in runners["torch"].items()}
                for engine in worst:
                    got = {name: run(*x[name]) for name, run in runners[engine].items()}
                    for name, out in got.items():
                        for key, value in out.items():
                            error = float((value - ref[name][key]).abs().max())
                            k = f"{name}.{key}"
                            worst[engine][k] = max(worst[engine].get(k, 0.0), error)
                    kept[engine].append(decisions(reference, ref, got))
            timings = time_calls(calls, list(zip(frames, inputs)), args.rounds)
    decided = {
        engine: {k: float(np.mean([row[k] for row in rows])) for k in rows[0]}
        for engine, rows in kept.items()
    }
    decided |= {
        f"{engine}_min": {k: float(np.min([row[k] for row in rows])) for k in rows[0]}
        for engine, rows in kept.items()
    }
    for name, row in timings.items():
        part, engine = name.split("/")
        row["ratio_to_torch"] = row["p50"] / timings[f"{part}/torch"]["p50"]
    meta = {
        "checkpoint": args.checkpoint,
        "frames": len(frames),
        "rounds": args.rounds,
        "threads": 1,
        "machine": describe_machine(),
    }
    out = {"meta": meta, "timings": timings, "max_abs_error": worst, "decisions": decided}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".json").write_text(json.dumps(out, indent=2) + "\n")
    lines = [
        "| part | engine | p50 ms | p95 ms | p50 / torch |",
        "|---|---|---|---|---|",
        *(
            f"| {name.split('/')[0]} | {name.split('/')[1]} | {r['p50']:.2f} | {r['p95']:.2f} "
            f"| {r['ratio_to_torch']:.2f} |"
            for name, r in sorted(timings.items(), key=lambda item: item[0].split("/")[0])
        ),
    ]
    errors = [
        "| engine | output | max abs difference from torch |",
        "|---|---|---|",
        *(f"| {e} | {k} | {v:.2e} |" for e, rows in worst.items() for k, v in rows.items()),
    ]
    kept_lines = [
        "| engine | frames with goal pixels | goal-mask IoU (mean / min) | segmenter argmax "
        "agrees | room argmax agrees |",
        "|---|---|---|---|---|",
        *(
            f"| {e} | {decided[e]['with_goal_pixels']:.2f} | "
            f"{decided[e]['goal_iou']:.4f} / {decided[e + '_min']['goal_iou']:.4f} | "
            f"{decided[e]['segmenter_agreement']:.4f} | {decided[e]['room_agreement']:.4f} |"
            for e in kept
        ),
    ]
    command = (
        f"python benchmarks/bench_perception_engine.py --checkpoint {args.checkpoint} "
        f"--episodes {args.episodes} --steps {args.steps} --rounds {args.rounds}"
        + (" --int8" if args.int8 else "")
    )
    shared = ""
    if meta["machine"]["load_average"][0] > 1.0:  # one thread of ours; the rest is others'
        shared = (
            "Taken while other jobs shared the machine (the load average above): the engines "
            "ran interleaved, so their ratios hold better than their milliseconds; rerun on a "
            "quiet machine for figures to quote.\n\n"
        )
    args.out.with_suffix(".md").write_text(
        f"# S2 perception by engine, batch 1, one thread; medians of {args.rounds} rounds over "
        f"{len(frames)} S2-tick frames\n\n`{command}`\n\n{machine_line(meta['machine'])}\n\n"
        + shared
        + "\n".join(lines)
        + "\n\nOutputs against PyTorch on the same frames:\n\n"
        + "\n".join(errors)
        + "\n\nDecisions against PyTorch's (the navigator's pixel threshold):\n\n"
        + "\n".join(kept_lines)
        + "\n"
    )
    logger.info("\n%s\n\n%s\n\n%s", "\n".join(lines), "\n".join(errors), "\n".join(kept_lines))
    return out


if __name__ == "__main__":
    main()
