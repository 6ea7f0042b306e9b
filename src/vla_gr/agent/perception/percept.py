"""S2's perception: one observation in, one typed :class:`Percept` out, once per S2 tick.

A perception reads the instruction once per episode, converts the frame once per tick and
asks each of its networks once: the goal likelihood (pixels of THE instance the instruction
means), the room check, the object checks and the relation's anchor. The navigator receives
the percept; nothing calls back into the policy.

- :class:`LearnedPerception`: the agent's own (instruction reader, goal head, room-type
  classifier and object-category segmenter of a ``VLAGRPolicy``);
  :meth:`LearnedPerception.gated` multiplies its goal likelihood by a pixel gate.
- :class:`TrueMaskPerception`: privileged, the true goal instance's mask (the planner's
  ceiling); :class:`TrueCategoryGate`: privileged, the pixels of the goal's category.
"""

from __future__ import annotations

import copy as _copy
import dataclasses
import re
from collections.abc import Callable, Mapping
from typing import Protocol

import numpy as np
import torch

from vla_gr.agent.observations import as_instructions, env_obs_to_frame
from vla_gr.agent.perception.engine import Network
from vla_gr.agent.perception.goal_head import GoalHead
from vla_gr.agent.perception.object_category import (
    ObjectCategorySegmenter,
    category_match,
    instructed_anchor,
    instructed_category,
)
from vla_gr.agent.perception.room_type import RoomTypeClassifier, instructed_room
from vla_gr.agent.reading import InstructionReader, Reading

__all__ = ["LearnedPerception", "Percept", "Perception", "TrueCategoryGate", "TrueMaskPerception"]


@dataclasses.dataclass(frozen=True)
class Percept:
    """What S2 perceived on one tick.

    ``likelihood`` (H, W) float32 in [0, 1]: probability that each pixel shows the instructed
    instance; ``visible``: probability that it is in view at all; ``room_match``: probability
    that the robot stands in the room the instruction names (1 when it names none or nothing
    checks it); ``category_match``: probability that the likely goal pixels show the
    instructed category (None: no evidence); ``anchor`` (H, W) or None: per-pixel probability
    of a relation's anchor category; ``room_probs`` (R,) or None: probabilities of the type of
    room the robot stands in (asked for by the navigator's ``room_search``).
    """

    likelihood: np.ndarray
    visible: float = 1.0
    room_match: float = 1.0
    category_match: float | None = None
    anchor: np.ndarray | None = None
    room_probs: np.ndarray | None = None


class Perception(Protocol):
    """What the dual system needs of a perception."""

    def reset(self) -> None:
        """New episode: forget the reading of the last instruction."""

    def read(self, instruction: str) -> Reading | None:
        """How it reads ``instruction`` (None: it reads no instruction, e.g. the true mask)."""

    def perceive(self, obs: Mapping) -> Percept:
        """One S2 tick on one environment observation (``rgb`` (H, W, 3), ``depth``
        (H, W, 1), ``pose`` (3,), ``instruction``)."""

    def fork(self) -> Perception:
        """The same perception with an episode state of its own, for another env of a batch
        (ValueError for one that reads a single env's ground truth)."""


#: ``obs -> (H, W) bool``: pixels a gated perception keeps in its goal likelihood.
PixelGate = Callable[[Mapping], np.ndarray]


@dataclasses.dataclass
class _EpisodeReading:
    """An episode's request as said, its reading, the words the goal head reads and the
    checks' class indices (category and anchor 1-based, room 0-based; None: not named)."""

    said: str
    reading: Reading
    phrase: str
    category: int | None
    anchor: int | None
    room: int | None


