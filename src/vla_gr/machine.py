"""What machine a timing was taken on, and how fast it is: the context every benchmark records.

Latency and throughput figures move with the CPU (the same agent's S2 tick p95 differed by 2x
between two 2-core machines of this project). :func:`describe_machine` records the CPU model,
core count, torch version and load average, and a one-thread reference speed: the median
GFLOP/s of a fixed float32 matrix product and of a fixed 3x3 convolution. Timings from two
machines compare through those references; timings from one machine compare directly.
"""

from __future__ import annotations

import os
import platform
import time
from pathlib import Path

import torch

__all__ = ["cpu_model", "describe_machine", "machine_line", "reference_gflops"]


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``), else what ``platform`` knows."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _median_seconds(fn, repeats: int) -> float:
    fn()  # warm-up: allocation, kernel selection
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return sorted(times)[len(times) // 2]


def reference_gflops(repeats: int = 7) -> dict[str, float]:
    """One-thread float32 GFLOP/s of a 384 x 384 matrix product and of a 3x3 convolution
    (batch 2, 32 -> 32 channels, 64 x 64: a goal-head layer); medians of ``repeats`` runs."""
    if repeats < 1:
        raise ValueError(f"repeats={repeats} must be >= 1")
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        g = torch.Generator().manual_seed(0)
        a, b = torch.randn(384, 384, generator=g), torch.randn(384, 384, generator=g)
        x = torch.randn(2, 32, 64, 64, generator=g)  # (B, C, H, W)
        w = torch.randn(32, 32, 3, 3, generator=g)  # (C_out, C_in, 3, 3)
        with torch.inference_mode():
            t_mm = _median_seconds(lambda: a @ b, repeats)
            t_conv = _median_seconds(lambda: torch.nn.functional.conv2d(x, w, padding=1), repeats)
    finally:
        torch.set_num_threads(threads)
    mm_flops = 2.0 * 384**3
    conv_flops = 2.0 * 2 * 32 * 32 * 9 * 64 * 64
    return {
        "matmul_gflops": round(mm_flops / t_mm / 1e9, 2),
        "conv_gflops": round(conv_flops / t_conv / 1e9, 2),
    }


def describe_machine(calibrate: bool = True) -> dict:
    """CPU model, cores, torch, load average and (with ``calibrate``) the reference speed."""
    info = {
        "cpu": cpu_model(),
        "cores": os.cpu_count(),
        "torch": torch.__version__,
        "python": platform.python_version(),
        "load_average": [round(x, 2) for x in os.getloadavg()],
    }
    if calibrate:
        info["reference"] = reference_gflops()
    return info


def machine_line(info: dict) -> str:
    """One Markdown line for a results table: ``Machine: <cpu>, <n> cores, ...``."""
    parts = [f"Machine: {info['cpu']}, {info['cores']} cores, torch {info['torch']}"]
    ref = info.get("reference")
    if ref:
        parts.append(
            f"one-thread reference {ref['matmul_gflops']} GFLOP/s (matmul), "
            f"{ref['conv_gflops']} GFLOP/s (3x3 conv)"
        )
    parts.append(f"load average {' / '.join(str(x) for x in info['load_average'])}")
    return "; ".join(parts) + "."
