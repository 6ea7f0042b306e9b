"""Diffusion (DDPM) maths as pure functions: forward noising and regression targets.

With ``ab = alphas_cumprod[t]`` (``alpha_bar``) the forward process is

    x_t = sqrt(ab) * x0 + sqrt(1 - ab) * eps,

and the network regresses one of (``prediction_type``):

- ``"epsilon"``: ``eps`` (DDPM, Ho et al. 2020);
- ``"sample"``: ``x0`` (Diffusion Policy's option, "predict the clean sample");
- ``"v_prediction"``: ``v = sqrt(ab) * eps - sqrt(1 - ab) * x0`` (Salimans & Ho 2022).

These match diffusers' ``add_noise`` / ``get_velocity`` and the way its schedulers'
``step`` interpret model outputs (checked by the tests), so a model trained with these
targets is sampled with diffusers' DDPM / DDIM schedulers.

Next in the data flow: :mod:`vla_gr.core.diffusion_policy.head` (diffusion training uses it).
"""

from __future__ import annotations

import torch

from vla_gr.core.diffusion_policy.config import PREDICTION_TYPES
from vla_gr.validation import check_choice

__all__ = [
    "gather_alpha_bar",
    "q_sample",
    "diffusion_target",
    "predicted_x0",
]


def gather_alpha_bar(
    alphas_cumprod: torch.Tensor, timesteps: torch.Tensor, ndim: int
) -> torch.Tensor:
    """``alpha_bar`` at ``timesteps``, shaped to broadcast over a ``ndim``-d sample.

    Args:
        alphas_cumprod: ``(N,)`` cumulative products of ``1 - beta``.
        timesteps: ``(B,)`` integer timesteps in ``[0, N)``.
        ndim: number of dims of the sample (3 for ``(B, H, A)``).

    Returns:
        ``(B, 1, ..., 1)`` with ``ndim`` dims.
    """
    ab = alphas_cumprod.to(timesteps.device)[timesteps.long()]  # (B,)
    return ab.view(-1, *([1] * (ndim - 1)))  # (B, 1, 1)


def _alpha_bar_like(
    alphas_cumprod: torch.Tensor, timesteps: torch.Tensor, sample: torch.Tensor
) -> torch.Tensor:
    """:func:`gather_alpha_bar` shaped for ``sample`` ``(B, H, A)`` and in its dtype:
    ``(B, 1, 1)``."""
    return gather_alpha_bar(alphas_cumprod, timesteps, sample.dim()).to(sample.dtype)


def q_sample(
    x0: torch.Tensor, noise: torch.Tensor, timesteps: torch.Tensor, alphas_cumprod: torch.Tensor
) -> torch.Tensor:
    """Forward noising ``x_t = sqrt(ab) * x0 + sqrt(1 - ab) * eps``.

    Args:
        x0: ``(B, H, A)`` clean actions.
        noise: ``(B, H, A)`` standard Gaussian ``eps``.
        timesteps: ``(B,)`` integer timesteps.
        alphas_cumprod: ``(N,)`` schedule.

    Returns:
        ``(B, H, A)``.
    """
    ab = _alpha_bar_like(alphas_cumprod, timesteps, x0)  # (B, 1, 1)
    return ab.sqrt() * x0 + (1.0 - ab).sqrt() * noise


def diffusion_target(
    x0: torch.Tensor,
    noise: torch.Tensor,
    timesteps: torch.Tensor,
    alphas_cumprod: torch.Tensor,
    prediction_type: str,
) -> torch.Tensor:
    """Regression target for ``prediction_type`` (see module docstring).

    Args:
        x0: ``(B, H, A)`` clean actions.
        noise: ``(B, H, A)`` the ``eps`` used in :func:`q_sample`.
        timesteps: ``(B,)`` integer timesteps.
        alphas_cumprod: ``(N,)`` schedule.
        prediction_type: ``"epsilon"``, ``"v_prediction"`` or ``"sample"``.

    Returns:
        ``(B, H, A)``.
    """
    check_choice("prediction_type", prediction_type, PREDICTION_TYPES)
    if prediction_type == "epsilon":
        return noise
    if prediction_type == "sample":
        return x0
    ab = _alpha_bar_like(alphas_cumprod, timesteps, x0)  # (B, 1, 1)
    return ab.sqrt() * noise - (1.0 - ab).sqrt() * x0  # v_prediction


def predicted_x0(
    model_output: torch.Tensor,
    x_t: torch.Tensor,
    timesteps: torch.Tensor,
    alphas_cumprod: torch.Tensor,
    prediction_type: str,
) -> torch.Tensor:
    """Clean-sample estimate ``(B, H, A)`` implied by a model output (inverse of the targets).

    ``model_output`` ``(B, H, A)`` predicts the ``prediction_type`` target of the noisy
    sample ``x_t`` ``(B, H, A)``; the other arguments are those of :func:`diffusion_target`.
    """
    check_choice("prediction_type", prediction_type, PREDICTION_TYPES)
    ab = _alpha_bar_like(alphas_cumprod, timesteps, x_t)  # (B, 1, 1)
    if prediction_type == "epsilon":
        return (x_t - (1.0 - ab).sqrt() * model_output) / ab.sqrt()
    if prediction_type == "sample":
        return model_output
    return ab.sqrt() * x_t - (1.0 - ab).sqrt() * model_output  # v_prediction