class LearnedPerception:
    """The agent's S2 perception, built from the networks of a ``VLAGRPolicy``.

    Args:
        config: the agent's ``ModelConfig`` (``object_category``, ``room_type`` and
            ``navigator.confirmation.pixel_threshold`` are read).
        goal_head: the language-grounded goal head.
        room_type, object_category: optional checks (None: the check passes).
        reader: the instruction reader (None: the template words are read exactly, and the
            goal head reads the request as said).
        gate: optional privileged pixel gate multiplied into the goal likelihood.
        networks: what runs each network's ``network`` by name (``goal_head``, ``room_type``,
            ``object_category``: an inference engine's, :mod:`.engine`); a name absent: the
            module itself (PyTorch).
    """

    def __init__(
        self,
        config,
        goal_head: GoalHead,
        room_type: RoomTypeClassifier | None = None,
        object_category: ObjectCategorySegmenter | None = None,
        reader: InstructionReader | None = None,
        gate: PixelGate | None = None,
        networks: Mapping[str, Network] | None = None,
    ) -> None:
        self.config = config
        self.goal_head = goal_head
        self.room_type = room_type
        self.object_category = object_category
        self.reader = reader
        self.gate = gate
        self.networks = dict(networks or {})
        self._episode: _EpisodeReading | None = None

    def gated(self, gate: PixelGate) -> LearnedPerception:
        """The same networks, with the goal likelihood multiplied by ``gate(obs)``."""
        copy = _copy.copy(self)
        copy.gate, copy._episode = gate, None
        return copy

    def fork(self) -> LearnedPerception:
        """The same networks with a reading of their own (ValueError when gated: a gate reads
        one env's ground truth)."""
        if self.gate is not None:
            raise ValueError("a gated perception reads one env's ground truth: it drives one env")
        copy = _copy.copy(self)
        copy._episode = None
        return copy

    @property
    def device(self) -> torch.device:
        """Where the networks run: the goal head's parameters' device (they move together)."""
        return next(self.goal_head.parameters()).device

    def reset(self) -> None:
        self._episode = None

    def read(self, instruction: str) -> Reading:
        """The reading of ``instruction`` (the reader's, or the template words')."""
        return self._read(instruction).reading

    def _read(self, said: str) -> _EpisodeReading:
        """The reading of ``said``, made at the first tick of an episode and kept."""
        if self._episode is None or self._episode.said != said:
            if self.reader is not None:
                reading = self.reader.read(said)
                indices = self.reader.indices(reading)
                phrase = reading.phrase
            else:
                reading, indices = template_reading(said, self.config)
                phrase = said
            self._episode = _EpisodeReading(said, reading, phrase, *indices)
        return self._episode

    @torch.no_grad()
    def perceive(self, obs: Mapping) -> Percept:
        said = as_instructions(obs["instruction"], "obs['instruction']")
        if len(said) != 1 or np.asarray(obs["rgb"]).ndim != 3:
            raise ValueError(
                f"S2 perceives one observation at a time; got obs['rgb'] of shape "
                f"{np.asarray(obs['rgb']).shape}"
            )
        episode = self._read(said[0])
        if not episode.reading.understood:
            raise ValueError(
                f"S2 does not act on a request it did not understand: {episode.reading.reason}"
            )
        frame = env_obs_to_frame({**obs, "instruction": episode.phrase}, device=self.device)
        networks = self.networks
        pixels, visible = self.goal_head.likelihood(
            frame["rgb"], frame["depth"], frame["instruction"], networks.get("goal_head")
        )  # (1, H, W), (1,)
        likelihood = pixels[0].float().cpu().numpy()  # (H, W)
        segmented: list[np.ndarray] = []  # the segmenter's (1 + K, H, W), once per tick

        def segment() -> np.ndarray:
            if not segmented:
                probs = self.object_category.probabilities(
                    frame["rgb"], frame["depth"], networks.get("object_category")
                )[0]
                segmented.append(probs.cpu().numpy())  # (1 + K, H, W)
            return segmented[0]

        oc = self.config.object_category
        threshold = self.config.navigator.confirmation.pixel_threshold
        with_segmenter = self.object_category is not None
        is_relation = episode.category is not None and episode.anchor is not None
        has_colour = episode.reading.color is not None
        if with_segmenter and oc.relation_candidates and is_relation and not has_colour:
            # a relation without a colour: every pixel of the category is a candidate
            likelihood = np.maximum(likelihood, segment()[episode.category])  # (H, W)
        excluded = episode.anchor is not None and episode.anchor != episode.category
        if with_segmenter and oc.anchor_not_goal and excluded:  # anchor pixels are not goal's
            anchor_pixels = segment()[episode.anchor] >= threshold  # (H, W)
            likelihood = np.where(anchor_pixels, 0.0, likelihood).astype(np.float32)  # (H, W)
        if self.gate is not None:
            likelihood = likelihood * self.gate(obs)  # (H, W)
        likelihood = np.asarray(likelihood, dtype=np.float32)  # (H, W)
        depth_shape = np.asarray(obs["depth"]).shape[:2]
        if likelihood.shape != depth_shape:
            raise ValueError(
                f"goal likelihood has shape {likelihood.shape}, expected {depth_shape}"
            )

        room_match, room_probs = 1.0, None
        wanted = episode.room is not None or self.config.navigator.room_search.enabled
        if self.room_type is not None and wanted:
            probs = self.room_type.probabilities(
                frame["rgb"], frame["depth"], networks.get("room_type")
            )  # (1, R)
            room_probs = probs[0].float().cpu().numpy()  # (R,)
            if episode.room is not None:
                room_match = float(room_probs[episode.room])

        match, anchor = None, None
        if with_segmenter:
            index = episode.category
            goal = likelihood >= threshold  # (H, W)
            if index is not None and int(goal.sum()) < oc.min_goal_pixels:
                index = None
            if index is not None:
                match = category_match(segment(), goal, index, oc.min_goal_pixels)
            if episode.anchor is not None:
                anchor = segment()[episode.anchor]  # (H, W)
        return Percept(likelihood, float(visible[0]), room_match, match, anchor, room_probs)


