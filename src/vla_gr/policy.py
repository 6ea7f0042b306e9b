"""``VLAGRPolicy``: the navigation agent (observation encoders -> context tokens -> action head).

LeRobot-shaped interface (see DESIGN.md "Policy interface"):

- ``forward(batch) -> {"loss", ...}`` for training on dataset windows;
- ``predict_action_chunk(obs) -> (B, horizon, 3)`` without gradients;
- ``select_action(obs) -> (B, 3)`` from a queue of the chunk, replanning every
  ``n_action_steps``; ``reset()`` clears the queues.

Observations in a *batch* (dataset layout, ``T = n_obs_steps``): ``rgb`` (B, T, 3, H, W)
float in [0, 1] or uint8, ``depth`` (B, T, 1, H, W) metres, ``pose`` (B, T, 3) raw
(x, y, yaw), ``instruction`` list of B strings; training adds ``action`` (B, horizon, 3)
raw. Actions and positions are normalised inside the policy with the dataset's min/max
statistics, kept as buffers so that they travel with the weights.

Context tokens (width D): one instruction token, T pose tokens and T*K image tokens, each
with a type and an observation-step embedding, mixed by ``fusion_layers`` transformer
blocks, then decoded by the action head (``model.head``). The GR field and the dual system
(``model.gr_field``, ``model.dual_system``) are not composed into the agent yet.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping, Sequence

import numpy as np
import torch
from torch import nn
from torch.utils.checkpoint import checkpoint

from vla_gr.checkpoint import load_model_state, read_checkpoint
from vla_gr.configs.model_schema import ModelConfig
from vla_gr.core.diffusion_policy import DiffusionPolicy
from vla_gr.core.encoders import PoseEncoder, RGBDEncoder, build_text_encoder, pose_features
from vla_gr.core.trajectory_attention import TransformerBlock

__all__ = ["VLAGRPolicy", "apply_peft", "make_fake_batch", "env_obs_to_frame"]

_OBS_KEYS = ("rgb", "depth", "pose")


class VLAGRPolicy(nn.Module):
    """The agent; ``config`` is a validated :class:`ModelConfig`."""

    name = "vla_gr"

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        self.config = c = config
        e = c.encoders
        self.vision = RGBDEncoder(
            channels=e.vision_channels,
            dim=e.dim,
            pool=e.vision_pool,
            num_tokens=e.vision_tokens,
            max_depth=e.max_depth,
            gradient_checkpointing=e.gradient_checkpointing,
        )
        self.text = build_text_encoder(e.text_encoder, e.dim, e.text_buckets)
        self.pose = PoseEncoder(e.dim, e.pose_hidden)
        self.step_embed = nn.Parameter(torch.randn(c.n_obs_steps, e.dim) * 0.02)  # (T, D)
        self.type_embed = nn.Parameter(torch.randn(3, e.dim) * 0.02)  # text, pose, image
        self.fusion = nn.ModuleList(
            TransformerBlock(e.dim, e.fusion_heads, dropout=e.dropout, use_rope=False)
            for _ in range(e.fusion_layers)
        )
        self.fusion_norm = nn.LayerNorm(e.dim)
        self.head = DiffusionPolicy(config=c.head)
        # Min-max normalisers (identity until set_normalization); saved with the weights.
        self.register_buffer("action_scale", torch.ones(c.action_dim))
        self.register_buffer("action_offset", torch.zeros(c.action_dim))
        self.register_buffer("pose_scale", torch.ones(3))
        self.register_buffer("pose_offset", torch.zeros(3))
        for name in c.freeze:
            getattr(self, name).requires_grad_(False)
        self.reset()

    @classmethod
    def from_pretrained(cls, path, device: torch.device | str = "cpu") -> VLAGRPolicy:
        """Load a training checkpoint folder (``<run>/checkpoints/best``), verified.

        The model config comes from the checkpoint's ``config.yaml`` (PEFT layers are
        re-applied before the weights are loaded); the weights are ``model.safetensors``
        (the EMA averages when training used EMA). Returned in eval mode.
        """
        from omegaconf import OmegaConf

        loaded = read_checkpoint(path)
        saved = OmegaConf.create(loaded.config_yaml)
        if "model" not in saved:
            raise ValueError(f"checkpoint {path}: config.yaml has no model section")
        schema = OmegaConf.structured(ModelConfig)
        config = OmegaConf.to_object(OmegaConf.merge(schema, saved.model))
        policy = cls(config)
        apply_peft(policy, config.peft)
        load_model_state(policy, loaded.model, str(path))
        return policy.to(device).eval()

    # ------------------------------------------------------------------ normalisation
    def set_normalization(self, normalizers: Mapping) -> None:
        """Copy ``action`` and ``pose`` min-max normalisers (``scale``/``offset`` (D,))."""
        for key in ("action", "pose"):
            if key not in normalizers:
                raise ValueError(f"normalizers need an entry {key!r}; got {sorted(normalizers)}")
            norm = normalizers[key]
            scale = torch.as_tensor(np.asarray(norm.scale), dtype=torch.float32)
            offset = torch.as_tensor(np.asarray(norm.offset), dtype=torch.float32)
            buf = getattr(self, f"{key}_scale")
            if scale.shape != buf.shape:
                raise ValueError(
                    f"{key} normaliser has shape {tuple(scale.shape)}, expected {tuple(buf.shape)}"
                )
            buf.copy_(scale)
            getattr(self, f"{key}_offset").copy_(offset)

    def normalize_action(self, action: torch.Tensor) -> torch.Tensor:
        """Raw ``(..., A)`` -> ``[-1, 1]`` range ``(..., A)``."""
        return action * self.action_scale + self.action_offset

    def unnormalize_action(self, action: torch.Tensor) -> torch.Tensor:
        """Normalised ``(..., A)`` -> raw ``(..., A)``."""
        return (action - self.action_offset) / self.action_scale

    # ------------------------------------------------------------------ encoding
    def encode_observations(self, batch: Mapping) -> torch.Tensor:
        """Context tokens ``(B, 1 + T + T*K, D)`` from a batch of observation histories."""
        rgb, depth, pose = batch["rgb"], batch["depth"], batch["pose"]  # (B,T,3,H,W) ...
        instructions = as_instructions(batch["instruction"], "batch['instruction']")
        if rgb.dim() != 5:
            raise ValueError(f"batch['rgb'] must be (B, T, 3, H, W); got {tuple(rgb.shape)}")
        B, T = rgb.shape[:2]
        if self.config.n_obs_steps != T:
            raise ValueError(
                f"batch has {T} observation steps, model.n_obs_steps={self.config.n_obs_steps}"
            )
        if len(instructions) != B:
            raise ValueError(f"batch has {B} observations but {len(instructions)} instructions")
        img = self.vision(rgb.flatten(0, 1), depth.flatten(0, 1))  # (B*T, K, D)
        img = img.unflatten(0, (B, T)) + self.step_embed[None, :, None]  # (B, T, K, D)
        img = img.flatten(1, 2) + self.type_embed[2]  # (B, T*K, D)
        feats = pose_features(pose.float(), self.pose_scale, self.pose_offset)  # (B, T, 4)
        pos = self.pose(feats) + self.step_embed + self.type_embed[1]  # (B, T, D)
        txt = self.text(instructions).unsqueeze(1) + self.type_embed[0]  # (B, 1, D)
        tokens = torch.cat([txt.to(img.dtype), pos.to(img.dtype), img], dim=1)  # (B, S, D)
        for block in self.fusion:
            if (
                self.config.encoders.gradient_checkpointing
                and self.training
                and torch.is_grad_enabled()
            ):
                tokens = checkpoint(block, tokens, use_reentrant=False)
            else:
                tokens = block(tokens)  # (B, S, D)
        return self.fusion_norm(tokens)  # (B, S, D)

    # ------------------------------------------------------------------ training
    def forward(self, batch: Mapping) -> dict[str, torch.Tensor]:
        """Training loss on a batch with ``action`` (B, horizon, A) raw.

        Returns ``{"loss": scalar, ...}`` (further scalars from the head, for logging).
        """
        action = batch["action"]  # (B, H, A)
        if action.shape[1:] != (self.config.horizon, self.config.action_dim):
            raise ValueError(
                f"batch['action'] must be (B, {self.config.horizon}, {self.config.action_dim}); "
                f"got {tuple(action.shape)}"
            )
        context = self.encode_observations(batch)  # (B, S, D)
        out = self.head(self.normalize_action(action.float()), context)
        result = {"loss": out["loss"]}
        for key, value in out.items():
            if key != "loss" and isinstance(value, torch.Tensor) and value.numel() == 1:
                result[key] = value.detach()
        return result

    # ------------------------------------------------------------------ inference
    @torch.no_grad()
    def predict_action_chunk(self, obs: Mapping) -> torch.Tensor:
        """Raw actions ``(B, horizon, A)`` in ``[-1, 1]`` for a batch of observation histories."""
        context = self.encode_observations(obs)  # (B, S, D)
        chunk = self.head.get_action(context)  # (B, H, A), sampler and steps from model.head
        return self.unnormalize_action(chunk).clamp(-1.0, 1.0)  # (B, H, A)

    def reset(self) -> None:
        """Forget the observation history and the queued actions (call at episode start)."""
        self._obs_queue: deque[dict] = deque(maxlen=self.config.n_obs_steps)
        self._action_queue: deque[torch.Tensor] = deque(maxlen=self.config.n_action_steps)

    @torch.no_grad()
    def select_action(self, obs: Mapping) -> torch.Tensor:
        """One action ``(B, A)`` for the current environment observation.

        ``obs`` is an environment observation, single (``rgb`` (H, W, 3)) or batched
        (``rgb`` (B, H, W, 3), ``depth`` (B, H, W, 1), ``pose`` (B, 3), ``instruction``
        list), numpy or torch. The last ``n_obs_steps`` observations are kept (the first
        one repeated after ``reset``), and a chunk is predicted only when the action
        queue is empty. Timeline for ``n_obs_steps=2, horizon=16, n_action_steps=8``::

            env step t      :  0   1   2  ...  7 |  8   9  ... 15 | 16 ...
            observations    : o0 o0,o1 ...       | o7,o8          | o15,o16
            chunk predicted :  *                 |  *             |  *
            action executed : c0[0] c0[1] .. c0[7] | c8[0] .. c8[7] | c16[0] ..

        i.e. a new chunk ``c_t`` (``horizon`` actions from step ``t``) is computed at
        ``t = 0, n_action_steps, 2 * n_action_steps, ...``; only its first
        ``n_action_steps`` actions are executed, the rest is discarded.
        """
        frame = env_obs_to_frame(obs, device=self.action_scale.device)
        if not self._obs_queue:
            self._obs_queue.extend([frame] * self.config.n_obs_steps)
        else:
            self._obs_queue.append(frame)
        if not self._action_queue:
            history = {
                k: torch.stack([f[k] for f in self._obs_queue], dim=1) for k in _OBS_KEYS
            }  # each (B, T, ...)
            history["instruction"] = frame["instruction"]
            chunk = self.predict_action_chunk(history)  # (B, H, A)
            self._action_queue.extend(chunk[:, : self.config.n_action_steps].unbind(1))
        return self._action_queue.popleft()  # (B, A)


def apply_peft(model: nn.Module, peft) -> nn.Module:
    """Apply ``model.peft`` (a :class:`PeftConfig`) in place when enabled; returns ``model``."""
    if not peft.enabled:
        return model
    from vla_gr.core import peft_modules

    targets = list(peft.target_modules)
    if peft.method == "lora":
        peft_modules.apply_lora_to_model(
            model, targets, peft.lora_rank, peft.lora_alpha, peft.lora_dropout
        )
    elif peft.method == "oft":
        peft_modules.apply_oft_to_model(model, targets, peft.oft_rank)
    else:
        peft_modules.apply_adapter_to_model(model, targets, peft.adapter_bottleneck)
    return model


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


def make_fake_batch(
    config: ModelConfig,
    batch_size: int = 2,
    seed: int = 0,
    instructions: Sequence[str] | None = None,
) -> dict:
    """A random training batch in dataset layout (openpi's ``fake_obs`` + ``fake_act``)."""
    g = torch.Generator().manual_seed(seed)
    B, T, S = batch_size, config.n_obs_steps, config.image_size
    words = ["chair", "bed", "sofa", "table", "sink", "plant"]
    return {
        "rgb": torch.rand(B, T, 3, S, S, generator=g),  # (B, T, 3, S, S)
        "depth": torch.rand(B, T, 1, S, S, generator=g) * 5.0,  # (B, T, 1, S, S)
        "pose": torch.randn(B, T, 3, generator=g),  # (B, T, 3)
        "action": torch.rand(B, config.horizon, config.action_dim, generator=g) * 2 - 1,
        "instruction": list(instructions)
        if instructions is not None
        else [f"find the {words[i % len(words)]}" for i in range(B)],
    }
