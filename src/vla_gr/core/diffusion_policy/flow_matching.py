"""Flow-matching maths (pure functions), following openpi's pi0 convention.

Convention (openpi / LeRobot pi0 code): time ``t`` runs from data (``t = 0``) to
noise (``t = 1``) along the straight path

    x_t = t * noise + (1 - t) * actions,        u_t = d x_t / d t = noise - actions,

and the network regresses ``u_t``. Sampling integrates ``dx/dt = v(x, t)`` from
``t = 1`` (pure noise) down to ``t = 0`` with Euler or midpoint steps of size
``-1/N``.

Training times follow pi0: ``t = eps + (1 - eps) * u`` with ``u ~ Beta(1.5, 1)`` and
``eps = 0.001`` (i.e. ``s = 0.999``), which puts more weight on noisy times (``t``
near 1). This is the paper's ``p(tau) = Beta((s - tau) / s; 1.5, 1)`` written for
``t = 1 - tau``. ``Beta(a, 1)`` has CDF ``u**a``, so it is sampled exactly by inverse
CDF ``U ** (1/a)`` from a uniform ``U``, which keeps a ``torch.Generator`` usable.

Next in the data flow: :mod:`vla_gr.core.diffusion_policy.head` (training and sampling use it).
"""

from __future__ import annotations

from collections.abc import Callable

import torch

from vla_gr.core.diffusion_policy.config import FLOW_SAMPLERS
from vla_gr.validation import check_choice

__all__ = [
    "sample_flow_time",
    "flow_interpolate",
    "flow_target",
    "flow_x0_from_velocity",
    "euler_step",
    "midpoint_step",
    "integrate_flow",
    "flow_time_grid",
]


def sample_flow_time(
    batch_size: int,
    alpha: float = 1.5,
    beta: float = 1.0,
    s: float = 0.999,
    generator: torch.Generator | None = None,
    device: torch.device | str | None = None,
) -> torch.Tensor:
    """Sample training times ``t = (1 - s) + s * u``, ``u ~ Beta(alpha, beta)``.

    Args:
        batch_size: number of times ``B``.
        alpha: first Beta parameter (1.5 in pi0).
        beta: second Beta parameter (1.0 in pi0; only ``beta == 1`` can use a generator,
            other values fall back to ``torch.distributions.Beta``).
        s: scale so that ``t`` stays in ``[1 - s, 1]`` (0.999 in pi0).
        generator: optional RNG for reproducibility.
        device: output device.

    Returns:
        ``(B,)`` float32 times in ``[1 - s, 1]``.
    """
    if alpha <= 0 or beta <= 0:
        raise ValueError(f"alpha={alpha} and beta={beta} must be > 0")
    if not 0.0 < s <= 1.0:
        raise ValueError(f"s={s} must be in (0, 1]")
    if beta == 1.0:
        uni = torch.rand(batch_size, generator=generator, device=device)  # (B,)
        u = uni.pow(1.0 / alpha)  # (B,) inverse CDF of Beta(alpha, 1)
    else:
        dist = torch.distributions.Beta(torch.tensor(float(alpha)), torch.tensor(float(beta)))
        u = dist.sample((batch_size,)).to(device)  # (B,)
    return (1.0 - s) + s * u  # (B,)


