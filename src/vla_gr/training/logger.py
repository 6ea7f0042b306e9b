"""Run observability on rank 0: metrics.jsonl, TensorBoard (scalars and rollout videos),
optional wandb, a progress bar.

Fed by the loop in ``vla_gr.train``; ``read_metrics`` reads ``metrics.jsonl`` back.
"""

from __future__ import annotations

import json
import logging
import math
import os
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)


class MetricsLogger:
    """Append scalars to ``<run>/metrics.jsonl`` and mirror them to TensorBoard / wandb.

    Disabled (every call a no-op) on ranks other than 0. A run resumed at ``resume_step``
    first drops what was logged after that step (the resumed run logs those steps again).
    """

    def __init__(
        self,
        run_dir: str | Path,
        enabled: bool = True,
        tensorboard: bool = True,
        wandb_cfg=None,
        config: Mapping | None = None,
        run_name: str | None = None,
        resume_step: int | None = None,
    ) -> None:
        self.enabled = enabled
        self.run_dir = Path(run_dir)
        self._tb = None
        self._wandb = None
        if not enabled:
            return
        self.run_dir.mkdir(parents=True, exist_ok=True)
        if resume_step is not None:
            drop_rows_after(self.run_dir / "metrics.jsonl", resume_step)
        self._jsonl = open(self.run_dir / "metrics.jsonl", "a", buffering=1)  # noqa: SIM115
        if tensorboard:
            from torch.utils.tensorboard import SummaryWriter

            purge = resume_step + 1 if resume_step is not None else None
            self._tb = SummaryWriter(str(self.run_dir / "tensorboard"), purge_step=purge)
        if wandb_cfg is not None and wandb_cfg.enabled:
            try:
                import wandb
            except ImportError as err:
                raise ImportError(
                    "logging.wandb.enabled=true but wandb is not installed: "
                    "pip install 'vla-gr[wandb]'"
                ) from err
            self._wandb = wandb.init(
                project=wandb_cfg.project,
                entity=wandb_cfg.entity,
                mode=wandb_cfg.mode,
                name=run_name,
                dir=str(self.run_dir),
                config=dict(config or {}),
                resume="allow",
            )

    def log(self, step: int, metrics: Mapping[str, float]) -> None:
        """Record ``metrics`` (name -> number) at optimiser step ``step``."""
        if not self.enabled:
            return
        clean = {k: float(v) for k, v in metrics.items()}
        row = {"step": int(step), "time": time.time(), **clean}
        self._jsonl.write(json.dumps({k: _json_num(v) for k, v in row.items()}) + "\n")
        if self._tb is not None:
            for k, v in clean.items():
                self._tb.add_scalar(k, v, step)
        if self._wandb is not None:
            self._wandb.log(clean, step=step)

    def log_videos(
        self, step: int, clips: Mapping[str, tuple[Sequence[np.ndarray], float]]
    ) -> None:
        """Write each ``tag: (frames (each (H, W, 3) uint8), fps)`` of ``clips`` to TensorBoard
        at ``step``, as an animated GIF image summary (its Images tab plays it; torch's
        ``add_video`` would need moviepy). No-op without TensorBoard."""
        if not self.enabled or self._tb is None or not clips:
            return
        from tensorboard.compat.proto.summary_pb2 import Summary

        from vla_gr.envs.visualize import gif_bytes

        values = []
        for tag, (frames, fps) in clips.items():
            h, w, c = np.shape(frames[0])
            image = Summary.Image(
                height=h, width=w, colorspace=c, encoded_image_string=gif_bytes(frames, fps)
            )
            values.append(Summary.Value(tag=tag, image=image))
        # the writer SummaryWriter.add_video uses, handed a summary made here
        self._tb._get_file_writer().add_summary(Summary(value=values), step)

    def close(self) -> None:
        if not self.enabled:
            return
        self._jsonl.close()
        if self._tb is not None:
            self._tb.close()
        if self._wandb is not None:
            self._wandb.finish()


def _json_num(v):
    return None if isinstance(v, float) and not math.isfinite(v) else v


def drop_rows_after(path: Path, step: int) -> int:
    """Rewrite a ``metrics.jsonl`` without its rows past ``step`` (or torn by a kill);
    returns how many were dropped."""
    if not path.is_file():
        return 0
    lines = [x for x in path.read_text().splitlines() if x.strip()]
    kept = [x for x in lines if (s := _row_step(x)) is not None and s <= step]
    if len(kept) < len(lines):
        tmp = path.with_name(f".{path.name}.tmp")
        tmp.write_text("".join(x + "\n" for x in kept))
        os.replace(tmp, path)
        log.info("%s: dropped %d rows logged after step %d", path, len(lines) - len(kept), step)
    return len(lines) - len(kept)


def _row_step(line: str) -> int | None:
    try:
        return int(json.loads(line)["step"])
    except (ValueError, KeyError, TypeError):
        return None


def read_metrics(path: str | Path) -> list[dict]:
    """Rows of a ``metrics.jsonl`` file."""
    return [json.loads(line) for line in Path(path).read_text().splitlines() if line.strip()]


class Progress:
    """A tqdm bar over optimiser steps with loss, lr, samples/s and tqdm's ETA."""

    def __init__(self, total: int, initial: int = 0, enabled: bool = True) -> None:
        from tqdm import tqdm

        self.bar = tqdm(
            total=total,
            initial=initial,
            desc="train",
            unit="step",
            disable=not enabled,
            dynamic_ncols=True,
        )

    def update(self, loss: float, lr: float, samples_per_s: float) -> None:
        self.bar.set_postfix(loss=f"{loss:.4f}", lr=f"{lr:.2e}", sps=f"{samples_per_s:.1f}")
        self.bar.update(1)

    def close(self) -> None:
        self.bar.close()
