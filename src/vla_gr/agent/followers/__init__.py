"""S1: the followers that drive along S2's latest plan every control step. :mod:`.pure_pursuit`
(``PurePursuit``) is the non-learned one; :mod:`.learned_s1` (``S1Policy``,
``LearnedFollower``) the learned one (<= 2 M parameters), reading :mod:`.s1_inputs`."""

from vla_gr.agent.followers.learned_s1 import LearnedFollower, S1Policy
from vla_gr.agent.followers.pure_pursuit import PurePursuit, PursuitConfig

__all__ = ["LearnedFollower", "PurePursuit", "PursuitConfig", "S1Policy"]
