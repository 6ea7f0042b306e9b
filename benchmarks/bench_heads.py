"""Batch-1 CPU latency of the action heads, the dual system and LoRA merging.

    python benchmarks/bench_heads.py                 # full run (~1-2 min)
    python benchmarks/bench_heads.py --quick         # smoke run, results not written
    python benchmarks/bench_heads.py --no-compile    # skip the torch.compile'd rows

Measures p50/p95 per decision for DDPM-100, DDIM-10, flow-10, flow-5 and the L1
head (H=16, ~2 M parameter U-Net head), flow-10 through the U-Net's reference
``denoise_step`` instead of its batch-1 step plan (the default eager path), the
dual system's S1 step and S2 step,
and a transformer-denoiser flow-10 head as base / LoRA unmerged / LoRA merged.
Every figure is the median over ``--repeats`` rounds of ``--iters`` timed calls;
variants compared against each other (DDPM vs DDIM, base vs LoRA) are timed
interleaved call by call so that machine load hits them alike. One intra-op thread by
default (``--threads``). Writes ``results/bench_heads.{json,md}``.
"""

from __future__ import annotations

import argparse
import copy
import json
import logging
import os
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import torch

from vla_gr.core.diffusion_policy import DiffusionPolicy
from vla_gr.core.dual_system import DualSystemArchitecture
from vla_gr.core.peft_modules import apply_lora_to_model, merge_peft, trainable_parameters
from vla_gr.machine import describe_machine, machine_line

logger = logging.getLogger("bench_heads")

ROOT = Path(__file__).resolve().parent
DEFAULT_OUT = ROOT / "results" / "bench_heads"
ACTION_DIM, HORIZON, CONTEXT_DIM = 7, 16, 256
TARGET_PARAMS = 2_000_000


def n_params(module: torch.nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())


def time_calls(fn: Callable[[], object], iters: int) -> list[float]:
    """Wall times (ms) of ``iters`` calls of ``fn``."""
    out = []
    for _ in range(iters):
        t0 = time.perf_counter()
        fn()
        out.append(1e3 * (time.perf_counter() - t0))
    return out


def percentile(values: list[float], q: float) -> float:
    """Linear-interpolated percentile ``q`` in [0, 100] of ``values``."""
    s = sorted(values)
    pos = (len(s) - 1) * q / 100.0
    lo, hi = int(pos), min(int(pos) + 1, len(s) - 1)
    return s[lo] + (s[hi] - s[lo]) * (pos - lo)


def bench_group(
    fns: dict[str, Callable[[], object]], iters: int, repeats: int, warmup: int
) -> dict[str, dict]:
    """Time ``fns`` interleaved call by call (rotating order) in ``repeats`` rounds.

    Interleaving single calls makes load changes on a shared machine hit every
    variant alike. Per name: the median over rounds of the round p50 and p95 (ms).
    """
    for fn in fns.values():
        for _ in range(warmup):
            fn()
    names = list(fns)
    rounds: dict[str, list[list[float]]] = {k: [] for k in names}
    for _ in range(repeats):
        times: dict[str, list[float]] = {k: [] for k in names}
        for i in range(iters):
            for name in names[i % len(names) :] + names[: i % len(names)]:
                times[name] += time_calls(fns[name], 1)
        for name in names:
            rounds[name].append(times[name])
    out = {}
    for name, rs in rounds.items():
        out[name] = {
            "p50_ms": statistics.median(percentile(x, 50) for x in rs),
            "p95_ms": statistics.median(percentile(x, 95) for x in rs),
            "round_p50_ms": [percentile(x, 50) for x in rs],
        }
    return out


def ratio_of_medians(a: dict, b: dict) -> float:
    """Median over rounds of round-p50(a) / round-p50(b)."""
    return statistics.median(x / y for x, y in zip(a["round_p50_ms"], b["round_p50_ms"]))


