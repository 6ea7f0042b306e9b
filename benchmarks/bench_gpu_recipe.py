"""The 8 GB consumer-GPU recipe (``config_rtx4060``): its goal-head stage on CUDA for a few steps.

    python benchmarks/bench_gpu_recipe.py                      # fp16 (the recipe), fp32, bf16
    python benchmarks/bench_gpu_recipe.py --steps 20 --warmup 3 --amp fp16 none
    python benchmarks/bench_gpu_recipe.py --device cpu --steps 2 --warmup 1 --amp none \
        training.grad_accum=1 training.num_workers=0          # smoke run of the script itself

Runs the library's own training loop (``load_config`` + ``vla_gr.train.train``, what the
recipe's ``goal_head`` and ``round1`` stages run) on a synthetic episode store of the recipe's
image size (``write_synthetic_store``: frames with goal and distractor masks), with
``model.goal_head.text_encoder=hashed`` (the recipe's frozen MiniLM needs downloaded weights;
the hashed encoder changes the text tower only, not the U-Net that dominates memory). Everything
else is the recipe: the dual-system agent's goal head at 128 px, micro-batch 16 x accumulation
2, gradient checkpointing of the goal head's stages, fused AdamW, EMA, data loader workers;
validation and a checkpoint run once, at the last step. ``--amp`` runs the recipe once per mode
(``fp16``: autocast + GradScaler, as shipped; ``none``: fp32; ``bf16``: autocast without a
scaler).

Per mode it records, around each ``train_step`` the loop calls: its seconds (CUDA-synchronised),
the wall seconds from one step's start to the next (data loading and augmentation included),
the loss, the gradient norm and the GradScaler's scale; the median is over the steps after the
first ``--warmup``. Peak memory is ``torch.cuda.max_memory_allocated`` (tensors) and
``max_memory_reserved`` (the caching allocator's pool) over the whole run, model construction
and the final validation + checkpoint included; neither counts the CUDA context (a few hundred
MiB more on the card). Writes ``<out>.json`` and ``<out>.md`` (``--out``; by default
benchmarks/results/bench_gpu_recipe on CUDA and .../bench_gpu_recipe_cpu_smoke on CPU).
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import statistics
import sys
import tempfile
import time
import traceback
from pathlib import Path

import torch

import vla_gr.train as train_module
from vla_gr.configs import load_config
from vla_gr.machine import describe_machine, machine_line
from vla_gr.training.data import write_synthetic_store

RESULTS = Path(__file__).resolve().parent / "results"
CONFIG = "config_rtx4060"
CLAIM_GIB = 8.0  # the recipe's claim: fits an 8 GB card (RTX 4060)
GIB = 2**30
TRAIN_STEP = train_module.train_step  # the loop's step, restored after each run


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


class StepRecorder:
    """Wraps ``vla_gr.train.train_step`` (the function the training loop calls) and records
    each optimizer step: seconds inside it, wall seconds since the previous step's start, the
    loss, the gradient norm and the GradScaler's scale after the step."""

    def __init__(self, inner, device: torch.device, total: int) -> None:
        self.inner, self.device, self.total = inner, device, total
        self.rows: list[dict] = []
        self._last_start: float | None = None
        self.parameters = self.trainable = 0

    def __call__(self, model, *args, **kwargs):
        if not self.rows:
            self.parameters = sum(p.numel() for p in model.parameters())
            self.trainable = sum(p.numel() for p in model.parameters() if p.requires_grad)
        _sync(self.device)
        start = time.perf_counter()
        out = self.inner(model, *args, **kwargs)
        _sync(self.device)
        end = time.perf_counter()
        scaler = kwargs.get("scaler")
        row = {
            "step": len(self.rows) + 1,
            "step_s": end - start,
            "wall_s": None if self._last_start is None else start - self._last_start,
            "loss": out["loss"],
            "grad_norm": out["grad_norm"],
            "lr": out["lr"],
            "scale": float(scaler.get_scale()) if scaler is not None else None,
        }
        if self.device.type == "cuda":
            row["max_allocated_gib"] = torch.cuda.max_memory_allocated(self.device) / GIB
        self._last_start = start
        self.rows.append(row)
        scale = f" scale {row['scale']:.0f}" if row["scale"] is not None else ""
        print(  # noqa: T201 (progress of a long script)
            f"  step {row['step']}/{self.total}: {row['step_s']:.3f} s, loss {row['loss']:.4f}, "
            f"grad norm {row['grad_norm']:.3g}{scale}",
            flush=True,
        )
        return out


