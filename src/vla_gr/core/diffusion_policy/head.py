"""Action heads that turn context features into action chunks ``(B, H, A)``.

- ``objective="diffusion"`` -- DDPM training (Ho et al. 2020) with ``epsilon``,
  ``v_prediction`` or ``sample`` targets on diffusers' noise schedule; sampling with
  diffusers' DDIM (deterministic for ``eta=0``) or DDPM schedulers, as in Diffusion
  Policy (Chi et al. 2023).
- ``objective="flow_matching"`` -- pi0's conditional flow matching (straight path
  ``x_t = t * noise + (1 - t) * actions``, Beta-shaped times emphasising noise; see
  :mod:`vla_gr.core.diffusion_policy.flow_matching`), Euler or midpoint integration.
- ``objective="l1"`` -- OpenVLA-OFT's parallel-decoding L1 regression
  (:class:`L1RegressionHead`, defined in :mod:`vla_gr.core.diffusion_policy.regression_head`): one
  forward pass, no sampling loop.

Actions are assumed normalised to ``[-1, 1]`` (``clip_sample`` clips samples there).
Context is a ``(B, C)`` vector or ``(B, T, C)`` tokens (with an optional bool
``(B, T)`` padding mask, ``True`` = padded).

Example (the seed's calls)::

    policy = DiffusionPolicy(7, 256, 512, 100, "v_prediction")
    loss = policy(actions, context)["loss"]          # actions (B, 16, 7), context (B, 512)
    chunk = policy.get_action(context, num_inference_steps=10)   # (B, 16, 7)

Sampling precomputes everything that does not depend on the noisy sample (time
embeddings, context pooling/projection, FiLM parameters) once per chunk; only the
denoiser's per-step trunk runs inside the loop. That trunk is
``denoiser.sampling_step(noise)``, asked for once per chunk: at batch 1 the U-Net gives
a :class:`~vla_gr.core.diffusion_policy.unet_inference.UnetStepPlan` (same maths, about
half the eager per-op overhead; built from views of the current parameters, so it can
never run stale weights), otherwise the reference ``denoise_step``.

Next in the data flow: the denoisers (:mod:`vla_gr.core.diffusion_policy.denoisers`); the
agent that feeds it context is :class:`vla_gr.policy.VLAGRPolicy`.
"""

from __future__ import annotations

import logging

import torch
import torch.nn.functional as F
from diffusers import DDIMScheduler, DDPMScheduler
from torch import nn

from vla_gr.core.diffusion_policy.config import SAMPLERS, HeadConfig
from vla_gr.core.diffusion_policy.denoisers import ConditionalUnet1D, TransformerDenoiser
from vla_gr.core.diffusion_policy.flow_matching import (
    euler_step,
    flow_interpolate,
    flow_target,
    flow_time_grid,
    flow_x0_from_velocity,
    sample_flow_time,
)
from vla_gr.core.diffusion_policy.noise_targets import (
    diffusion_target,
    predicted_x0,
    q_sample,
)
from vla_gr.core.diffusion_policy.regression_head import (
    ActionHead,
    L1RegressionHead,
    ctx_mask,
)
from vla_gr.core.trajectory_attention.attention import as_context_tokens
from vla_gr.validation import check_choice, check_positive_int

__all__ = ["FLOW_TIME_SCALE", "DiffusionPolicy"]

logger = logging.getLogger(__name__)

# Flow times t in [0, 1] are fed to the denoiser as t * 1000 (as diffusers' flow-matching
# schedulers do), so the sinusoidal time embedding resolves them like diffusion steps.
FLOW_TIME_SCALE = 1000.0


