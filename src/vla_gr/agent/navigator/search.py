"""Whether the reachable house is searched, from the navigator's own map: the "not found" rule.

Each planner tick says whether a way is open (a confirmed goal, a path to a frontier at the
robot's own radius, a STOP, the look around) and how much of the map has been seen. The house
counts as searched once no way has been open and the map has grown by at most ``new_area`` for
``steps`` on end: more newly seen house (planning thinner got the robot through a narrow
passage) starts the count again. The settings are ``model.navigator.not_found``
(:class:`~vla_gr.agent.navigator.config.NotFoundConfig`); 0 steps never declares. With
``second_look`` the first time the count says searched with goals rejected, the navigator
forgets where they were (their cells vote again) and the count starts again.
"""

from __future__ import annotations

from vla_gr.agent.navigator.config import NotFoundConfig

__all__ = ["SearchCount"]


class SearchCount:
    """Planner ticks on end without an open way or new house (see module docstring).

    Args:
        config: ``model.navigator.not_found``.
        needed: planner ticks covering ``config.steps`` (the navigator's ``steps_to_ticks``).
    """

    def __init__(self, config: NotFoundConfig, needed: int) -> None:
        self.config, self.needed = config, int(needed)
        self.ticks = 0  # ticks on end without an open way or new house
        self.area = 0.0  # m2 of the map seen when the count last started
        self.looked_again = False  # the second look was taken (not_found.second_look)

    def update(self, open_way: bool, seen: float) -> bool:
        """One planner tick (``seen``: m2 of the map seen); True once the house is searched."""
        if open_way or seen - self.area > self.config.new_area:
            self.ticks, self.area = 0, float(seen)
        else:
            self.ticks += 1
        return self.config.steps > 0 and self.ticks >= self.needed

    def look_again(self, rejected: bool) -> bool:
        """Whether to search once more instead of declaring, the house counted as searched
        (``rejected``: goals were rejected this episode): with ``second_look``, the first
        time only; the count then starts again."""
        if not (self.config.second_look and rejected and not self.looked_again):
            return False
        self.looked_again, self.ticks = True, 0
        return True
