"""The navigation agent: :class:`VLAGRPolicy` (``agent``) and its inputs (``frames``)."""

from vla_gr.policy.agent import VLAGRPolicy
from vla_gr.policy.frames import apply_peft, as_instructions, env_obs_to_frame, make_fake_batch

__all__ = ["VLAGRPolicy", "apply_peft", "as_instructions", "env_obs_to_frame", "make_fake_batch"]
