"""The learned S1: current RGB-D + the latest S2 plan -> a (v, w) chunk and a STOP probability.

:class:`S1Policy` (``model.s1``, well under 2 M parameters with its own encoder) encodes the
RGB-D pooled to ``image_size`` with a strided conv stack and the plan vector of
:mod:`.s1_inputs` with an MLP, fuses them into three context tokens and decodes an action
chunk with the configured head (flow matching by default; DDIM, L1 or the transformer
denoiser selectable through ``model.s1.head``); a separate logit decides STOP.

:class:`LearnedFollower` runs it at batch 1 inside the grounded dual system: it receives S2's
plans like the pure-pursuit follower does, executes ``n_action_steps`` of each chunk and asks
S1 again (at once when a new plan arrives).
"""

from __future__ import annotations

from collections import deque
from dataclasses import replace

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from vla_gr.agent.followers.pure_pursuit import PursuitConfig, clearance_ahead, guarded_speed
from vla_gr.agent.followers.s1_inputs import PlanMemory, plan_vector_size, pool_rgbd
from vla_gr.core.diffusion_policy import DiffusionPolicy
from vla_gr.core.dual_system.config import S1Config

__all__ = ["LearnedFollower", "S1Policy"]


def _conv_stack(channels: list[int]) -> nn.Sequential:
    layers, c_in = [], 4
    for c in channels:
        layers += [nn.Conv2d(c_in, c, 3, stride=2, padding=1), nn.GroupNorm(1, c), nn.GELU()]
        c_in = c
    return nn.Sequential(*layers)