def flow_interpolate(actions: torch.Tensor, noise: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """Point ``x_t = t * noise + (1 - t) * actions`` on the straight path.

    Args:
        actions: ``(B, H, A)`` clean actions (``t = 0``).
        noise: ``(B, H, A)`` Gaussian noise (``t = 1``).
        t: ``(B,)`` times in ``[0, 1]``.

    Returns:
        ``(B, H, A)``.
    """
    tt = t.view(-1, *([1] * (actions.dim() - 1))).to(actions.dtype)  # (B, 1, 1)
    return tt * noise + (1.0 - tt) * actions  # (B, H, A)


def flow_target(actions: torch.Tensor, noise: torch.Tensor) -> torch.Tensor:
    """Target velocity ``u = noise - actions`` (constant along the path).

    Args:
        actions: ``(B, H, A)``.
        noise: ``(B, H, A)``.

    Returns:
        ``(B, H, A)``.
    """
    return noise - actions


def flow_x0_from_velocity(
    x_t: torch.Tensor, velocity: torch.Tensor, t: torch.Tensor
) -> torch.Tensor:
    """Clean-action estimate ``x_0 = x_t - t * v`` implied by a velocity.

    Args:
        x_t: ``(B, H, A)`` noisy actions.
        velocity: ``(B, H, A)`` predicted velocity.
        t: ``(B,)`` times.

    Returns:
        ``(B, H, A)``.
    """
    tt = t.view(-1, *([1] * (x_t.dim() - 1))).to(x_t.dtype)  # (B, 1, 1)
    return x_t - tt * velocity


def flow_time_grid(num_steps: int, device: torch.device | str | None = None) -> torch.Tensor:
    """Integration times ``1, 1 - 1/N, ..., 0`` (``N + 1`` values, decreasing).

    Args:
        num_steps: number of steps ``N >= 1``.
        device: output device.

    Returns:
        ``(N + 1,)`` float32.
    """
    if not isinstance(num_steps, int) or num_steps < 1:
        raise ValueError(f"num_steps={num_steps!r} must be an int >= 1")
    return torch.linspace(1.0, 0.0, num_steps + 1, device=device)  # (N + 1,)


def euler_step(x: torch.Tensor, velocity: torch.Tensor, dt: float | torch.Tensor) -> torch.Tensor:
    """One explicit Euler step ``x + dt * v``.

    Args:
        x: ``(B, H, A)`` state.
        velocity: ``(B, H, A)`` velocity at ``(x, t)``.
        dt: signed step (negative when integrating towards ``t = 0``).

    Returns:
        ``(B, H, A)``.
    """
    return x + dt * velocity


def midpoint_step(
    x: torch.Tensor,
    t: torch.Tensor,
    dt: torch.Tensor,
    velocity_fn: Callable[[torch.Tensor, torch.Tensor], torch.Tensor],
) -> torch.Tensor:
    """One explicit midpoint (RK2) step ``x + dt * v(x + dt/2 * v(x, t), t + dt/2)``.

    Args:
        x: ``(B, H, A)`` state at time ``t``.
        t: scalar time tensor.
        dt: scalar signed step.
        velocity_fn: ``(x (B, H, A), t scalar) -> (B, H, A)``.

    Returns:
        ``(B, H, A)``.
    """
    half = x + 0.5 * dt * velocity_fn(x, t)  # (B, H, A)
    return x + dt * velocity_fn(half, t + 0.5 * dt)


def integrate_flow(
    velocity_fn: Callable[[torch.Tensor, torch.Tensor], torch.Tensor],
    x_init: torch.Tensor,
    num_steps: int = 10,
    method: str = "euler",
) -> torch.Tensor:
    """Integrate ``dx/dt = v(x, t)`` from ``t = 1`` (noise) to ``t = 0`` (actions).

    Args:
        velocity_fn: ``(x (B, H, A), t scalar tensor) -> (B, H, A)``.
        x_init: ``(B, H, A)`` state at ``t = 1`` (Gaussian noise when sampling).
        num_steps: number of steps ``N`` (``N`` evaluations for Euler, ``2N`` for midpoint).
        method: ``"euler"`` or ``"midpoint"``.

    Returns:
        ``(B, H, A)`` state at ``t = 0``.
    """
    check_choice("method", method, FLOW_SAMPLERS)
    times = flow_time_grid(num_steps, x_init.device)  # (N + 1,)
    dt = times[1] - times[0]  # scalar, = -1/N
    x = x_init
    for i in range(num_steps):
        t = times[i]
        if method == "euler":
            x = euler_step(x, velocity_fn(x, t), dt)  # (B, H, A)
        else:
            x = midpoint_step(x, t, dt, velocity_fn)  # (B, H, A)
    return x
