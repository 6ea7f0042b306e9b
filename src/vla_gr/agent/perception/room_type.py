"""Which type of room the camera is in, and which room an instruction names.

S2's check on room instructions ("the chair in the kitchen"). The goal head marks the
instructed object from one frame, and a same-category twin in another room can look just
like it. The robot, though, stands in the goal's room when it is about to STOP, and rooms of
one type share their wall paint and floor finish. So near a confirmed goal the navigator asks
this classifier how likely the robot's room is of the instructed type; a confident "no"
rejects that goal and exploration goes on (``navigator.goal_checks.room_reject_threshold``).

- :class:`RoomTypeClassifier`: one RGB-D frame -> logits over ``room_types``. It is a small
  stride-2 CNN, trained on the world's room labels at the robot's position
  (:mod:`vla_gr.training.room_type`).
- :func:`instructed_room`: the room type an instruction names with "in the <room>" (room
  types written with spaces: "living room"). Anything else, such as no room or a word
  outside ``room_types``, gives None, and the check stays off for that episode.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from functools import lru_cache

import torch
import torch.nn.functional as F
from torch import nn

from vla_gr.agent.perception.engine import Network
from vla_gr.agent.perception.goal_head import norm_groups, rgbd_inputs
from vla_gr.geometry.robot_spec import MAX_DEPTH
from vla_gr.validation import check_positive

__all__ = ["RoomTypeClassifier", "RoomTypeConfig", "instructed_room", "spoken_room_name"]


#: The world's room types, in the order of the classifier's classes.
ROOM_TYPES: tuple[str, ...] = (
    "kitchen", "living_room", "bedroom", "bathroom", "office", "hallway",
)  # fmt: skip


@dataclass
class RoomTypeConfig:
    """The room-type classifier (``model.room_type.*``); its weights are in the checkpoint."""

    # build the classifier (S2 uses it with navigator.goal_checks.room_reject_threshold)
    enabled: bool = False
    room_types: list[str] = field(default_factory=lambda: list(ROOM_TYPES))
    input_size: int = 32  # frames are area-averaged to this side first (room cues are coarse)
    channels: list[int] = field(default_factory=lambda: [16, 32, 64])  # stride-2 stages
    max_depth: float = MAX_DEPTH  # metres; depth is clipped and scaled to [-1, 1]

    def __post_init__(self) -> None:
        if len(self.room_types) < 2 or len(set(self.room_types)) != len(self.room_types):
            raise ValueError(
                f"model.room_type.room_types={self.room_types} must name at least two distinct "
                "room types"
            )
        if not self.channels or min(self.channels) < 1:
            raise ValueError(f"model.room_type.channels={self.channels} must be positive widths")
        check_positive("model.room_type.max_depth", self.max_depth)
        check_positive("model.room_type.input_size", self.input_size)


class RoomTypeClassifier(nn.Module):
    """RGB-D frame -> room-type logits: area-averaged to ``input_size``, then (conv 3x3
    stride 2 -> GroupNorm -> SiLU) per stage, global average pooling, linear."""

    def __init__(self, config: RoomTypeConfig | None = None) -> None:
        super().__init__()
        self.config = c = config or RoomTypeConfig()
        layers: list[nn.Module] = []
        width = 4
        for out in c.channels:
            layers += [
                nn.Conv2d(width, out, 3, stride=2, padding=1),
                nn.GroupNorm(norm_groups(out), out),
                nn.SiLU(),
            ]
            width = out
        self.features = nn.Sequential(*layers)
        self.logits = nn.Linear(width, len(c.room_types))

    def network_inputs(self, rgb: torch.Tensor, depth: torch.Tensor) -> tuple[torch.Tensor]:
        """What :meth:`network` takes: rgb (B, 3, H, W) uint8 or [0, 1], depth (B, 1, H, W)
        metres -> (x (B, 4, s, s) in [-1, 1], area-averaged to ``input_size``,)."""
        if rgb.dim() != 4 or rgb.shape[1] != 3:
            raise ValueError(f"rgb must be (B, 3, H, W); got {tuple(rgb.shape)}")
        if depth.shape != (rgb.shape[0], 1, *rgb.shape[2:]):
            raise ValueError(f"depth must be (B, 1, H, W) like rgb; got {tuple(depth.shape)}")
        x = rgbd_inputs(rgb, depth, self.config.max_depth)  # (B, 4, H, W)
        return (F.adaptive_avg_pool2d(x, self.config.input_size),)  # (B, 4, s, s)

    def network(self, x: torch.Tensor) -> dict[str, torch.Tensor]:
        """The CNN, what an inference engine runs (:mod:`.engine`): x (B, 4, s, s) ->
        ``logits`` (B, R)."""
        h = self.features(x)  # (B, C, s', s')
        return {"logits": self.logits(h.mean(dim=(2, 3)))}  # (B, R)

    def forward(
        self, rgb: torch.Tensor, depth: torch.Tensor, network: Network | None = None
    ) -> torch.Tensor:
        """rgb (B, 3, H, W) uint8 or [0, 1], depth (B, 1, H, W) metres -> logits (B, R);
        ``network`` runs :meth:`network` (an engine's export of it; None: this module)."""
        return (network or self.network)(*self.network_inputs(rgb, depth))["logits"]

    @torch.no_grad()
    def probabilities(
        self, rgb: torch.Tensor, depth: torch.Tensor, network: Network | None = None
    ) -> torch.Tensor:
        """Room-type probabilities (B, R), in the order of ``config.room_types``."""
        return F.softmax(self(rgb, depth, network).float(), dim=-1)  # (B, R)


def spoken_room_name(room_type: str) -> str:
    """How instructions say a room type: 'living_room' -> 'living room'."""
    return room_type.replace("_", " ")


@lru_cache(maxsize=64)
def _room_pattern(room_types: tuple[str, ...]) -> re.Pattern:
    names = sorted(map(spoken_room_name, room_types), key=len, reverse=True)
    return re.compile(r"\bin the (" + "|".join(map(re.escape, names)) + r")\b", re.IGNORECASE)


def instructed_room(instruction: str, room_types: tuple[str, ...] | list[str]) -> int | None:
    """Index in ``room_types`` of the room ``instruction`` names ("... in the living room"),
    or None when it names none of them."""
    if not isinstance(instruction, str):
        raise TypeError(f"instruction must be a str, got {type(instruction).__name__}")
    found = _room_pattern(tuple(room_types)).search(instruction)
    if found is None:
        return None
    return [spoken_room_name(r) for r in room_types].index(found.group(1).lower())
