"""Environment observations as the agent's networks read them: instruction lists and frames."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import torch

__all__ = ["as_instructions", "env_obs_to_frame"]


def as_instructions(value, name: str = "instruction") -> list[str]:
    """``value`` (one string, or a sequence / array of strings) as a list of strings.

    Raises ``TypeError`` naming ``name`` for anything else (None, bytes, non-string items),
    which would otherwise be turned into text such as ``"None"`` or fail deep inside.
    """
    if isinstance(value, str):
        return [value]
    if (
        value is None
        or isinstance(value, (bytes, bytearray, Mapping))
        or not isinstance(value, (Sequence, np.ndarray))
    ):
        raise TypeError(f"{name} must be a string or a list of strings, got {type(value).__name__}")
    bad = [s for s in value if not isinstance(s, str)]
    if bad:
        raise TypeError(
            f"{name} must be a string or a list of strings; it holds a "
            f"{type(bad[0]).__name__}: {bad[0]!r}"
        )
    return [str(s) for s in value]


def env_obs_to_frame(obs: Mapping, device: torch.device | str = "cpu") -> dict:
    """Environment observation (single or batched) -> one policy frame.

    Returns ``rgb`` (B, 3, H, W) float in [0, 1], ``depth`` (B, 1, H, W), ``pose`` (B, 3),
    ``instruction`` list of B strings.
    """
    rgb = torch.as_tensor(np.asarray(obs["rgb"]))
    batched = rgb.dim() == 4
    if not batched:
        if rgb.dim() != 3:
            raise ValueError(
                f"obs['rgb'] must be (H, W, 3) or (B, H, W, 3); got {tuple(rgb.shape)}"
            )
        rgb = rgb[None]  # (1, H, W, 3)
    depth = torch.as_tensor(np.asarray(obs["depth"]), dtype=torch.float32)
    pose = torch.as_tensor(np.asarray(obs["pose"]), dtype=torch.float32)
    if not batched:
        depth, pose = depth[None], pose[None]  # (1, H, W, 1), (1, 3)
    instructions = as_instructions(obs["instruction"], "obs['instruction']")
    if len(instructions) != rgb.shape[0]:
        raise ValueError(f"{rgb.shape[0]} observations but {len(instructions)} instructions")
    rgb = (
        rgb.permute(0, 3, 1, 2).float() / 255.0
        if rgb.dtype == torch.uint8
        else rgb.permute(0, 3, 1, 2).float()
    )
    return {
        "rgb": rgb.to(device),  # (B, 3, H, W)
        "depth": depth.permute(0, 3, 1, 2).to(device),  # (B, 1, H, W)
        "pose": pose.to(device),  # (B, 3)
        "instruction": instructions,
    }
