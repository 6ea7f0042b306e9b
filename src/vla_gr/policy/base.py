"""What every navigation policy shares: min-max normalisers kept as buffers (they travel
with the weights), the device it runs on, ``from_pretrained`` through the factory, and the
LeRobot-shaped interface each agent class fills in (see DESIGN.md "Policy interface")."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import torch
from torch import nn

from vla_gr.configs.model_schema import ModelConfig

__all__ = ["NavigationPolicy"]


class NavigationPolicy(nn.Module):
    """Base of the agent classes; ``config`` is a validated :class:`ModelConfig`.

    Subclasses implement ``forward(batch) -> {"loss", ...}``, ``predict_action_chunk(obs)``,
    ``select_action(obs)``, ``reset()`` and ``validation_step(batch)``.
    """

    name = "vla_gr"

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        self.config = config
        # Min-max normalisers (identity until set_normalization); saved with the weights.
        self.register_buffer("action_scale", torch.ones(config.action_dim))
        self.register_buffer("action_offset", torch.zeros(config.action_dim))
        self.register_buffer("pose_scale", torch.ones(3))
        self.register_buffer("pose_offset", torch.zeros(3))

    def freeze_parts(self) -> None:
        """Stop gradients of the parts ``model.freeze`` names (after the parts are built)."""
        for name in self.config.freeze:
            getattr(self, name).requires_grad_(False)

    @property
    def device(self) -> torch.device:
        """Where the policy's tensors live (its normalisers move with ``.to()``)."""
        return self.action_scale.device

    @classmethod
    def from_pretrained(
        cls, path, device: torch.device | str = "cpu", overrides: Sequence[str] = ()
    ) -> NavigationPolicy:
        """This class's agent from checkpoint ``path`` (see
        :func:`vla_gr.policy.factory.load_policy`); a checkpoint of another agent is refused,
        naming it."""
        from vla_gr.policy.factory import load_policy

        return load_policy(path, device=device, overrides=overrides, expected=cls)

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

    # ------------------------------------------------------------------ evaluation hooks
    @property
    def last_timings(self) -> dict[str, float]:
        """Seconds per part of the last decision ({} : the whole decision is one part)."""
        return {}

    def episode_summary(self) -> dict:
        """What the agent concluded this episode, kept in the episode's eval row."""
        return {}

    @property
    def declared_outcome(self) -> str | None:
        """The outcome this agent declared this episode instead of acting on
        (``"not_understood"``, ``"not_found"``; see ``vla_gr.envs.DECLARED_OUTCOMES``);
        None while it acts. Its last action was no STOP: the caller ends the episode with
        ``env.unwrapped.declare(outcome)``."""
        return None

    @property
    def reading(self):
        """How the agent read this episode's request (a ``Reading``), None before its first
        step or for an agent that reads no request into fields."""
        return None

    def validation_step(self, batch: Mapping) -> tuple[torch.Tensor, dict[str, int]]:
        """Held-out loss (scalar) of ``batch`` and confusion counts to sum over batches."""
        return self(batch)["loss"].float(), {}