def _median(values) -> float | None:
    values = [v for v in values if v is not None]
    return statistics.median(values) if values else None


def one_mode(amp: str, args, store: Path, runs: Path, device: torch.device) -> dict:
    """Train the recipe with ``training.amp=amp`` for ``warmup + steps`` optimizer steps."""
    total = args.warmup + args.steps
    overrides = [
        "model.goal_head.text_encoder=hashed",
        f"training.device={device.type}",
        f"training.amp={amp}",
        f"training.steps={total}",
        "training.log_every=1",
        f"training.dataset={store}",
        f"training.output_dir={runs}",
        f"training.run_name={amp}",
        "logging.tensorboard=false",
        "logging.progress=false",
        *args.overrides,
    ]
    resolved, cfg = load_config(CONFIG, overrides)
    t = cfg.training
    recorder = StepRecorder(TRAIN_STEP, device, total)
    if device.type == "cuda":
        torch.cuda.empty_cache()
        torch.cuda.reset_peak_memory_stats(device)
    start = time.perf_counter()
    train_module.train_step = recorder
    try:
        summary = train_module.train(cfg, resolved)
    finally:
        train_module.train_step = TRAIN_STEP
    _sync(device)
    elapsed = time.perf_counter() - start
    timed = recorder.rows[args.warmup :]
    losses = [r["loss"] for r in recorder.rows]
    scales = [r["scale"] for r in recorder.rows if r["scale"] is not None]
    # A GradScaler halves its scale on each step whose fp16 gradients overflowed (the
    # optimizer step is then skipped); it starts at 2**16 and grows only every 2000 steps.
    skipped = sum(1 for a, b in zip([2.0**16, *scales], scales, strict=False) if b < a)
    step_s = _median(r["step_s"] for r in timed)
    result = {
        "amp": amp,
        "status": "ok",
        "optimizer_steps": len(recorder.rows),
        "timed_steps": len(timed),
        "micro_batch": t.batch_size,
        "grad_accum": t.grad_accum,
        "samples_per_step": t.batch_size * t.grad_accum,
        "image_size": cfg.model.image_size,
        "parameters_m": recorder.parameters / 1e6,
        "trainable_parameters_m": recorder.trainable / 1e6,
        "step_s_median": step_s,
        "step_s_min": min((r["step_s"] for r in timed), default=None),
        "step_s_max": max((r["step_s"] for r in timed), default=None),
        "wall_s_median": _median(r["wall_s"] for r in timed),
        "samples_per_s": (t.batch_size * t.grad_accum / step_s) if step_s else None,
        "first_step_s": recorder.rows[0]["step_s"] if recorder.rows else None,
        "run_s": elapsed,
        "loss_first": losses[0] if losses else None,
        "loss_last": losses[-1] if losses else None,
        "loss_first5_mean": statistics.fmean(losses[:5]) if losses else None,
        "loss_last5_mean": statistics.fmean(losses[-5:]) if losses else None,
        "loss_all_finite": all(math.isfinite(x) for x in losses),
        "lr_last": recorder.rows[-1]["lr"] if recorder.rows else None,
        "grad_scale_first": scales[0] if scales else None,
        "grad_scale_last": scales[-1] if scales else None,
        "grad_scale_min": min(scales) if scales else None,
        "skipped_steps": skipped if scales else None,
        "val_loss": summary.get("val_loss"),
        "steps": recorder.rows,
    }
    if device.type == "cuda":
        peak = torch.cuda.max_memory_allocated(device) / GIB
        during = max((r["max_allocated_gib"] for r in recorder.rows), default=0.0)
        free, card = torch.cuda.mem_get_info(device)
        result |= {
            "peak_allocated_gib": peak,
            "peak_allocated_training_gib": during,
            "peak_reserved_gib": torch.cuda.max_memory_reserved(device) / GIB,
            "device_used_after_run_gib": (card - free) / GIB,
            "within_8gb_claim": peak < CLAIM_GIB,
        }
    return result


