"""``HeadConfig``: every setting of the action head, and the one list of each choice.

:class:`~vla_gr.core.diffusion_policy.head.DiffusionPolicy` is built from a ``HeadConfig``
(recipe key ``model.head``); its keyword constructor fills one. Next in the data flow:
:mod:`vla_gr.core.diffusion_policy.head`.
"""

from __future__ import annotations

from dataclasses import dataclass

from vla_gr.validation import check_choice, check_positive, check_positive_int

__all__ = [
    "BETA_SCHEDULES",
    "DENOISERS",
    "DIFFUSION_SAMPLERS",
    "FLOW_SAMPLERS",
    "OBJECTIVES",
    "PREDICTION_TYPES",
    "SAMPLERS",
    "HeadConfig",
]

OBJECTIVES = ("diffusion", "flow_matching", "l1")
DENOISERS = ("unet1d", "transformer")
PREDICTION_TYPES = ("epsilon", "v_prediction", "sample")
DIFFUSION_SAMPLERS = ("ddim", "ddpm")
FLOW_SAMPLERS = ("euler", "midpoint")
#: Samplers per objective; the first is the default. The L1 head has no sampling loop.
SAMPLERS = {"diffusion": DIFFUSION_SAMPLERS, "flow_matching": FLOW_SAMPLERS, "l1": ()}
BETA_SCHEDULES = ("squaredcos_cap_v2", "linear", "scaled_linear", "sigmoid")


@dataclass
class HeadConfig:
    """The action head (``model.head.*``). The first five fields are the seed's positional
    arguments ``DiffusionPolicy(action_dim, hidden_dim, context_dim, num_diffusion_steps,
    prediction_type)``.

    Inside the agent, ``action_dim``, ``horizon`` and ``context_dim`` follow
    ``model.action_dim``, ``model.horizon`` and ``model.encoders.dim``.
    """

    action_dim: int = 3  # the world's action: (linear, angular, stop)
    hidden_dim: int = 128  # transformer width, or the deepest U-Net level
    context_dim: int | None = None  # context width C; None = hidden_dim
    num_diffusion_steps: int = 100  # DDPM training steps N
    prediction_type: str = "v_prediction"  # diffusion target
    objective: str = "diffusion"
    horizon: int = 16  # chunk length H
    denoiser: str = "unet1d"  # conv U-Net with FiLM, or transformer
    num_layers: int = 2  # transformer blocks (transformer denoiser and L1 head)
    num_heads: int = 4
    mlp_ratio: float = 4.0  # transformer MLP width / hidden_dim
    down_dims: list[int] | None = None  # U-Net channels per level; None = (D/4, D/2, D)
    kernel_size: int = 5  # U-Net temporal kernel
    n_groups: int = 8  # U-Net GroupNorm groups
    time_embed_dim: int | None = None  # U-Net time embedding; None = ~hidden_dim / 2
    beta_schedule: str = "squaredcos_cap_v2"  # diffusers schedule, as Diffusion Policy
    clip_sample: bool = True  # actions are normalised to [-1, 1]
    flow_beta_alpha: float = 1.5  # pi0's Beta(alpha, 1) flow time distribution
    flow_time_scale: float = 0.999  # pi0's s: flow times lie in [1 - s, 1]
    dropout: float = 0.0
    gradient_checkpointing: bool = False  # recompute denoiser blocks in backward
    sampler: str | None = None  # None = the objective's first sampler (ddim / euler)
    num_inference_steps: int = 10  # denoising / integration steps (ignored by l1)

    def __post_init__(self) -> None:
        check_choice("model.head.objective", self.objective, OBJECTIVES)
        check_choice("model.head.prediction_type", self.prediction_type, PREDICTION_TYPES)
        check_choice("model.head.denoiser", self.denoiser, DENOISERS)
        check_choice("model.head.beta_schedule", self.beta_schedule, BETA_SCHEDULES)
        for key in (
            "action_dim", "hidden_dim", "num_diffusion_steps", "horizon", "num_layers",
            "num_heads", "kernel_size", "n_groups", "num_inference_steps",
        ):  # fmt: skip
            check_positive_int(f"model.head.{key}", getattr(self, key))
        for key in ("context_dim", "time_embed_dim"):
            if getattr(self, key) is not None:
                check_positive_int(f"model.head.{key}", getattr(self, key))
        if self.down_dims is not None:
            if not self.down_dims:
                raise ValueError("model.head.down_dims must be None or a non-empty list")
            for width in self.down_dims:
                check_positive_int("model.head.down_dims[]", width)
        check_positive("model.head.mlp_ratio", self.mlp_ratio)
        check_positive("model.head.flow_beta_alpha", self.flow_beta_alpha)
        if not 0.0 < self.flow_time_scale <= 1.0:
            raise ValueError(f"model.head.flow_time_scale={self.flow_time_scale} must be in (0, 1]")
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"model.head.dropout={self.dropout} must be in [0, 1)")
        samplers = SAMPLERS[self.objective]
        if self.sampler is not None:
            check_choice(f"model.head.sampler (objective {self.objective})", self.sampler, samplers)

    @property
    def resolved_context_dim(self) -> int:
        """Context width ``C`` (``hidden_dim`` when ``context_dim`` is None)."""
        return self.hidden_dim if self.context_dim is None else self.context_dim

    @property
    def resolved_sampler(self) -> str | None:
        """``sampler``, or the objective's default (None for ``l1``)."""
        samplers = SAMPLERS[self.objective]
        return self.sampler if self.sampler is not None else (samplers[0] if samplers else None)
