"""``EndToEndPolicy``: the ablation without the GR field or S2 (``model.agent=end_to_end``).

Observations in a *batch* (dataset layout, ``T = n_obs_steps``): ``rgb`` (B, T, 3, H, W)
float in [0, 1] or uint8, ``depth`` (B, T, 1, H, W) metres, ``pose`` (B, T, 3) raw
(x, y, yaw), ``instruction`` list of B strings; training adds ``action`` (B, horizon, 3)
raw. Actions and positions are normalised inside the policy with the dataset's min/max
statistics.

Context tokens (width D): one instruction token, T pose tokens and T*K image tokens, each
with a type and an observation-step embedding, mixed by ``fusion_layers`` transformer
blocks, then decoded by the action head (``model.head``).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping

import numpy as np
import torch
from torch import nn
from torch.utils.checkpoint import checkpoint

from vla_gr.agent.observations import as_instructions, env_obs_to_frame
from vla_gr.configs.model_schema import ModelConfig
from vla_gr.core.diffusion_policy import DiffusionPolicy
from vla_gr.core.encoders import PoseEncoder, RGBDEncoder, build_text_encoder, pose_features
from vla_gr.core.trajectory_attention import TransformerBlock
from vla_gr.policy.base import NavigationPolicy

__all__ = ["EndToEndPolicy"]

_OBS_KEYS = ("rgb", "depth", "pose")


class EndToEndPolicy(NavigationPolicy):
    """Encoders -> fusion transformer -> action head, decoding action chunks."""

    def __init__(self, config: ModelConfig) -> None:
        super().__init__(config)
        c, e = config, config.encoders
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
        self.freeze_parts()
        self.reset()

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

    def forward(self, batch: Mapping) -> dict[str, torch.Tensor]:
        """Training loss of the action head on ``action`` (B, horizon, A) raw.

        Returns ``{"loss": scalar, ...}`` (further detached scalars, for logging).
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

    @torch.no_grad()
    def predict_action_chunk(self, obs: Mapping) -> torch.Tensor:
        """Raw actions ``(B, horizon, A)`` in ``[-1, 1]`` for a batch of observation histories."""
        context = self.encode_observations(obs)  # (B, S, D)
        chunk = self.head.get_action(context)  # (B, H, A), sampler and steps from model.head
        return self.unnormalize_action(chunk).clamp(-1.0, 1.0)  # (B, H, A)

    def _new_env_state(self) -> _History:
        """One env's observation history and action queue."""
        return _History(self.config.n_obs_steps, self.config.n_action_steps)

    def _act(self, obs: Mapping, envs: np.ndarray) -> np.ndarray:
        """One action per env of ``envs`` (b,) -> ``(b, A)``: each env's last ``n_obs_steps``
        observations are kept (its first one repeated after its reset), and a chunk is
        predicted, for the envs whose action queue is empty, in one batch. Timeline of one env
        for ``n_obs_steps=2, horizon=16, n_action_steps=8``::

            env step t      :  0   1   2  ...  7 |  8   9  ... 15 | 16 ...
            observations    : o0 o0,o1 ...       | o7,o8          | o15,o16
            chunk predicted :  *                 |  *             |  *
            action executed : c0[0] c0[1] .. c0[7] | c8[0] .. c8[7] | c16[0] ..

        i.e. a new chunk ``c_t`` (``horizon`` actions from step ``t``) is computed at
        ``t = 0, n_action_steps, 2 * n_action_steps, ...``; only its first
        ``n_action_steps`` actions are executed, the rest is discarded. The head samples
        from torch's global generator: a batch replays lone envs' actions only for a
        deterministic head.
        """
        frame = env_obs_to_frame(obs, device=self.device)  # rgb (B, 3, H, W), ...
        states = [self._env_states[int(i)] for i in envs]
        for i, state in zip(envs, states):
            state.observe({k: frame[k][int(i)] for k in _OBS_KEYS})  # rgb (3, H, W), ...
        due = [j for j, state in enumerate(states) if not state.actions]
        if due:
            history = {
                k: torch.stack([torch.stack(list(states[j].frames[k])) for j in due])
                for k in _OBS_KEYS
            }  # rgb (b', T, 3, H, W), depth (b', T, 1, H, W), pose (b', T, 3)
            history["instruction"] = [frame["instruction"][int(envs[j])] for j in due]
            chunk = self.predict_action_chunk(history)  # (b', H, A)
            for j, actions in zip(due, chunk[:, : self.config.n_action_steps]):  # (n, A)
                states[j].actions.extend(actions.unbind(0))
        actions = torch.stack([state.actions.popleft() for state in states])  # (b, A)
        return actions.float().cpu().numpy()  # (b, A)


class _History:
    """One env's last ``n_obs`` frames (per key) and its queued actions (each ``(A,)``)."""

    def __init__(self, n_obs: int, n_actions: int) -> None:
        self.frames = {k: deque(maxlen=n_obs) for k in _OBS_KEYS}
        self.actions: deque[torch.Tensor] = deque(maxlen=n_actions)

    def reset(self) -> None:
        for frames in self.frames.values():
            frames.clear()
        self.actions.clear()

    def observe(self, frame: Mapping) -> None:
        """Append one frame (the first of an episode fills the history)."""
        for k, frames in self.frames.items():
            if frames:
                frames.append(frame[k])
            else:
                frames.extend([frame[k]] * frames.maxlen)
