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
"""

from __future__ import annotations

import logging

import torch
import torch.nn.functional as F
from diffusers import DDIMScheduler, DDPMScheduler
from torch import nn

from vla_gr.core.diffusion_policy.denoisers import DENOISERS, ConditionalUnet1D, TransformerDenoiser
from vla_gr.core.diffusion_policy.flow_matching import (
    FLOW_SAMPLERS,
    euler_step,
    flow_interpolate,
    flow_target,
    flow_time_grid,
    flow_x0_from_velocity,
    sample_flow_time,
)
from vla_gr.core.diffusion_policy.noise_targets import (
    PREDICTION_TYPES,
    diffusion_target,
    predicted_x0,
    q_sample,
)
from vla_gr.core.diffusion_policy.regression_head import (
    L1RegressionHead,
    check_actions,
    check_choice,
    check_positive_int,
    ctx_mask,
)
from vla_gr.core.trajectory_attention.attention import as_context_tokens

__all__ = [
    "OBJECTIVES",
    "SAMPLERS",
    "FLOW_TIME_SCALE",
    "DiffusionPolicy",
]

logger = logging.getLogger(__name__)

OBJECTIVES = ("diffusion", "flow_matching", "l1")
DIFFUSION_SAMPLERS = ("ddim", "ddpm")
SAMPLERS = {"diffusion": DIFFUSION_SAMPLERS, "flow_matching": FLOW_SAMPLERS, "l1": ()}
BETA_SCHEDULES = ("squaredcos_cap_v2", "linear", "scaled_linear", "sigmoid")
# Flow times t in [0, 1] are fed to the denoiser as t * 1000 (as diffusers' flow-matching
# schedulers do), so the sinusoidal time embedding resolves them like diffusion steps.
FLOW_TIME_SCALE = 1000.0


class DiffusionPolicy(nn.Module):
    """Diffusion / flow-matching / L1 action head with the seed's interface.

    Args:
        action_dim: action size ``A``.
        hidden_dim: widest feature size of the denoiser: transformer width, or the
            deepest U-Net level (``down_dims = (D/4, D/2, D)`` unless given).
        context_dim: context width ``C`` (default ``hidden_dim``).
        num_diffusion_steps: DDPM training steps ``N``.
        prediction_type: ``"v_prediction"``, ``"epsilon"`` or ``"sample"`` (diffusion).
        objective: ``"diffusion"``, ``"flow_matching"`` or ``"l1"``.
        horizon: chunk length ``H`` (8--32 typical; any ``>= 1`` works).
        denoiser: ``"unet1d"`` (conv U-Net with FiLM) or ``"transformer"``.
        num_layers: transformer blocks (transformer denoiser and L1 head).
        num_heads: attention heads.
        mlp_ratio: transformer MLP width as a multiple of ``hidden_dim``.
        down_dims: U-Net channels per level (overrides the ``hidden_dim`` rule).
        kernel_size: U-Net temporal kernel.
        n_groups: U-Net GroupNorm groups.
        time_embed_dim: U-Net time embedding size (default ``hidden_dim // 2``).
        beta_schedule: diffusers beta schedule (``squaredcos_cap_v2`` as Diffusion Policy).
        clip_sample: clip samples to ``[-1, 1]`` (normalised actions).
        flow_beta_alpha: ``alpha`` of pi0's ``Beta(alpha, 1)`` flow time distribution.
        flow_time_scale: pi0's ``s``: times lie in ``[1 - s, 1]``.
        dropout: dropout probability (transformer parts).
        gradient_checkpointing: recompute denoiser blocks in backward (8 GB GPUs).
        default_sampler: sampler when ``get_action`` gets none (``ddim`` / ``euler``).
    """

    def __init__(
        self,
        action_dim: int = 7,
        hidden_dim: int = 256,
        context_dim: int | None = None,
        num_diffusion_steps: int = 100,
        prediction_type: str = "v_prediction",
        objective: str = "diffusion",
        horizon: int = 16,
        denoiser: str = "unet1d",
        num_layers: int = 4,
        num_heads: int = 4,
        mlp_ratio: float = 4.0,
        down_dims: tuple[int, ...] | None = None,
        kernel_size: int = 5,
        n_groups: int = 8,
        time_embed_dim: int | None = None,
        beta_schedule: str = "squaredcos_cap_v2",
        clip_sample: bool = True,
        flow_beta_alpha: float = 1.5,
        flow_time_scale: float = 0.999,
        dropout: float = 0.0,
        gradient_checkpointing: bool = False,
        default_sampler: str | None = None,
    ) -> None:
        super().__init__()
        check_choice("objective", objective, OBJECTIVES)
        check_choice("prediction_type", prediction_type, PREDICTION_TYPES)
        check_choice("denoiser", denoiser, DENOISERS)
        check_choice("beta_schedule", beta_schedule, BETA_SCHEDULES)
        for name, val in (
            ("action_dim", action_dim),
            ("hidden_dim", hidden_dim),
            ("num_diffusion_steps", num_diffusion_steps),
            ("horizon", horizon),
            ("num_layers", num_layers),
        ):
            check_positive_int(name, val)
        if context_dim is not None:
            check_positive_int("context_dim", context_dim)
        if flow_beta_alpha <= 0:
            raise ValueError(f"flow_beta_alpha={flow_beta_alpha} must be > 0")
        if not 0.0 < flow_time_scale <= 1.0:
            raise ValueError(f"flow_time_scale={flow_time_scale} must be in (0, 1]")
        self.action_dim, self.hidden_dim, self.horizon = action_dim, hidden_dim, horizon
        self.context_dim = hidden_dim if context_dim is None else context_dim
        self.num_diffusion_steps, self.prediction_type = num_diffusion_steps, prediction_type
        self.objective, self.denoiser_type, self.clip_sample = objective, denoiser, clip_sample
        self.flow_beta_alpha, self.flow_time_scale = flow_beta_alpha, flow_time_scale
        samplers = SAMPLERS[objective]
        if default_sampler is None:
            default_sampler = samplers[0] if samplers else None
        elif objective != "l1":
            check_choice("default_sampler", default_sampler, samplers)
        self.default_sampler = default_sampler

        self.head: L1RegressionHead | None = None
        self.denoiser: nn.Module | None = None
        self._compiled_step = None  # set by compile_sampler()
        if objective == "l1":
            self.head = L1RegressionHead(
                action_dim,
                hidden_dim,
                self.context_dim,
                horizon,
                num_layers,
                num_heads,
                dropout,
                clip_sample,
                gradient_checkpointing,
                mlp_ratio,
            )
            return
        if denoiser == "unet1d":
            if down_dims is None:  # (D/4, D/2, D), rounded to multiples of n_groups
                down_dims = tuple(
                    max(n_groups, (hidden_dim // f) // n_groups * n_groups) for f in (4, 2, 1)
                )
            self.denoiser = ConditionalUnet1D(
                action_dim,
                self.context_dim,
                tuple(down_dims),
                time_embed_dim or max(hidden_dim // 4 * 2, 4),  # even, ~hidden_dim / 2
                kernel_size,
                n_groups,
                gradient_checkpointing,
            )
        else:
            self.denoiser = TransformerDenoiser(
                action_dim,
                self.context_dim,
                hidden_dim,
                num_layers,
                num_heads,
                mlp_ratio=mlp_ratio,
                dropout=dropout,
                gradient_checkpointing=gradient_checkpointing,
            )
        if objective == "diffusion":
            cfg = dict(
                num_train_timesteps=num_diffusion_steps,
                beta_schedule=beta_schedule,
                clip_sample=clip_sample,
                clip_sample_range=1.0,
                prediction_type=prediction_type,
                timestep_spacing="trailing",
            )
            self.ddpm = DDPMScheduler(**cfg)
            self.ddim = DDIMScheduler(**cfg, set_alpha_to_one=True, steps_offset=0)
            acp = torch.as_tensor(self.ddpm.alphas_cumprod, dtype=torch.float32)  # (N,)
            self.register_buffer("alphas_cumprod", acp, persistent=False)
        logger.debug(
            "DiffusionPolicy(objective=%s, denoiser=%s): %d parameters",
            objective,
            denoiser,
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

    def forward(
        self,
        actions: torch.Tensor,
        context: torch.Tensor,
        context_padding_mask: torch.Tensor | None = None,
        generator: torch.Generator | None = None,
    ) -> dict[str, torch.Tensor]:
        """Training loss.

        Args:
            actions: ``(B, H, A)`` normalised target actions.
            context: ``(B, C)`` or ``(B, T, C)``.
            context_padding_mask: optional bool ``(B, T)``, ``True`` = padded.
            generator: optional RNG for noise and times (reproducible losses).

        Returns:
            ``{"loss": scalar, "mse": scalar, "x0_mse": scalar}`` (logged scalars detached;
            ``{"loss", "l1"}`` for the L1 objective).
        """
        if self.head is not None:
            return self.head(actions, context, context_padding_mask)
        check_actions(actions, self.horizon, self.action_dim)
        ctx = as_context_tokens(context, self.context_dim)  # (B, T, C)
        mask = ctx_mask(context_padding_mask)
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

    def get_action(
        self,
        context: torch.Tensor,
        num_inference_steps: int = 10,
        sampler: str | None = None,
        generator: torch.Generator | None = None,
        context_padding_mask: torch.Tensor | None = None,
        eta: float = 0.0,
        noise: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Sample an action chunk.

        Args:
            context: ``(B, C)`` or ``(B, T, C)``.
            num_inference_steps: denoising / integration steps (ignored by ``l1``).
            sampler: ``"ddim"`` | ``"ddpm"`` (diffusion), ``"euler"`` | ``"midpoint"``
                (flow matching); default ``default_sampler``.
            generator: RNG for the initial noise (and DDPM / DDIM ``eta > 0`` noise).
            context_padding_mask: optional bool ``(B, T)``, ``True`` = padded.
            eta: DDIM stochasticity (0 = deterministic).
            noise: optional initial noise ``(B, H, A)`` (overrides ``generator`` for it).

        Returns:
            ``(B, H, A)`` actions (clipped to ``[-1, 1]`` when ``clip_sample``).
        """
        if self.head is not None:
            return self.head.get_action(context, context_padding_mask=context_padding_mask)
        # inference_mode skips autograd bookkeeping (~12% faster than no_grad at batch 1);
        # the clone returns an ordinary tensor that later autograd code may use.
        with torch.inference_mode():
            x = self._get_action(
                context, num_inference_steps, sampler, generator, context_padding_mask, eta, noise
            )
        return x.clone()

    def _get_action(
        self,
        context: torch.Tensor,
        num_inference_steps: int,
        sampler: str | None,
        generator: torch.Generator | None,
        context_padding_mask: torch.Tensor | None,
        eta: float,
        noise: torch.Tensor | None,
    ) -> torch.Tensor:
        """Body of :meth:`get_action` (runs under ``torch.inference_mode``)."""
        sampler = self.default_sampler if sampler is None else sampler
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
