"""S2's behaviour on the GR field: look around, confirm, explore, approach, verify, recover,
stop (:mod:`.navigator`); its settings by concern (:mod:`.config`), the checks of a goal
before a STOP (:mod:`.goal_checks`), the fine local planner for narrow gaps
(:mod:`.local_planner`), its own marks on the map (:mod:`.map_edits`) and whether the reachable
house is searched (:mod:`.search`: "not found")."""

from vla_gr.agent.navigator.config import NavigatorConfig
from vla_gr.agent.navigator.navigator import MODES, Navigator, NavPlan

__all__ = ["MODES", "NavPlan", "Navigator", "NavigatorConfig"]
