"""``VLAGRPolicy``: the navigation agent, end to end or as a dual system (``model.agent``).

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
blocks, then decoded by the action head (``model.head``); that is ``model.agent=end_to_end``.

``model.agent=dual_system`` builds S2's language-grounded goal head (``model.goal_head``,
:mod:`vla_gr.core.grounding`) and trains it on the last observation frame of each window
against ``goal_mask`` (the instructed instance only; distractors are negatives). Its
inference (S2 on the GR field, S1) is ``_dual_system_step``.
"""

from __future__ import annotations

import re
from collections import deque
from collections.abc import Mapping, Sequence

import numpy as np
import torch
from torch import nn
from torch.utils.checkpoint import checkpoint

from vla_gr.checkpoint import load_model_state, read_checkpoint
from vla_gr.configs.model_schema import ModelConfig
from vla_gr.core.diffusion_policy import DiffusionPolicy
from vla_gr.core.dual_system import S1Policy
from vla_gr.core.encoders import PoseEncoder, RGBDEncoder, build_text_encoder, pose_features
from vla_gr.core.grounding import (
    GoalHead,
    InstructionLexicon,
    InstructionReader,
    ObjectCategorySegmenter,
    ObjectEvidence,
    Reading,
    RoomTypeClassifier,
    category_match,
    goal_head_loss,
    mask_confusion,
    read_instruction,
)
from vla_gr.core.trajectory_attention import TransformerBlock
from vla_gr.errors import ConfigError
from vla_gr.policy.dual_system import GroundedDualSystem
from vla_gr.policy.frames import apply_peft, as_instructions, env_obs_to_frame

__all__ = ["VLAGRPolicy"]

_OBS_KEYS = ("rgb", "depth", "pose")
#: Model settings a loaded checkpoint may change (no weight depends on them): the planner,
#: its GR field, which S1 drives and how it samples, the follower, the S2 schedule and
#: the goal head's inference options (category gate, test-time flip) and the segmenter's
#: relation candidates.
INFERENCE_SETTINGS = (
    "navigator.",
    "pursuit.",
    "gr_field.",
    "instruction_lexicon.",
    "dual_system.planning_frequency_hz",
    "goal_head.category_gate",
    "goal_head.test_time_flip",
    "object_category.relation_candidates",
    "object_category.anchor_not_goal",
    "s1.kind",
    "s1.use_s2",
    "s1.depth_guard",
    "s1.stop_threshold",
    "s1.n_action_steps",
    "s1.head.num_inference_steps",
    "s1.head.sampler",
)


