"""What every navigation policy shares: min-max normalisers kept as buffers (they travel
with the weights), the device it runs on, huggingface_hub's ``save_pretrained`` /
``from_pretrained`` (:mod:`vla_gr.policy.hub`, loading through the factory), the acting
contract (``select_action`` for one env or a vector env, one state per env) and the
LeRobot-shaped interface each agent class fills in (see DESIGN.md "Policy interface")."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import torch
from torch import nn

from vla_gr.agent.observations import as_instructions
from vla_gr.configs.model_schema import ModelConfig
from vla_gr.policy.hub import PolicyHubMixin

__all__ = ["NavigationPolicy", "done_mask", "env_row", "observation_count"]


class NavigationPolicy(nn.Module, PolicyHubMixin):
    """Base of the agent classes; ``config`` is a validated :class:`ModelConfig`.

    ``policy.save_pretrained(folder)`` writes a pretrained folder;
    ``NavigationPolicy.from_pretrained(path)`` loads any agent's folder or checkpoint (a
    subclass refuses another agent's, naming it).

    Subclasses implement ``forward(batch) -> {"loss", ...}``, ``predict_action_chunk(obs)``,
    ``validation_step(batch)`` and the two hooks of :meth:`select_action`: ``_new_env_state()``
    (one env's episode state, an object with ``reset()``) and ``_act(obs, envs)``.
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
        self._env_states: list = []  # one episode state per env, env 0 first
        self._num_envs: int | None = None  # envs acted for since reset(); None: not yet

    def attach_checkpoint(self, loaded) -> None:
        """What the agent takes from its checkpoint folder ``loaded`` (a ``LoadedCheckpoint``)
        besides its weights, once they are loaded; nothing here."""

    def freeze_parts(self) -> None:
        """Stop gradients of the parts ``model.freeze`` names (after the parts are built)."""
        for name in self.config.freeze:
            getattr(self, name).requires_grad_(False)

    @property
    def device(self) -> torch.device:
        """Where the policy's tensors live (its normalisers move with ``.to()``)."""
        return self.action_scale.device

    # ------------------------------------------------------------------ acting
    @torch.no_grad()
    def select_action(self, obs: Mapping, done=None) -> np.ndarray:
        """The action ``env.step`` takes for ``obs``: float32 ``(A,)`` for one env's
        observation (``rgb`` (H, W, 3), as ``env.reset`` / ``env.step`` return it), ``(B, A)``
        for a vector env's (``rgb`` (B, H, W, 3), ``instruction`` B strings).

        The policy keeps one episode state per env (env ``i`` is row ``i``), made at its first
        observation. ``reset()`` starts every env's episode again; a run then keeps its number
        of envs until the next ``reset()``. ``done`` (bool, one per env; None: none) is
        ``terminated | truncated`` of the ``env.step`` that returned ``obs``: under gymnasium's
        next-step autoreset (what ``gymnasium.make_vec`` builds) that ``obs`` row is its
        episode's last, the vector env ignores the row's action and resets the sub-env. The
        policy resets that env's state only and returns zeros (no motion, no STOP) for it; the
        sub-env's next observation starts its new episode, acted on exactly as a lone env's::

            obs, info = envs.reset(seed=0)
            policy.reset()
            done = np.zeros(envs.num_envs, dtype=bool)
            while True:
                obs, reward, terminated, truncated, info = envs.step(
                    policy.select_action(obs, done)
                )
                done = terminated | truncated
        """
        batched, count = observation_count(obs)
        if self._num_envs not in (None, count):
            raise ValueError(
                f"the policy acts for {self._num_envs} env(s) since its last reset(); got "
                f"{count}: call reset() before a run with another number of envs"
            )
        while len(self._env_states) < count:
            self._env_states.append(self._new_env_state())
        ended = done_mask(done, count)  # (B,) bool
        for i in np.flatnonzero(ended):
            self._env_states[i].reset()
        live = np.flatnonzero(~ended)  # (b,) env indices
        actions = np.zeros((count, self.config.action_dim), np.float32)  # (B, A)
        if live.size:
            actions[live] = self._act(obs, live)  # (b, A)
        self._num_envs = count
        return actions if batched else actions[0]

    def reset(self) -> None:
        """New episodes: env 0's state starts again, the other envs' are dropped (made again at
        their first observation), and the number of envs is open."""
        if not self._env_states:
            self._env_states.append(self._new_env_state())
        self._env_states[0].reset()
        del self._env_states[1:]
        self._num_envs = None

    def _new_env_state(self):
        """A new episode state for one env (an object with ``reset()``)."""
        raise NotImplementedError

    def _act(self, obs: Mapping, envs: np.ndarray) -> np.ndarray:
        """One control step of the envs ``envs`` (b,) (rows of ``obs``, single or batched)
        -> their actions float32 ``(b, A)``."""
        raise NotImplementedError

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


def observation_count(obs: Mapping) -> tuple[bool, int]:
    """Whether ``obs`` is a vector env's batch, and how many envs it holds (1 when single)."""
    shape = np.shape(obs["rgb"])
    if len(shape) == 3:
        return False, 1
    if len(shape) != 4:
        raise ValueError(
            f"obs['rgb'] must be (H, W, 3) for one env or (B, H, W, 3) for a vector env; got "
            f"shape {tuple(shape)}"
        )
    return True, int(shape[0])


def env_row(obs: Mapping, index: int) -> dict:
    """Env ``index``'s observation (``rgb`` (H, W, 3), ...) of a vector env's batch ``obs``."""
    count = int(np.shape(obs["rgb"])[0])
    row = {}
    for key, value in obs.items():
        if key == "instruction":
            said = as_instructions(value, "obs['instruction']")
            if len(said) != count:
                raise ValueError(f"{count} observations but {len(said)} instructions")
            row[key] = said[index]
            continue
        value = np.asarray(value)
        if value.ndim == 0 or value.shape[0] != count:
            raise ValueError(
                f"obs[{key!r}] of shape {value.shape} does not hold one row per env ({count})"
            )
        row[key] = value[index]
    return row


def done_mask(done, count: int) -> np.ndarray:
    """``done`` (None, a bool, or one flag per env) as a bool array ``(count,)``."""
    if done is None:
        return np.zeros(count, dtype=bool)
    mask = np.asarray(done, dtype=bool).reshape(-1)  # (B,)
    if mask.shape != (count,):
        raise ValueError(f"done must hold one flag per env ({count}); got shape {np.shape(done)}")
    return mask
