"""``VLAGRPolicy``: the VLA-GR agent, a dual system (``model.agent=dual_system``).

One control step of one env::

    select_action(obs) -> GroundedDualSystem.step
        every plan_every steps: perception.perceive(obs) -> Percept -> Navigator.plan -> plan
        every step:             S1 follower (pure pursuit or the learned S1) -> (v, w, stop)

A vector env's batch runs one ``GroundedDualSystem`` per env (its own map, plan, reading and
follower; the networks are shared), each stepped on its env's row (see
:meth:`NavigationPolicy.select_action` for the contract and autoresets).

Training (``forward``) fits S2's language-grounded goal head (``model.goal_head``,
:mod:`vla_gr.agent.perception`) on the last observation frame of each window against
``goal_mask`` (the instructed instance only; distractors are negatives). The other networks
(room-type classifier, object-category segmenter, instruction reader, learned S1) are
trained by their own stages and loaded from the checkpoint. At inference the perception runs
its networks with ``model.perception.engine`` (PyTorch, or the checkpoint's ONNX export under
ONNX Runtime: :mod:`vla_gr.policy.onnx_export`).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import torch

from vla_gr.agent.dual_system import GroundedDualSystem
from vla_gr.agent.followers import S1Policy
from vla_gr.agent.observations import as_instructions
from vla_gr.agent.perception import (
    GoalHead,
    ObjectCategorySegmenter,
    RoomTypeClassifier,
    goal_head_loss,
    mask_confusion,
)
from vla_gr.agent.perception.engine import Network, not_loaded
from vla_gr.agent.perception.percept import LearnedPerception, Perception
from vla_gr.agent.reading import InstructionReader, Reading
from vla_gr.checkpoint import LoadedCheckpoint
from vla_gr.configs.model_schema import ModelConfig
from vla_gr.policy.base import NavigationPolicy, env_row

__all__ = ["VLAGRPolicy"]


class VLAGRPolicy(NavigationPolicy):
    """The dual-system agent: S2 (perception + GR-field navigator) steering S1."""

    def __init__(self, config: ModelConfig) -> None:
        super().__init__(config)
        c = config
        self.goal_head = GoalHead(c.goal_head)
        self.room_type = RoomTypeClassifier(c.room_type) if c.room_type.enabled else None
        self.object_category = (
            ObjectCategorySegmenter(c.object_category) if c.object_category.enabled else None
        )
        self.instruction_reader = (
            InstructionReader(c.instruction_reader) if c.instruction_reader.enabled else None
        )
        # the learned S1 is built whatever s1.kind says, so one checkpoint serves both kinds
        self.s1 = S1Policy(c.s1)
        self.freeze_parts()
        # what runs each perception network: {} = PyTorch; the ONNX export once loaded
        self._networks: dict[str, Network] = {}
        if c.perception.engine == "onnxruntime":
            self._networks = {name: not_loaded(name) for name in self.perception_networks()}
        self.use_perception(self.learned_perception())

    def perception_networks(self) -> dict[str, torch.nn.Module]:
        """The networks S2's perception runs through ``model.perception.engine``, by name
        (``goal_head``, ``room_type``, ``object_category``: those this agent has)."""
        parts = {
            "goal_head": self.goal_head,
            "room_type": self.room_type,
            "object_category": self.object_category,
        }
        return {name: module for name, module in parts.items() if module is not None}

    def learned_perception(self) -> LearnedPerception:
        """S2's perception from this agent's own networks, run by its engine."""
        return LearnedPerception(
            self.config,
            self.goal_head,
            self.room_type,
            self.object_category,
            self.instruction_reader,
            networks=self._networks,
        )

    def attach_checkpoint(self, loaded: LoadedCheckpoint) -> None:
        """With ``model.perception.engine=onnxruntime``, run the perception networks with
        the ONNX export of checkpoint ``loaded`` (its weights are this agent's): refused when
        the export is missing or stale (:func:`~vla_gr.policy.onnx_export.onnx_networks`)."""
        if self.config.perception.engine == "onnxruntime":
            from vla_gr.policy.onnx_export import onnx_networks

            self._networks = onnx_networks(loaded, self.perception_networks())
            self.use_perception(self.learned_perception())

    def use_perception(self, perception: Perception) -> None:
        """Drive with ``perception`` as S2's (the privileged ablations pass the true mask or
        a gated copy of :meth:`learned_perception`); a new episode starts. The envs of a batch
        after the first drive with ``perception.fork()``."""
        self._env_states = [GroundedDualSystem.from_model_config(perception, self.config, self.s1)]
        self._num_envs = None

    @property
    def dual_system(self) -> GroundedDualSystem:
        """Env 0's dual system (the only one when a single env runs)."""
        return self._env_states[0]

    @property
    def dual_systems(self) -> tuple[GroundedDualSystem, ...]:
        """One dual system per env of the current run, env 0 first."""
        return tuple(self._env_states)

    # ------------------------------------------------------------------ training
    def use_gradient_checkpointing(self, on: bool = True) -> None:
        """Recompute the goal head's stage activations in backward while training
        (``training.gradient_checkpointing``): less memory, the same outputs and gradients."""
        self.goal_head.gradient_checkpointing = bool(on)

    def forward(self, batch: Mapping) -> dict[str, torch.Tensor]:
        """Training loss of the goal head on the last observation frame's ``goal_mask``.

        Returns ``{"loss": scalar, ...}`` (further detached scalars, for logging).
        """
        losses = self.goal_loss(self.goal_outputs(batch))
        return {k: v if k == "loss" else v.detach() for k, v in losses.items()}

    def goal_outputs(self, batch: Mapping) -> dict:
        """The goal head on the last observation frame of each window of ``batch``.

        Returns ``pixel_logits`` (B, H, W), ``visible_logits`` (B,), the ``target`` goal mask
        (B, H, W) bool and, when the batch has them, ``distractors`` (B, H, W) bool; a head
        with a category output adds ``category_logits`` (B, H, W).
        """
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

    def validation_step(self, batch: Mapping) -> tuple[torch.Tensor, dict[str, int]]:
        """The goal head's held-out loss and its pixel / visibility confusion counts."""
        outputs = self.goal_outputs(batch)
        return self.goal_loss(outputs)["loss"].float(), self.goal_confusion(outputs)

    # ------------------------------------------------------------------ inference
    @property
    def perception(self) -> Perception:
        """S2's perception this agent drives with (env 0's)."""
        return self.dual_system.perception

    @property
    def last_timings(self) -> dict[str, float]:
        """Seconds of env 0's last step's parts: ``s1``; on S2 ticks ``s2``,
        ``s2_perception``, ``s2_navigator``."""
        return self.dual_system.last_timings

    def episode_summary(self) -> dict:
        """Env 0's (:attr:`dual_systems` holds every env's)."""
        return self.dual_system.episode_summary()

    @property
    def declared_outcome(self) -> str | None:
        """Env 0's (:attr:`dual_systems` holds every env's)."""
        return self.dual_system.declared_outcome

    @property
    def reading(self) -> Reading | None:
        """Env 0's (:attr:`dual_systems` holds every env's)."""
        return self.dual_system.reading

    def read(self, request: str) -> Reading:
        """How this agent reads ``request``: its fields, confidences, the words it could not
        place, and whether it would act on it (RequestError for a non-str or over-long one)."""
        if self.instruction_reader is not None:
            return self.instruction_reader.read(request)
        from vla_gr.agent.perception.percept import template_reading

        return template_reading(request, self.config)[0]

    def _new_env_state(self) -> GroundedDualSystem:
        """Another env's dual system: the same networks, a perception of its own."""
        return GroundedDualSystem.from_model_config(self.perception.fork(), self.config, self.s1)

    def _act(self, obs: Mapping, envs: np.ndarray) -> np.ndarray:
        """Each env of ``envs`` (b,) steps its own dual system on its row -> ``(b, A)``."""
        batched = np.ndim(obs["rgb"]) == 4
        rows = [env_row(obs, int(i)) if batched else dict(obs) for i in envs]
        steps = [self._env_states[int(i)].step(row) for i, row in zip(envs, rows)]  # b x (A,)
        return np.stack(steps).astype(np.float32)  # (b, A)

    @torch.no_grad()
    def predict_action_chunk(self, obs: Mapping) -> torch.Tensor:
        """The dual system is stateful (its map) and its S1 follower decides one step at a
        time: environment observations in, a chunk of one ``(B, 1, A)`` out (B = 1 for one
        env's observation)."""
        action = torch.from_numpy(self.select_action(obs)).to(self.device)  # (B, A) or (A,)
        return action.reshape(-1, 1, self.config.action_dim)  # (B, 1, A)