class VLAGRPolicy(nn.Module):
    """The agent; ``config`` is a validated :class:`ModelConfig`."""

    name = "vla_gr"

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        self.config = c = config
        self.last_timings: dict[str, float] = {}  # seconds per part of the last decision
        if c.agent == "dual_system":
            self._build_dual_system(c)
        else:
            self._build_end_to_end(c)
        # Min-max normalisers (identity until set_normalization); saved with the weights.
        self.register_buffer("action_scale", torch.ones(c.action_dim))
        self.register_buffer("action_offset", torch.zeros(c.action_dim))
        self.register_buffer("pose_scale", torch.ones(3))
        self.register_buffer("pose_offset", torch.zeros(3))
        for name in c.freeze:
            getattr(self, name).requires_grad_(False)
        self.reset()

    def _build_end_to_end(self, c: ModelConfig) -> None:
        """Encoders -> fusion transformer -> action head."""
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

    @property
    def has_goal_head(self) -> bool:
        return self.config.agent == "dual_system"

    @classmethod
    def from_pretrained(
        cls, path, device: torch.device | str = "cpu", overrides: Sequence[str] = ()
    ) -> VLAGRPolicy:
        """Load a training checkpoint folder (``<run>/checkpoints/best``), verified.

        The model config comes from the checkpoint's ``config.yaml`` (PEFT layers are
        re-applied before the weights are loaded); the weights are ``model.safetensors``
        (the EMA averages when training used EMA). Returned in eval mode. ``overrides``
        (``"navigator.confirm_ticks=3"``, ...) change settings that no weight depends on:
        keys under ``model.`` in :data:`INFERENCE_SETTINGS`.
        """
        from omegaconf import OmegaConf

        loaded = read_checkpoint(path)
        saved = OmegaConf.create(loaded.config_yaml)
        if "model" not in saved:
            raise ValueError(f"checkpoint {path}: config.yaml has no model section")
        for item in overrides:
            key = item.split("=", 1)[0].strip()
            if "=" not in item or not key.startswith(INFERENCE_SETTINGS):
                raise ConfigError(
                    f"checkpoint override {item!r} must be key=value with a key under "
                    f"{', '.join(INFERENCE_SETTINGS)} (settings no weight depends on)"
                )
        schema = OmegaConf.structured(ModelConfig)
        merged = OmegaConf.merge(schema, saved.model, OmegaConf.from_dotlist(list(overrides)))
        config = OmegaConf.to_object(merged)
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
        """Training loss: the action head's on ``action`` (B, horizon, A) raw (end to end), or
        the goal head's on the last observation frame's ``goal_mask`` (dual system).

        Returns ``{"loss": scalar, ...}`` (further detached scalars, for logging).
        """
        if self.has_goal_head:
            losses = self.goal_loss(self.goal_outputs(batch))
            return {k: v if k == "loss" else v.detach() for k, v in losses.items()}
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

    # ------------------------------------------------------------------ goal head (S2)
    def goal_outputs(self, batch: Mapping) -> dict:
        """The goal head on the last observation frame of each window of ``batch``.

        Returns ``pixel_logits`` (B, H, W), ``visible_logits`` (B,), the ``target`` goal mask
        (B, H, W) bool and, when the batch has them, ``distractors`` (B, H, W) bool; a head
        with a category output adds ``category_logits`` (B, H, W).
        """
        if not self.has_goal_head:
            raise RuntimeError("this agent has no goal head (model.agent=end_to_end)")
        rgb, depth = batch["rgb"], batch["depth"]  # (B, T, 3, H, W), (B, T, 1, H, W)
        if rgb.dim() != 5 or depth.dim() != 5:
            raise ValueError(
                f"batch['rgb'] / ['depth'] must be (B, T, C, H, W); got {tuple(rgb.shape)} / "
                f"{tuple(depth.shape)}"
            )
        if "goal_mask" not in batch:
            raise ValueError("training the goal head needs batch['goal_mask'] (B, T, 1, H, W)")
        instructions = as_instructions(batch["instruction"], "batch['instruction']")
        out = dict(self.goal_head(rgb[:, -1], depth[:, -1], instructions))
        out["target"] = batch["goal_mask"][:, -1, 0].bool()  # (B, H, W)
        if "distractor_mask" in batch:
            out["distractors"] = batch["distractor_mask"][:, -1, 0].bool()  # (B, H, W)
        elif "category_logits" in out:
            raise ValueError(
                "model.goal_head.category_head needs batch['distractor_mask'] (its target is the "
                "goal mask | the distractor mask); collect the store again to record it"
            )
        return out

    def goal_loss(self, outputs: Mapping) -> dict[str, torch.Tensor]:
        """``goal_head_loss`` of :meth:`goal_outputs` with ``model.grounding``'s weights."""
        g = self.config.grounding
        category = outputs.get("category_logits")  # (B, H, W) or None
        category_target = None  # (B, H, W) bool: every instance of the instructed category
        if category is not None:
            category, category_target = category.float(), outputs["target"] | outputs["distractors"]
        return goal_head_loss(
            outputs["pixel_logits"].float(),
            outputs["visible_logits"].float(),
            outputs["target"],
            min_pixels=g.min_pixels,
            pos_weight=g.pos_weight,
            dice_weight=g.dice_weight,
            visible_weight=g.visible_weight,
            category_logits=category,
            category_target=category_target,
            category_weight=g.category_weight,
        )

    def goal_confusion(self, outputs: Mapping) -> dict[str, int]:
        """``mask_confusion`` counts of :meth:`goal_outputs` (``model.grounding`` thresholds)."""
        g = self.config.grounding
        return mask_confusion(
            self.goal_head.pixel_probability(outputs),
            torch.sigmoid(outputs["visible_logits"].float()),
            outputs["target"],
            threshold=g.threshold,
            min_pixels=g.min_pixels,
            distractors=outputs.get("distractors"),
        )

    # ------------------------------------------------------------------ inference
    def _build_dual_system(self, c: ModelConfig) -> None:
        """S2's goal head (and, with ``room_type.enabled``, ``object_category.enabled`` and
        ``instruction_reader.enabled``, its room-type classifier, object-category segmenter
        and instruction reader; with ``instruction_lexicon.enabled``, the lexicon that says the
        instruction in template words before S2 reads it) + the navigator on the GR field; S1
        (the learned network is built whatever ``s1.kind`` says, so that one checkpoint
        serves both S1 kinds)."""
        self.goal_head = GoalHead(c.goal_head)
        self.room_type = RoomTypeClassifier(c.room_type) if c.room_type.enabled else None
        self.object_category = (
            ObjectCategorySegmenter(c.object_category) if c.object_category.enabled else None
        )
        self.instruction_reader = (
            InstructionReader(c.instruction_reader) if c.instruction_reader.enabled else None
        )
        self.instruction_lexicon = (
            InstructionLexicon(c.instruction_lexicon) if c.instruction_lexicon.enabled else None
        )
        self._segmented: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._readings: dict[str, tuple[Reading, bool]] = {}  # instruction -> read, has colour
        self.s1 = S1Policy(c.s1)
        self.dual_system = GroundedDualSystem.from_model_config(
            self.goal_likelihood,
            c,
            self.s1,
            room_match=self.room_match if self.room_type is not None else None,
            object_evidence=self.object_evidence if self.object_category is not None else None,
        )

    @torch.no_grad()
    def goal_likelihood(self, obs: Mapping) -> tuple[np.ndarray, float]:
        """S2's perception: (H, W) probability that each pixel shows the instructed object,
        and the probability that it is in view at all.

        ``obs`` is one environment observation (``rgb`` (H, W, 3), ``depth`` (H, W, 1),
        ``instruction`` str); a leading batch of one is accepted.
        """
        frame = env_obs_to_frame(obs, device=self.action_scale.device)
        if frame["rgb"].shape[0] != 1:
            raise ValueError(
                f"the dual system runs at batch 1; got {frame['rgb'].shape[0]} observations"
            )
        pixels, visible = self.goal_head.likelihood(
            frame["rgb"], frame["depth"], frame["instruction"]
        )  # (1, H, W), (1,)
        self.last_goal_visible = float(visible[0])
        likelihood = pixels[0].float().cpu().numpy()  # (H, W)
        candidate = self._relation_candidate(obs)
        if candidate is not None:  # the instructed category's pixels are candidates too
            likelihood = np.maximum(likelihood, self._segment(obs)[candidate])  # (H, W)
        anchor = self._anchor_to_exclude(obs)
        if anchor is not None:  # the anchor's pixels are not the goal's
            anchor_pixels = self._segment(obs)[anchor] >= self.config.navigator.pixel_threshold
            likelihood = np.where(anchor_pixels, 0.0, likelihood).astype(np.float32)  # (H, W)
        return likelihood, self.last_goal_visible

    def _anchor_to_exclude(self, obs: Mapping) -> int | None:
        """The segmenter class of the relation's anchor when its pixels are kept out of the
        goal likelihood (``object_category.anchor_not_goal``), else None."""
        if self.object_category is None or not self.config.object_category.anchor_not_goal:
            return None
        reading = self._read_obs(obs)[0]
        return reading.anchor if reading.anchor != reading.category else None

    def _relation_candidate(self, obs: Mapping) -> int | None:
        """The segmenter class whose pixels are goal candidates (``relation_candidates``: an
        instruction naming a category and a relation's anchor but no colour), else None."""
        if self.object_category is None or not self.config.object_category.relation_candidates:
            return None
        reading, has_colour = self._read_obs(obs)
        if reading.category is None or reading.anchor is None or has_colour:
            return None
        return reading.category

    def _segment(self, obs: Mapping) -> np.ndarray:
        """The segmenter's probabilities (1 + K, H, W) of this observation's frame, computed
        once per frame (the goal likelihood and the object checks both read them)."""
        rgb, depth = np.asarray(obs["rgb"]), np.asarray(obs["depth"])
        cached = self._segmented  # (rgb, depth, probabilities) of the last frame segmented
        if (
            cached is not None
            and np.array_equal(cached[0], rgb)
            and np.array_equal(cached[1], depth)
        ):
            return cached[2]
        frame = env_obs_to_frame(obs, device=self.action_scale.device)
        probs = self.object_category.probabilities(frame["rgb"], frame["depth"])[0]
        self._segmented = (rgb.copy(), depth.copy(), probs.cpu().numpy())  # (1 + K, H, W)
        return self._segmented[2]

    def read_instruction(self, instruction: str) -> Reading:
        """What the checks take ``instruction`` to name (:func:`read_instruction`: template
        words, then the instruction reader when the agent has one); read once per episode."""
        return self._read(instruction)[0]

    def _read_obs(self, obs: Mapping) -> tuple[Reading, bool]:
        """:meth:`_read` of the instruction of one observation ``obs``."""
        return self._read(as_instructions(obs["instruction"], "obs['instruction']")[0])

    def _read(self, instruction: str) -> tuple[Reading, bool]:
        """(:meth:`read_instruction`, whether ``instruction`` says a colour word), computed at
        the first S2 tick that asks and kept until :meth:`reset`: the instruction is fixed for
        an episode, and every check reads it on every tick."""
        if instruction not in self._readings:
            reading = read_instruction(
                instruction,
                self.config.object_category.categories,
                self.config.room_type.room_types,
                self.instruction_reader,
            )
            words = set(re.findall(r"[a-z]+", instruction.lower()))
            colours = words & set(self.config.instruction_lexicon.colors)
            self._readings[instruction] = (reading, bool(colours))
        return self._readings[instruction]

    @torch.no_grad()
    def room_match(self, obs: Mapping) -> float:
        """S2's room check: the probability that the robot is in a room of the type the
        instruction names; 1 when it names none (or the agent has no room classifier)."""
        index = self._read_obs(obs)[0].room
        if index is None or self.room_type is None:
            return 1.0
        frame = env_obs_to_frame(obs, device=self.action_scale.device)
        probs = self.room_type.probabilities(frame["rgb"], frame["depth"])  # (1, R)
        return float(probs[0, index])

    @torch.no_grad()
    def object_evidence(self, obs: Mapping, likelihood: np.ndarray) -> ObjectEvidence:
        """S2's object checks on one frame (:class:`ObjectEvidence`): the mean probability
        that the pixels ``likelihood`` (H, W) marks (``navigator.pixel_threshold``) show the
        category the instruction names (None when too few are marked or it names no known
        category), and the per-pixel probability of a relation's anchor (None without one).
        Both None when the agent has no segmenter."""
        if self.object_category is None:
            return ObjectEvidence()
        c = self.config.object_category
        reading = self._read_obs(obs)[0]
        index, anchor = reading.category, reading.anchor
        goal = np.asarray(likelihood) >= self.config.navigator.pixel_threshold  # (H, W)
        if index is not None and int(goal.sum()) < c.min_goal_pixels:
            index = None
        if index is None and anchor is None:
            return ObjectEvidence()
        probs = self._segment(obs)  # (1 + K, H, W)
        return ObjectEvidence(
            None if index is None else category_match(probs, goal, index, c.min_goal_pixels),
            None if anchor is None else probs[anchor],
        )

    def as_s2_reads(self, obs: Mapping) -> Mapping:
        """One observation with its instruction as S2 reads it: in template words when the
        agent has an instruction lexicon (a copy; kept in ``read_as``), else ``obs`` itself."""
        if self.instruction_lexicon is None:
            return obs
        said = as_instructions(obs["instruction"], "obs['instruction']")[0]
        self.read_as = self.instruction_lexicon.canonical(said)
        return {**obs, "instruction": self.read_as}

    def _dual_system_step(self, obs: Mapping) -> torch.Tensor:
        """One control step of the dual system (S2 every ``plan_every`` steps, S1 every step;
        see :mod:`vla_gr.policy.dual_system`) -> action (1, A)."""
        action = self.dual_system.step(self.as_s2_reads(_single_observation(obs)))  # (A,)
        self.last_timings = self.dual_system.last_timings
        return torch.from_numpy(action).to(self.action_scale.device)[None]  # (1, A)

    @torch.no_grad()
    def predict_action_chunk(self, obs: Mapping) -> torch.Tensor:
        """Raw actions ``(B, horizon, A)`` in ``[-1, 1]`` for a batch of observation histories.

        The dual system is stateful (its map) and its S1 follower decides one step at a time:
        it takes one environment observation and returns a chunk of one, ``(1, 1, A)``.
        """
        if self.has_goal_head:
            return self._dual_system_step(obs)[:, None]  # (1, 1, A)
        context = self.encode_observations(obs)  # (B, S, D)
        chunk = self.head.get_action(context)  # (B, H, A), sampler and steps from model.head
        return self.unnormalize_action(chunk).clamp(-1.0, 1.0)  # (B, H, A)

    def reset(self) -> None:
        """Forget the observation history and the queued actions (call at episode start)."""
        self._obs_queue: deque[dict] = deque(maxlen=self.config.n_obs_steps)
        self._action_queue: deque[torch.Tensor] = deque(maxlen=self.config.n_action_steps)
        self.read_as: str | None = None  # this episode's instruction as the lexicon said it
        if self.has_goal_head:
            self._readings.clear()
            self.dual_system.reset()

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
        if self.has_goal_head:
            return self._dual_system_step(obs)
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


def _single_observation(obs: Mapping) -> dict:
    """One env observation (``rgb`` (H, W, 3), ...) from one with an optional batch of 1."""
    rgb = np.asarray(obs["rgb"])
    if rgb.ndim == 3:
        return dict(obs)
    if rgb.ndim != 4 or rgb.shape[0] != 1:
        raise ValueError(
            f"the dual system runs at batch 1; got obs['rgb'] of shape {tuple(rgb.shape)}"
        )
    single = {k: np.asarray(obs[k])[0] for k in _OBS_KEYS}
    single["instruction"] = as_instructions(obs["instruction"], "obs['instruction']")[0]
    return single
