"""Observation encoders of the agent: each modality becomes ``D``-wide context tokens.

Data flow: :mod:`.config` (``EncodersConfig``) -> :mod:`.rgbd` (image tokens) ->
:mod:`.text` (instruction token) -> :mod:`.pose` (pose tokens);
:class:`vla_gr.policy.VLAGRPolicy` fuses the tokens and hands them to the action head
(:mod:`vla_gr.core.diffusion_policy`).
"""

from vla_gr.core.encoders.config import TEXT_ENCODERS, VISION_POOLS, EncodersConfig
from vla_gr.core.encoders.pose import PoseEncoder, pose_features
from vla_gr.core.encoders.rgbd import RGBDEncoder, spatial_softmax
from vla_gr.core.encoders.text import (
    HashedTextEncoder,
    SentenceTextEncoder,
    build_text_encoder,
    default_sentence_model_path,
    hash_instruction,
    load_sentence_model,
    mean_pool,
)

__all__ = [
    "TEXT_ENCODERS",
    "VISION_POOLS",
    "EncodersConfig",
    "HashedTextEncoder",
    "PoseEncoder",
    "RGBDEncoder",
    "SentenceTextEncoder",
    "build_text_encoder",
    "default_sentence_model_path",
    "load_sentence_model",
    "hash_instruction",
    "mean_pool",
    "pose_features",
    "spatial_softmax",
]
