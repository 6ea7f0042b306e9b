"""Training throughput of a recipe: samples/s of train_step (median of several runs).

    python benchmarks/bench_train.py                       # config_end_to_end on this machine
    python benchmarks/bench_train.py --config config_rtx4060 --cap-gb 8   # on a GPU
    python benchmarks/bench_train.py --config config_server                # bf16 + compile

Uses the recipe's model, batch size, accumulation, AMP and compile settings on a
synthetic episode store of the recipe's image size (data loading included), so the
figure does not depend on a collected dataset. Writes benchmarks/results/bench_train_<config>.md
and .json.
"""

from __future__ import annotations

import argparse
import json
import logging
import statistics
import tempfile
import time
from pathlib import Path

import torch

from vla_gr.configs import load_config
from vla_gr.machine import cpu_model
from vla_gr.train import build_policy
from vla_gr.training.data import build_datasets, build_loaders, write_synthetic_store
from vla_gr.training.distributed import DistInfo, resolve_device
from vla_gr.training.ema import EMA
from vla_gr.training.optim import build_optimizer, build_scheduler
from vla_gr.training.step import train_step

RESULTS = Path(__file__).resolve().parent / "results"


def one_run(cfg, store: Path, steps: int, warmup: int, device: torch.device) -> dict:
    """Time ``steps`` optimiser steps after ``warmup`` untimed ones."""
    t = cfg.training
    train_set, _ = build_datasets(cfg, store)
    loader, _, _ = build_loaders(cfg, DistInfo(device=device), train_set, None)
    model = build_policy(cfg, train_set.get_normalizers()).to(device)
    ema = EMA(model, t.ema_decay) if t.ema_decay > 0 else None
    opt = build_optimizer(model, t.lr, t.weight_decay)
    sched = build_scheduler(opt, t.warmup_steps, t.steps, t.min_lr_ratio)
    scaler = torch.amp.GradScaler(device.type) if t.amp == "fp16" else None
    step_model = torch.compile(model) if t.compile else model
    batches = iter(loader)

    def next_batches():
        nonlocal batches
        out = []
        for _ in range(t.grad_accum):
            try:
                out.append(next(batches))
            except StopIteration:
                batches = iter(loader)
                out.append(next(batches))
        return out

    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats(device)
    for i in range(warmup + steps):
        if i == warmup:
            if device.type == "cuda":
                torch.cuda.synchronize(device)
            t0 = time.perf_counter()
        train_step(
            step_model,
            next_batches(),
            opt,
            scheduler=sched,
            scaler=scaler,
            ema=ema,
            ema_target=model,
            amp=t.amp,
            grad_clip=t.grad_clip,
            device=device,
        )
    if device.type == "cuda":
        torch.cuda.synchronize(device)
    elapsed = time.perf_counter() - t0
    samples = steps * t.batch_size * t.grad_accum
    out = {"samples_per_s": samples / elapsed, "steps_per_s": steps / elapsed}
    if device.type == "cuda":
        out["peak_memory_gb"] = torch.cuda.max_memory_allocated(device) / 2**30
    out["parameters_m"] = sum(p.numel() for p in model.parameters()) / 1e6
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="config_end_to_end")
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--steps", type=int, default=10)
    parser.add_argument("--warmup", type=int, default=2)
    parser.add_argument("--threads", type=int, default=0, help="torch threads (0: default)")
    parser.add_argument("--cap-gb", type=float, default=0.0, help="cap CUDA memory (GiB)")
    parser.add_argument("overrides", nargs="*")
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING)
    if args.threads:
        torch.set_num_threads(args.threads)
    resolved, cfg = load_config(args.config, args.overrides)
    device = resolve_device(cfg.training.device if torch.cuda.is_available() else "cpu")
    if args.cap_gb and device.type == "cuda":
        total = torch.cuda.get_device_properties(device).total_memory / 2**30
        torch.cuda.set_per_process_memory_fraction(min(1.0, args.cap_gb / total), device)
    with tempfile.TemporaryDirectory() as tmp:
        store = Path(tmp) / "bench.zarr"
        write_synthetic_store(store, 6, 64, cfg.model.image_size, cfg.seed)
        runs = [one_run(cfg, store, args.steps, args.warmup, device) for _ in range(args.runs)]
    sps = [r["samples_per_s"] for r in runs]
    cpu = f"CPU ({cpu_model()}), {torch.get_num_threads()} threads"
    result = {
        "config": args.config,
        "overrides": args.overrides,
        "device": torch.cuda.get_device_name(device) if device.type == "cuda" else cpu,
        "torch": torch.__version__,
        "amp": cfg.training.amp,
        "compile": cfg.training.compile,
        "batch_size": cfg.training.batch_size,
        "grad_accum": cfg.training.grad_accum,
        "image_size": cfg.model.image_size,
        "parameters_m": runs[0]["parameters_m"],
        "runs": args.runs,
        "timed_steps_per_run": args.steps,
        "samples_per_s_median": statistics.median(sps),
        "samples_per_s_min": min(sps),
        "samples_per_s_max": max(sps),
        "steps_per_s_median": statistics.median(r["steps_per_s"] for r in runs),
    }
    if device.type == "cuda":
        result["peak_memory_gb_max"] = max(r["peak_memory_gb"] for r in runs)
    RESULTS.mkdir(exist_ok=True)
    stem = RESULTS / f"bench_train_{args.config}"
    stem.with_suffix(".json").write_text(json.dumps(result, indent=1) + "\n")
    lines = [f"# Training throughput: {args.config}", "", "| key | value |", "|---|---|"]
    lines += [
        f"| {k} | {v:.3g} |" if isinstance(v, float) else f"| {k} | {v} |"
        for k, v in result.items()
    ]
    stem.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))  # noqa: T201 (a script's report)


if __name__ == "__main__":
    main()