def machine(device: torch.device) -> dict:
    info = describe_machine()
    if device.type == "cuda":
        props = torch.cuda.get_device_properties(device)
        info |= {
            "gpu": torch.cuda.get_device_name(device),
            "gpu_memory_gib": props.total_memory / GIB,
            "gpu_capability": f"{props.major}.{props.minor}",
            "cuda": torch.version.cuda,
            "cudnn": torch.backends.cudnn.version(),
        }
    return info


def _fmt(value, spec: str = ".3g") -> str:
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return format(value, spec)
    return str(value)


ROWS = (
    ("status", "status", ""),
    ("optimizer steps (timed after warm-up)", None, ""),
    ("micro-batch x accumulation", None, ""),
    ("parameters (M)", "parameters_m", ".3g"),
    ("peak CUDA memory allocated (GiB)", "peak_allocated_gib", ".2f"),
    ("peak allocated during train steps (GiB)", "peak_allocated_training_gib", ".2f"),
    ("peak CUDA memory reserved (GiB)", "peak_reserved_gib", ".2f"),
    ("within the 8 GB claim (allocated < 8 GiB)", "within_8gb_claim", ""),
    ("median s / optimizer step (train_step)", "step_s_median", ".3f"),
    ("min / max s / optimizer step", None, ""),
    ("median wall s / step (data loading included)", "wall_s_median", ".3f"),
    ("samples / s (train_step)", "samples_per_s", ".1f"),
    ("first step s (allocation, kernel selection)", "first_step_s", ".2f"),
    ("loss: first / last step", None, ""),
    ("loss: mean of first 5 / last 5 steps", None, ""),
    ("loss finite at every step", "loss_all_finite", ""),
    ("lr at the last step", "lr_last", ".2e"),
    ("GradScaler scale: first / last / min", None, ""),
    ("optimizer steps skipped (fp16 overflow)", "skipped_steps", ""),
    ("held-out loss at the end (EMA weights)", "val_loss", ".4f"),
)


def _cell(result: dict, label: str, key: str | None, spec: str) -> str:
    if result.get("status") != "ok" and key != "status":
        return "-"
    if key is not None:
        return _fmt(result.get(key), spec) if spec else _fmt(result.get(key))
    if label.startswith("optimizer steps"):
        return f"{result['optimizer_steps']} ({result['timed_steps']} timed)"
    if label.startswith("micro-batch"):
        return f"{result['micro_batch']} x {result['grad_accum']}"
    if label.startswith("min / max"):
        return f"{_fmt(result['step_s_min'], '.3f')} / {_fmt(result['step_s_max'], '.3f')}"
    if label.startswith("loss: first / last"):
        return f"{_fmt(result['loss_first'], '.4f')} / {_fmt(result['loss_last'], '.4f')}"
    if label.startswith("loss: mean"):
        a, b = result["loss_first5_mean"], result["loss_last5_mean"]
        return f"{_fmt(a, '.4f')} / {_fmt(b, '.4f')}"
    if label.startswith("GradScaler"):
        keys = ("grad_scale_first", "grad_scale_last", "grad_scale_min")
        values = [result.get(k) for k in keys]
        return " / ".join(_fmt(v, ".0f") for v in values) if values[0] is not None else "-"
    return "-"