class DiffusionPolicy(ActionHead):
    """Diffusion / flow-matching / L1 action head with the seed's interface.

    Built from a :class:`~vla_gr.core.diffusion_policy.config.HeadConfig` (every setting
    and its default live there): ``DiffusionPolicy(config=HeadConfig(...))``, or with the
    seed's keywords, which fill one: ``DiffusionPolicy(action_dim, hidden_dim, context_dim,
    num_diffusion_steps, prediction_type, objective=..., horizon=..., ...)``.
    """

    def __init__(self, *args, config: HeadConfig | None = None, **kwargs) -> None:
        super().__init__()
        if config is None:
            config = HeadConfig(*args, **kwargs)
        elif args or kwargs:
            raise ValueError("pass either a HeadConfig or keyword arguments, not both")
        self.config = c = config
        self.action_dim, self.hidden_dim, self.horizon = c.action_dim, c.hidden_dim, c.horizon
        self.context_dim = c.resolved_context_dim
        self.num_diffusion_steps, self.prediction_type = c.num_diffusion_steps, c.prediction_type
        self.objective, self.denoiser_type, self.clip_sample = (
            c.objective,
            c.denoiser,
            c.clip_sample,
        )
        self.flow_beta_alpha, self.flow_time_scale = c.flow_beta_alpha, c.flow_time_scale
        self.default_sampler = c.resolved_sampler

        self.head: L1RegressionHead | None = None
        self.denoiser: nn.Module | None = None
        self._compiled_step = None  # set by compile_sampler()
        if c.objective == "l1":
            self.head = L1RegressionHead(
                c.action_dim,
                c.hidden_dim,
                self.context_dim,
                c.horizon,
                c.num_layers,
                c.num_heads,
                c.dropout,
                c.clip_sample,
                c.gradient_checkpointing,
                c.mlp_ratio,
            )
            return
        if c.denoiser == "unet1d":
            down_dims = c.down_dims
            if down_dims is None:  # (D/4, D/2, D), rounded to multiples of n_groups
                g = c.n_groups
                down_dims = [max(g, (c.hidden_dim // f) // g * g) for f in (4, 2, 1)]
            self.denoiser = ConditionalUnet1D(
                c.action_dim,
                self.context_dim,
                tuple(down_dims),
                c.time_embed_dim or max(c.hidden_dim // 4 * 2, 4),  # even, ~hidden_dim / 2
                c.kernel_size,
                c.n_groups,
                c.gradient_checkpointing,
            )
        else:
            self.denoiser = TransformerDenoiser(
                c.action_dim,
                self.context_dim,
                c.hidden_dim,
                c.num_layers,
                c.num_heads,
                mlp_ratio=c.mlp_ratio,
                dropout=c.dropout,
                gradient_checkpointing=c.gradient_checkpointing,
            )
        if c.objective == "diffusion":
            cfg = dict(
                num_train_timesteps=c.num_diffusion_steps,
                beta_schedule=c.beta_schedule,
                clip_sample=c.clip_sample,
                clip_sample_range=1.0,
                prediction_type=c.prediction_type,
                timestep_spacing="trailing",
            )
            self.ddpm = DDPMScheduler(**cfg)
            self.ddim = DDIMScheduler(**cfg, set_alpha_to_one=True, steps_offset=0)
            acp = torch.as_tensor(self.ddpm.alphas_cumprod, dtype=torch.float32)  # (N,)
            self.register_buffer("alphas_cumprod", acp, persistent=False)
        logger.debug(
            "DiffusionPolicy(objective=%s, denoiser=%s): %d parameters",
            c.objective,
            c.denoiser,
            sum(p.numel() for p in self.parameters()),
        )

    def compile_sampler(self, **compile_kwargs) -> DiffusionPolicy:
        """Compile the per-step denoiser trunk with ``torch.compile`` (opt-in).

        Fuses the per-step ops (for the U-Net at batch 1 on CPU about as fast as the
        eager step plan, which it replaces; see ``benchmarks/results/bench_heads.md``).
        The first call compiles, which takes a minute or more on a small CPU. Shapes are static
        (``dynamic=False`` unless given). Call again after changing the module structure
        (e.g. adding or merging adapters).

        Args:
            **compile_kwargs: forwarded to :func:`torch.compile`.

        Returns:
            ``self``.
        """
        if self.denoiser is None:
            raise ValueError("objective='l1' has no sampling loop to compile")
        compile_kwargs.setdefault("dynamic", False)
        self._compiled_step = torch.compile(self.denoiser.denoise_step, **compile_kwargs)
        return self

    def __getstate__(self) -> dict:
        state = super().__getstate__() if hasattr(super(), "__getstate__") else self.__dict__
        state = dict(state)
        state["_compiled_step"] = None  # compiled functions are not copied / pickled
        return state

    # ------------------------------------------------------------------ training

    def _loss(
        self,
        actions: torch.Tensor,
        ctx: torch.Tensor,
        mask: torch.Tensor | None,
        generator: torch.Generator | None,
    ) -> dict[str, torch.Tensor]:
        """Diffusion / flow-matching loss ``{"loss": scalar, "mse": scalar, "x0_mse": scalar}``
        (``{"loss", "l1"}`` for the L1 objective); ``generator`` draws noise and times."""
        if self.head is not None:
            return self.head(actions, ctx, mask)
        B = actions.shape[0]
        noise = torch.randn(
            actions.shape, generator=generator, device=actions.device, dtype=actions.dtype
        )  # (B, H, A)
        if self.objective == "diffusion":
            t = torch.randint(
                0, self.num_diffusion_steps, (B,), generator=generator, device=actions.device
            )  # (B,)
            x_t = q_sample(actions, noise, t, self.alphas_cumprod)  # (B, H, A)
            target = diffusion_target(actions, noise, t, self.alphas_cumprod, self.prediction_type)
            pred = self.denoiser(x_t, t.float(), ctx, mask)  # (B, H, A)
            x0 = predicted_x0(pred.detach(), x_t, t, self.alphas_cumprod, self.prediction_type)
        else:
            t = sample_flow_time(
                B,
                self.flow_beta_alpha,
                1.0,
                self.flow_time_scale,
                generator=generator,
                device=actions.device,
            )  # (B,)
            x_t = flow_interpolate(actions, noise, t)  # (B, H, A)
            target = flow_target(actions, noise)  # (B, H, A)
            pred = self.denoiser(x_t, t * FLOW_TIME_SCALE, ctx, mask)  # (B, H, A)
            x0 = flow_x0_from_velocity(x_t, pred.detach(), t)  # (B, H, A)
        loss = F.mse_loss(pred, target)
        return {
            "loss": loss,
            "mse": loss.detach(),
            "x0_mse": F.mse_loss(x0, actions).detach(),
        }

    # ------------------------------------------------------------------ sampling

    def _get_action(
        self,
        context: torch.Tensor,
        context_padding_mask: torch.Tensor | None,
        num_inference_steps: int | None,
        sampler: str | None,
        generator: torch.Generator | None,
        eta: float,
        noise: torch.Tensor | None,
    ) -> torch.Tensor:
        """Body of :meth:`get_action` (runs under ``torch.inference_mode``)."""
        if self.head is not None:
            return self.head._get_action(context, context_padding_mask)
        sampler = self.default_sampler if sampler is None else sampler
        if num_inference_steps is None:
            num_inference_steps = self.config.num_inference_steps
        check_choice("sampler", sampler, SAMPLERS[self.objective])
        check_positive_int("num_inference_steps", num_inference_steps)
        ctx = as_context_tokens(context, self.context_dim)  # (B, T, C)
        shape = (ctx.shape[0], self.horizon, self.action_dim)
        if noise is None:
            noise = torch.randn(shape, generator=generator, device=ctx.device, dtype=ctx.dtype)
        elif tuple(noise.shape) != shape:
            raise ValueError(f"noise must be {shape}; got {tuple(noise.shape)}")
        prepared = self.denoiser.prepare_context(ctx, ctx_mask(context_padding_mask))
        if self.objective == "flow_matching":
            x = self._sample_flow(noise, prepared, num_inference_steps, sampler)
        else:
            x = self._sample_diffusion(
                noise, prepared, num_inference_steps, sampler, generator, eta
            )
        return x.clamp(-1.0, 1.0) if self.clip_sample else x  # (B, H, A)

    def _sample_flow(
        self, x: torch.Tensor, prepared: dict, num_steps: int, sampler: str
    ) -> torch.Tensor:
        """Integrate the learned velocity from ``t = 1`` to ``0``; ``x``: ``(B, H, A)``."""
        times = flow_time_grid(num_steps, x.device)  # (N + 1,)
        dt = float(times[1] - times[0])  # -1/N
        if sampler == "euler":
            eval_t = times[:-1]  # (N,)
        else:  # midpoint: t_i and t_i + dt/2 interleaved
            eval_t = torch.stack((times[:-1], times[:-1] + 0.5 * dt), dim=1).flatten()  # (2N,)
        conds = self.denoiser.step_conditions(
            self.denoiser.embed_time(eval_t * FLOW_TIME_SCALE), prepared
        )
        step = self._compiled_step or self.denoiser.sampling_step(x)
        if sampler == "euler":
            for i in range(num_steps):
                x = euler_step(x, step(x, conds[i]), dt)  # (B, H, A)
        else:
            for i in range(num_steps):
                half = euler_step(x, step(x, conds[2 * i]), 0.5 * dt)  # (B, H, A)
                x = euler_step(x, step(half, conds[2 * i + 1]), dt)  # (B, H, A)
        return x

    def _sample_diffusion(
        self,
        x: torch.Tensor,
        prepared: dict,
        num_steps: int,
        sampler: str,
        generator: torch.Generator | None,
        eta: float,
    ) -> torch.Tensor:
        """Reverse diffusion with diffusers' DDIM / DDPM step; ``x``: ``(B, H, A)``."""
        if num_steps > self.num_diffusion_steps:
            raise ValueError(
                f"num_inference_steps={num_steps} exceeds num_diffusion_steps="
                f"{self.num_diffusion_steps}"
            )
        sched = self.ddim if sampler == "ddim" else self.ddpm
        if sched.num_inference_steps != num_steps:
            sched.set_timesteps(num_steps)
        timesteps = sched.timesteps  # (N,) int64, decreasing
        conds = self.denoiser.step_conditions(
            self.denoiser.embed_time(timesteps.to(x.device, torch.float32)), prepared
        )
        step = self._compiled_step or self.denoiser.sampling_step(x)
        for i, t in enumerate(timesteps.tolist()):
            out = step(x, conds[i])  # (B, H, A)
            if sampler == "ddim":
                x = sched.step(out, t, x, eta=eta, generator=generator).prev_sample
            else:
                x = sched.step(out, t, x, generator=generator).prev_sample
        return x  # (B, H, A)
