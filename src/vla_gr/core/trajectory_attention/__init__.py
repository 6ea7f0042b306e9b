"""Trajectory attention: RoPE, SDPA attention, the pre-norm transformer block, action queries.

Data flow: :mod:`.rope` (rotary positions) -> :mod:`.attention` (``MultiHeadAttention``,
``TransformerBlock``, also used by the observation fusion and the transformer denoiser)
-> :mod:`.encoder` (``TrajectoryEncoder``, DETR-style action queries).
"""

from vla_gr.core.trajectory_attention.attention import (
    MultiHeadAttention,
    TransformerBlock,
    as_context_tokens,
    build_attention_mask,
)
from vla_gr.core.trajectory_attention.encoder import TrajectoryEncoder
from vla_gr.core.trajectory_attention.rope import (
    apply_rope,
    apply_rope_complex,
    apply_rope_cos_sin,
    apply_rope_tables,
    rope_angles,
    rope_tables,
)

__all__ = [
    "MultiHeadAttention",
    "TransformerBlock",
    "TrajectoryEncoder",
    "apply_rope",
    "apply_rope_complex",
    "apply_rope_cos_sin",
    "apply_rope_tables",
    "as_context_tokens",
    "build_attention_mask",
    "rope_angles",
    "rope_tables",
]
