"""The navigation agents, one class each, chosen by ``model.agent`` through the factory:
:class:`VLAGRPolicy` (the dual system) and :class:`EndToEndPolicy` (the ablation without the
GR field); :func:`load_policy` reads a checkpoint into the class it names."""

from vla_gr.agent.observations import as_instructions, env_obs_to_frame
from vla_gr.policy.base import NavigationPolicy
from vla_gr.policy.end_to_end import EndToEndPolicy
from vla_gr.policy.factory import load_policy, make_policy, policy_class
from vla_gr.policy.frames import apply_peft, make_fake_batch
from vla_gr.policy.vla_gr import VLAGRPolicy

__all__ = [
    "EndToEndPolicy",
    "NavigationPolicy",
    "VLAGRPolicy",
    "apply_peft",
    "as_instructions",
    "env_obs_to_frame",
    "load_policy",
    "make_fake_batch",
    "make_policy",
    "policy_class",
]