class S1Policy(nn.Module):
    """S1's network: (rgb, depth, plan vector) -> context -> action chunk; + STOP logit."""

    def __init__(self, config: S1Config) -> None:
        super().__init__()
        self.config = c = config
        self.plan_dim = plan_vector_size(c.path_points)
        side = c.image_size // 2 ** len(c.channels)
        self.encoder = _conv_stack(list(c.channels))
        self.visual_proj = nn.Linear(c.channels[-1] * side * side, c.dim)
        self.plan_proj = nn.Sequential(
            nn.Linear(self.plan_dim, c.dim), nn.GELU(), nn.Linear(c.dim, c.dim)
        )
        self.fuse = nn.Sequential(nn.LayerNorm(2 * c.dim), nn.Linear(2 * c.dim, c.dim), nn.GELU())
        self.token_embed = nn.Parameter(torch.randn(3, c.dim) * 0.02)  # fused, visual, plan
        self.stop_head = nn.Sequential(nn.Linear(c.dim, c.dim), nn.GELU(), nn.Linear(c.dim, 1))
        self.head = DiffusionPolicy(config=replace(c.head, context_dim=c.dim))

    def encode(
        self, rgb: torch.Tensor, depth: torch.Tensor, plan: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Context tokens and the STOP logit.

        Args:
            rgb: (B, 3, s, s) uint8 or float in [0, 1]; depth: (B, 1, s, s) metres;
            plan: (B, P) plan vectors.

        Returns:
            context (B, 3, D) and stop logit (B,).
        """
        rgb = rgb.float() / 255.0 if rgb.dtype == torch.uint8 else rgb.float()
        d = (depth.float() / self.config.max_depth).clamp(0.0, 1.0)  # (B, 1, s, s)
        x = torch.cat([rgb * 2.0 - 1.0, d * 2.0 - 1.0], dim=1)  # (B, 4, s, s)
        visual = self.visual_proj(self.encoder(x).flatten(1))  # (B, D)
        planned = self.plan_proj(plan.float())  # (B, D)
        fused = self.fuse(torch.cat([visual, planned], dim=-1))  # (B, D)
        tokens = torch.stack([fused, visual, planned], dim=1) + self.token_embed  # (B, 3, D)
        return tokens, self.stop_head(fused).squeeze(-1)  # (B, 3, D), (B,)

    def forward(self, batch: dict) -> dict[str, torch.Tensor]:
        """Training loss on ``rgb``, ``depth``, ``plan``, ``chunk`` (B, H, 2), ``stop`` (B,).

        ``loss = head loss(chunk) + stop_weight * BCE(stop logit, stop)``; the other entries
        are detached scalars for logging (``stop_acc`` at ``stop_threshold``).
        """
        context, stop_logit = self.encode(batch["rgb"], batch["depth"], batch["plan"])
        out = self.head(batch["chunk"].float(), context)
        target = batch["stop"].float()  # (B,)
        stop_loss = F.binary_cross_entropy_with_logits(stop_logit, target)
        predicted = torch.sigmoid(stop_logit) > self.config.stop_threshold  # (B,)
        return {
            "loss": out["loss"] + self.config.stop_weight * stop_loss,
            "action_loss": out["loss"].detach(),
            "stop_loss": stop_loss.detach(),
            "stop_acc": (predicted == (target > 0.5)).float().mean(),
        }

    @torch.no_grad()
    def act(
        self, rgb: torch.Tensor, depth: torch.Tensor, plan: torch.Tensor, generator=None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """(B, H, 2) action chunk in [-1, 1] and (B,) STOP probability."""
        context, stop_logit = self.encode(rgb, depth, plan)
        chunk = self.head.get_action(context, generator=generator)  # (B, H, 2)
        return chunk.clamp(-1.0, 1.0), torch.sigmoid(stop_logit)


class LearnedFollower:
    """S1 at batch 1 in the dual system: plans in, one action (v, w, stop) per control step.

    Same protocol as :class:`~vla_gr.agent.followers.pure_pursuit.PurePursuit`:
    ``set_plan(plan, pose)`` after each S2 tick, ``act(depth, pose, rgb)`` every step.
    """

    def __init__(self, policy: S1Policy, seed: int = 0, guard: PursuitConfig | None = None):
        """``guard``: the depth check (``model.pursuit``) that limits the forward speed of
        every action S1 emits (``model.s1.depth_guard``); None leaves S1's actions as they
        are."""
        self.policy = policy
        self.guard = guard
        self.config = policy.config
        self.memory = PlanMemory(self.config.path_points)
        self.seed = int(seed)
        self.reset()

    def reset(self) -> None:
        """New episode: no plan, empty queue, the sampler's noise restarts from ``seed``."""
        self.memory.reset()
        self.queue: deque[np.ndarray] = deque()
        self.steps = 0
        self.last_stop_probability = 0.0
        device = next(self.policy.parameters()).device
        self.generator = torch.Generator(device=device).manual_seed(self.seed)

    def set_plan(self, plan, pose) -> None:
        """A new S2 plan made at ``pose`` (3,): S1 decides again on the next step."""
        if self.config.use_s2:
            self.memory.set_plan(plan, pose, self.steps)
        self.queue.clear()

    def inputs(self, rgb, depth, pose) -> dict[str, np.ndarray]:
        """S1's inputs now: ``rgb`` (3, s, s) uint8, ``depth`` (1, s, s), ``plan`` (P,)."""
        small_rgb, small_depth = pool_rgbd(rgb, depth, self.config.image_size)
        return {
            "rgb": small_rgb,
            "depth": small_depth,
            "plan": self.memory.vector(pose, self.steps),
        }

    def act(self, depth, pose, rgb=None) -> np.ndarray:
        """Action (3,) float32 = (v, w, stop) for the current frame (rgb (H, W, 3) needed)."""
        if rgb is None:
            raise ValueError("the learned S1 needs the RGB image (act(depth, pose, rgb=...))")
        if not self.queue:
            device = next(self.policy.parameters()).device
            x = {
                k: torch.from_numpy(v).unsqueeze(0).to(device)
                for k, v in self.inputs(rgb, depth, pose).items()
            }  # each (1, ...)
            chunk, stop = self.policy.act(x["rgb"], x["depth"], x["plan"], self.generator)
            self.last_stop_probability = float(stop[0])
            if self.last_stop_probability > self.config.stop_threshold:
                self.steps += 1
                return np.array([0.0, 0.0, 1.0], np.float32)
            steps = chunk[0, : self.config.n_action_steps].cpu().numpy()  # (n, 2)
            self.queue.extend(np.concatenate([steps, -np.ones((len(steps), 1))], 1))
        self.steps += 1
        action = self.queue.popleft().astype(np.float32)  # (3,) = (v, w, stop)
        if self.guard is not None and action[0] > 0:
            action[0] = guarded_speed(
                float(action[0]), clearance_ahead(depth, self.guard), self.guard
            )
        return action