class TrueMaskPerception:
    """Privileged: the TRUE goal mask as S2's likelihood (needs the env's ``semantic``
    observation), no room or object checks; the planner's ceiling."""

    def __init__(self, env) -> None:
        self.env = env

    def reset(self) -> None:
        pass

    def read(self, instruction: str) -> None:
        """It reads no request: the true goal is the env's."""
        return None

    def fork(self) -> TrueMaskPerception:
        raise ValueError("the true-mask perception reads one env's goal: it drives one env")

    def perceive(self, obs: Mapping) -> Percept:
        goal = int(self.env.unwrapped.goal.instance_id)
        return Percept((semantic_of(obs, "true_mask") == goal).astype(np.float32))  # (H, W)


class TrueCategoryGate:
    """Privileged pixel gate: the pixels that show an object of the goal's category (from
    the env's ``semantic`` observation). Gating the learned likelihood with it tells how
    much of the gap to the true mask is category recognition."""

    def __init__(self, env) -> None:
        self.env = env

    def __call__(self, obs: Mapping) -> np.ndarray:
        u = self.env.unwrapped
        same = [o.instance_id for o in u.house.objects if o.category == u.goal.category]
        return np.isin(semantic_of(obs, "true_category"), same)  # (H, W) bool


def template_reading(said: str, config) -> tuple[Reading, tuple]:
    """The reading of an agent without a reader: the template words read exactly (goal
    before a relation word, anchor after it, "in the <room>", a colour name); understood
    when a category is named. Returns (reading, (category, anchor, room) indices)."""
    categories = list(config.object_category.categories)
    rooms = list(config.room_type.room_types)
    category = instructed_category(said, categories)
    anchor = instructed_anchor(said, categories)
    room = instructed_room(said, rooms)
    words = re.findall(r"[a-z]+", said.lower())
    colour = next((c for c in config.instruction_reader.colors if c in words), None)
    reading = Reading(
        request=said,
        category=None if category is None else categories[category - 1],
        color=colour,
        room=None if room is None else rooms[room],
        anchor=None if anchor is None else categories[anchor - 1],
        understood=category is not None,
        reason=None if category is not None else "no category the templates name",
    )
    return reading, (category, anchor, room)


def semantic_of(obs: Mapping, agent: str) -> np.ndarray:
    """The env's instance-id image (H, W); ValueError naming ``agent`` without it."""
    if "semantic" not in obs:
        raise ValueError(f"agent={agent} needs the env's semantic observation (semantic=True)")
    return np.asarray(obs["semantic"])