def make_head(objective: str, hidden_dim: int, denoiser: str = "unet1d") -> DiffusionPolicy:
    torch.manual_seed(0)
    return DiffusionPolicy(
        action_dim=ACTION_DIM,
        hidden_dim=hidden_dim,
        context_dim=CONTEXT_DIM,
        num_diffusion_steps=100,
        prediction_type="epsilon",
        objective=objective,
        horizon=HORIZON,
        denoiser=denoiser,
        num_layers=4,  # the transformer denoiser the result tables were measured with
    ).eval()


def pick_hidden_dim(denoiser: str) -> int:
    """Width whose flow head is closest to ~2 M parameters."""
    sizes = {h: n_params(make_head("flow_matching", h, denoiser)) for h in (64, 96, 128, 192, 256)}
    return min(sizes, key=lambda h: abs(sizes[h] - TARGET_PARAMS))


def machine() -> dict:
    """The machine (:func:`vla_gr.machine.describe_machine`) and this run's thread count."""
    info = describe_machine()
    return info | {"threads": torch.get_num_threads(), "loadavg_start": info["load_average"]}


@torch.inference_mode()
def run(iters: int, repeats: int, warmup: int, compile_heads: bool = True) -> dict:
    ctx = torch.randn(1, CONTEXT_DIM)  # (1, C)
    results: dict = {"machine": machine(), "iters": iters, "repeats": repeats}

    # ------------------------------------------------------------ action heads (U-Net)
    hidden = pick_hidden_dim("unet1d")
    diff, flow, l1 = (make_head(o, hidden) for o in ("diffusion", "flow_matching", "l1"))
    flow_ref = make_head("flow_matching", hidden)
    flow_ref.denoiser.sampling_step = lambda x: flow_ref.denoiser.denoise_step  # no step plan
    heads = {
        "DDPM-100": lambda: diff.get_action(ctx, num_inference_steps=100, sampler="ddpm"),
        "DDIM-10": lambda: diff.get_action(ctx, num_inference_steps=10, sampler="ddim"),
        "flow-10": lambda: flow.get_action(ctx, num_inference_steps=10, sampler="euler"),
        "flow-5": lambda: flow.get_action(ctx, num_inference_steps=5, sampler="euler"),
        "L1": lambda: l1.get_action(ctx),
    }
    noise = torch.randn(1, HORIZON, ACTION_DIM)
    fast_out = flow.get_action(ctx, num_inference_steps=10, noise=noise)  # (1, H, A)
    ref_out = flow_ref.get_action(ctx, num_inference_steps=10, noise=noise)  # (1, H, A)
    plan_vs_ref = float((fast_out - ref_out).abs().max())
    slow = {"DDPM-100": heads.pop("DDPM-100"), "DDIM-10": heads["DDIM-10"]}
    side = bench_group(slow, max(3, iters // 5), repeats, warmup=1)
    timings = bench_group(heads, iters, repeats, warmup)
    timings["DDPM-100"] = side["DDPM-100"]
    timings["DDIM-10 (side by side with DDPM)"] = side["DDIM-10"]
    ref_group = {  # own group: the extra head's weights would crowd the caches of the others
        "flow-10 reference step": lambda: flow_ref.get_action(ctx, num_inference_steps=10),
        "flow-10 (side by side with reference)": heads["flow-10"],
    }
    ref_t = bench_group(ref_group, iters // 2, repeats, warmup)
    timings.update(ref_t)
    if compile_heads:
        flow_c = make_head("flow_matching", hidden).compile_sampler()
        t0 = time.perf_counter()
        flow_c.get_action(ctx, num_inference_steps=10, sampler="euler")  # compiles
        logger.info("torch.compile of the sampling step: %.1f s", time.perf_counter() - t0)
        compiled = {
            "flow-10 compiled": lambda: flow_c.get_action(ctx, num_inference_steps=10),
            "flow-5 compiled": lambda: flow_c.get_action(ctx, num_inference_steps=5),
        }
        timings.update(bench_group(compiled, iters, repeats, warmup))
    results["heads"] = {
        "hidden_dim": hidden,
        "params": {"diffusion": n_params(diff), "flow": n_params(flow), "l1": n_params(l1)},
        "timings": timings,
        "ddpm100_over_ddim10": ratio_of_medians(side["DDPM-100"], side["DDIM-10"]),
        "reference_over_plan": ratio_of_medians(
            ref_t["flow-10 reference step"], ref_t["flow-10 (side by side with reference)"]
        ),
        "plan_vs_reference_max_abs_diff": plan_vs_ref,
    }

    # ------------------------------------------------------------ dual system
    torch.manual_seed(0)
    dual = DualSystemArchitecture().eval()  # default sizes
    vis, prop = torch.randn(1, dual.visual_dim), torch.randn(1, dual.proprio_dim)
    vlm = torch.randn(1, 32, dual.vlm_dim)  # (1, T=32, vlm_dim)
    plan = dual.plan(vlm)
    goal, conf = plan["latent_goal"], plan["confidence"]
    dual_fns = {
        "S1 step": lambda: dual.act(vis, prop, goal, conf),
        "S2 step (32 tokens)": lambda: dual.plan(vlm),
        "S1 step + flow-10 chunk": lambda: (
            dual.act(vis, prop, goal, conf),
            flow.get_action(ctx, num_inference_steps=10, sampler="euler"),
        ),
    }
    results["dual_system"] = {
        "params": dual.num_parameters(),
        "plan_every": dual.plan_every,
        "timings": bench_group(dual_fns, iters, repeats, warmup),
    }

    # ------------------------------------------------------------ LoRA: base vs unmerged vs merged
    t_hidden = pick_hidden_dim("transformer")
    base = make_head("flow_matching", t_hidden, denoiser="transformer")
    targets = ["q_proj", "k_proj", "v_proj", "out_proj"]
    lora = apply_lora_to_model(copy.deepcopy(base), targets, rank=8, alpha=16)
    count = trainable_parameters(lora)
    with torch.no_grad():  # give B non-zero weights so that merging changes W
        for name, p in lora.named_parameters():
            if "lora_B" in name:
                p.normal_(0.0, 0.01)
    merged = merge_peft(copy.deepcopy(lora))
    torch.manual_seed(1)
    out_unmerged = lora.get_action(ctx, num_inference_steps=10, sampler="euler")  # (1, H, A)
    torch.manual_seed(1)
    out_merged = merged.get_action(ctx, num_inference_steps=10, sampler="euler")  # (1, H, A)
    lora_fns = {
        "base": lambda: base.get_action(ctx, num_inference_steps=10, sampler="euler"),
        "LoRA unmerged": lambda: lora.get_action(ctx, num_inference_steps=10, sampler="euler"),
        "LoRA merged": lambda: merged.get_action(ctx, num_inference_steps=10, sampler="euler"),
    }
    lt = bench_group(lora_fns, iters, 2 * repeats, warmup)
    results["lora"] = {
        "model": f"flow-10 transformer head, hidden_dim={t_hidden}, LoRA r=8 on {targets}",
        "params_total": count.total,
        "params_trainable": count.trainable,
        "timings": lt,
        "merged_over_base": ratio_of_medians(lt["LoRA merged"], lt["base"]),
        "unmerged_over_base": ratio_of_medians(lt["LoRA unmerged"], lt["base"]),
        "merged_vs_unmerged_max_abs_diff": float((out_merged - out_unmerged).abs().max()),
    }
    results["machine"]["loadavg_end"] = os.getloadavg()

    h, d, lo = results["heads"], results["dual_system"], results["lora"]
    results["goals"] = {
        "flow-10 p95 <= 10 ms (eager)": h["timings"]["flow-10"]["p95_ms"] <= 10.0,
        **(
            {
                "flow-10 p95 <= 10 ms (torch.compile)": h["timings"]["flow-10 compiled"]["p95_ms"]
                <= 10
            }
            if "flow-10 compiled" in h["timings"]
            else {}
        ),
        "DDIM-10 >= 8x faster than DDPM-100": h["ddpm100_over_ddim10"] >= 8.0,
        "merged LoRA within 2% of base": abs(lo["merged_over_base"] - 1.0) <= 0.02,
        "S1 <= 2 M parameters": d["params"]["s1"] <= 2_000_000,
    }
    return results


def to_markdown(res: dict) -> str:
    m, h, d, lo = res["machine"], res["heads"], res["dual_system"], res["lora"]
    lines = [
        "# bench_heads: batch-1 CPU latency",
        "",
        f"{machine_line(m)} {m['threads']} intra-op thread(s); "
        f"load average at start {m['loadavg_start'][0]:.2f}, at end {m['loadavg_end'][0]:.2f}. "
        f"Median over {res['repeats']} rounds of {res['iters']} calls "
        "(DDPM/DDIM: fewer calls); compared variants interleaved call by call.",
        "",
        "| what | params | p50 ms | p95 ms |",
        "|---|---:|---:|---:|",
    ]
    kinds = {"DDPM": "diffusion", "DDIM": "diffusion", "flow": "flow", "L1": "l1"}
    for name, t in h["timings"].items():
        params = h["params"][next(v for k, v in kinds.items() if name.startswith(k))]
        lines.append(
            f"| {name} (H={HORIZON}) | {params:,} | {t['p50_ms']:.2f} | {t['p95_ms']:.2f} |"
        )
    for name, t in d["timings"].items():
        params = f"{d['params']['s1'] if name.startswith('S1') else d['params']['s2']:,}"
        if "flow" in name:
            params += f" + {h['params']['flow']:,}"
        lines.append(f"| {name} | {params} | {t['p50_ms']:.2f} | {t['p95_ms']:.2f} |")
    base_params = lo["params_total"] - lo["params_trainable"]
    for name, t in lo["timings"].items():
        params = f"{base_params:,}"
        if name == "LoRA unmerged":
            params += f" + {lo['params_trainable']:,} LoRA"
        lines.append(f"| LoRA test: {name} | {params} | {t['p50_ms']:.2f} | {t['p95_ms']:.2f} |")
    lines += [
        "",
        f"DDPM-100 / DDIM-10 (side by side): {h['ddpm100_over_ddim10']:.1f}x; "
        f"flow-10 reference step / step plan: {h['reference_over_plan']:.2f}x "
        f"(max |diff| {h['plan_vs_reference_max_abs_diff']:.1e}); "
        f"LoRA merged / base: {lo['merged_over_base']:.3f}; "
        f"unmerged / base: {lo['unmerged_over_base']:.3f}. "
        f"S2 runs every {d['plan_every']} S1 steps (2 Hz / 20 Hz). "
        f"LoRA test model: {lo['model']}; merged vs unmerged max |diff| "
        f"{lo['merged_vs_unmerged_max_abs_diff']:.1e}.",
        "",
        "| goal | met |",
        "|---|---|",
        *[f"| {k} | {'yes' if v else 'no'} |" for k, v in res["goals"].items()],
        "",
        "Reproduce: `python benchmarks/bench_heads.py`",
        "",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--iters", type=int, default=40, help="timed calls per round")
    parser.add_argument("--repeats", type=int, default=5, help="rounds (median over rounds)")
    parser.add_argument("--warmup", type=int, default=5)
    parser.add_argument("--threads", type=int, default=1, help="torch intra-op threads")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="output path stem")
    parser.add_argument("--quick", action="store_true", help="tiny run, nothing written")
    parser.add_argument(
        "--no-compile", action="store_true", help="skip the torch.compile'd flow rows"
    )
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    torch.set_num_threads(args.threads)
    if args.quick:
        args.iters, args.repeats, args.warmup = 4, 2, 1
    res = run(args.iters, args.repeats, args.warmup, compile_heads=not args.no_compile)
    md = to_markdown(res)
    print(md)
    if not args.quick:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.with_suffix(".json").write_text(json.dumps(res, indent=2) + "\n")
        args.out.with_suffix(".md").write_text(md)
        logger.info("wrote %s.{json,md}", args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