def markdown(report: dict) -> str:
    results = report["results"]
    m = report["machine"]
    title = f"# The 8 GB recipe ({CONFIG}) on {m.get('gpu', report['device'])}"
    lines = [title, ""]
    header = "| | " + " | ".join(f"amp={r['amp']}" for r in results) + " |"
    lines += [header, "|---" * (len(results) + 1) + "|"]
    for label, key, spec in ROWS:
        lines.append(
            f"| {label} | " + " | ".join(_cell(r, label, key, spec) for r in results) + " |"
        )
    lines += ["", f"Command: `{report['command']}`", ""]
    if "gpu" in m:
        lines.append(
            f"GPU: {m['gpu']} ({m['gpu_memory_gib']:.0f} GiB, compute capability "
            f"{m['gpu_capability']}), CUDA {m['cuda']}, cuDNN {m['cudnn']}."
        )
    lines.append(machine_line(m))
    lines += [
        "",
        f"Synthetic store: {report['store']['episodes']} episodes x {report['store']['length']} "
        f"steps of {report['store']['image_size']}^2 frames; "
        "`model.goal_head.text_encoder=hashed` (no MiniLM weights); every other setting is the "
        "recipe's (with the overrides in the command). Peak memory is PyTorch's "
        "max_memory_allocated / max_memory_reserved over the whole run (model construction, "
        "the final validation and checkpoint included); the CUDA context adds a few hundred MiB "
        "on the card.",
    ]
    if "gpu" in m:
        lines[-1] += f" Timings come from the {m['gpu']}, not from an RTX 4060."
    for r in results:
        if r.get("status") != "ok":
            lines += ["", f"amp={r['amp']} failed: `{r['error']}`"]
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cuda", choices=("cuda", "cpu"))
    parser.add_argument("--steps", type=int, default=20, help="timed optimizer steps per mode")
    parser.add_argument("--warmup", type=int, default=3, help="untimed first optimizer steps")
    parser.add_argument(
        "--amp", nargs="+", default=["fp16", "none", "bf16"], help="modes, in order"
    )
    parser.add_argument("--episodes", type=int, default=16, help="synthetic episodes")
    parser.add_argument("--length", type=int, default=64, help="steps per synthetic episode")
    parser.add_argument("--out", type=Path, default=None, help="results path without suffix")
    parser.add_argument("overrides", nargs="*", help="extra Hydra overrides (key=value)")
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING)
    if args.device == "cuda" and not torch.cuda.is_available():
        sys.exit(
            "bench_gpu_recipe: no CUDA device is visible to torch "
            f"({torch.__version__}, built for CUDA {torch.version.cuda}); this benchmark "
            "measures the GPU recipe and needs one (use --device cpu for a smoke run)"
        )
    device = torch.device("cuda", 0) if args.device == "cuda" else torch.device("cpu")
    default = "bench_gpu_recipe" if device.type == "cuda" else "bench_gpu_recipe_cpu_smoke"
    out = args.out or RESULTS / default
    out.parent.mkdir(parents=True, exist_ok=True)
    _, cfg = load_config(CONFIG, ["model.goal_head.text_encoder=hashed"])
    report = {
        "config": CONFIG,
        "device": str(device),
        "command": "python benchmarks/bench_gpu_recipe.py " + " ".join(sys.argv[1:]),
        "machine": machine(device),
        "store": {
            "episodes": args.episodes,
            "length": args.length,
            "image_size": cfg.model.image_size,
        },
        "claim_gib": CLAIM_GIB,
        "results": [],
    }
    with tempfile.TemporaryDirectory() as tmp:
        store = Path(tmp) / "syn.zarr"
        t0 = time.perf_counter()
        write_synthetic_store(store, args.episodes, args.length, cfg.model.image_size, cfg.seed)
        report["store"]["write_s"] = time.perf_counter() - t0
        for amp in args.amp:
            print(f"amp={amp}: {args.warmup} + {args.steps} optimizer steps", flush=True)  # noqa: T201
            try:
                result = one_mode(amp, args, store, Path(tmp) / "runs", device)
            except Exception as err:  # noqa: BLE001 (one mode failing keeps the others)
                traceback.print_exc()
                result = {"amp": amp, "status": "failed", "error": f"{type(err).__name__}: {err}"}
            report["results"].append(result)
            # Written after each mode: a run stopped later keeps what was measured.
            out.with_suffix(".json").write_text(json.dumps(report, indent=1) + "\n")
            out.with_suffix(".md").write_text(markdown(report))
    text = markdown(report)
    print(text)  # noqa: T201 (a script's report)
    if any(r["status"] != "ok" for r in report["results"]):
        sys.exit(1)


if __name__ == "__main__":
    main()
