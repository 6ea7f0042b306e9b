"""Episode metrics for ObjectNav, following habitat-lab's Measures.

Each metric is a small class with ``reset(...)``, ``update(...)`` and ``value``;
:class:`EpisodeMeasures` composes them and is updated once per environment step.
Definitions (Habitat's ``Success``, ``SPL``, ``SoftSPL``, ``Collisions``):

- success = STOP called with geodesic distance to the goal footprint <= ``success_distance``;
- SPL = S * l* / max(l, l*), l* the geodesic start->goal distance, l the travelled path;
- soft-SPL = max(0, 1 - d_T / d_0) * l* / max(l, l*), d_T the final, d_0 the start distance;
- collision rate = colliding steps / steps.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

__all__ = [
    "Success",
    "SPL",
    "SoftSPL",
    "DistanceToGoal",
    "Collisions",
    "PathLength",
    "EpisodeMeasures",
    "spl_value",
    "soft_spl_value",
    "path_length_of",
    "aggregate",
    "format_table",
]


# ----------------------------------------------------------------------------- pure maths


def _efficiency(shortest: float, travelled: float) -> float:
    """l* / max(l, l*), with 1.0 when both are zero (started on the goal, never moved)."""
    denom = max(travelled, shortest)
    return 1.0 if denom <= 0.0 else shortest / denom


def spl_value(success: bool | float, shortest: float, travelled: float) -> float:
    """Success weighted by path length: S * l* / max(l, l*)."""
    _check_nonneg(shortest=shortest, travelled=travelled)
    return float(success) * _efficiency(shortest, travelled)


def soft_spl_value(final_distance: float, start_distance: float, travelled: float) -> float:
    """Habitat's soft-SPL: max(0, 1 - d_T / d_0) * d_0 / max(l, d_0).

    ``start_distance`` is both d_0 and l* (the geodesic start->goal distance). An
    unreachable final position (``inf``) counts as no progress.
    """
    _check_nonneg(start_distance=start_distance, travelled=travelled)
    if math.isnan(final_distance) or final_distance < 0:
        raise ValueError(f"final_distance must be >= 0 (inf allowed), got {final_distance}")
    if start_distance <= 0.0:
        progress = 1.0 if final_distance <= 0.0 else 0.0
    else:
        progress = max(0.0, 1.0 - final_distance / start_distance)
    return progress * _efficiency(start_distance, travelled)


def path_length_of(xy: np.ndarray) -> float:
    """Length in metres of a polyline ``xy`` (T, 2) of successive positions."""
    xy = np.asarray(xy, dtype=np.float64)
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise ValueError(f"xy must have shape (T, 2), got {xy.shape}")
    if len(xy) < 2:
        return 0.0
    return float(np.linalg.norm(np.diff(xy, axis=0), axis=1).sum())


def _check_nonneg(**values: float) -> None:
    for name, v in values.items():
        if not math.isfinite(v) or v < 0:
            raise ValueError(f"{name} must be finite and >= 0, got {v}")


def _as_xy(xy, name: str = "xy") -> np.ndarray:
    arr = np.asarray(xy, dtype=np.float64).reshape(-1)
    if arr.shape[0] < 2 or not np.all(np.isfinite(arr[:2])):
        raise ValueError(f"{name} must hold finite (x, y), got {xy!r}")
    return arr[:2].copy()  # (2,)


# ----------------------------------------------------------------------------- measures


class DistanceToGoal:
    """Current geodesic distance (m) from the robot to the goal footprint."""

    def reset(self, distance: float) -> None:
        self.value = float(distance)

    def update(self, distance: float) -> None:
        if math.isnan(distance):
            raise ValueError("distance_to_goal must not be NaN")
        self.value = float(distance)


class PathLength:
    """Travelled path length l (m): sum of straight segments between step positions."""

    def reset(self, start_xy) -> None:
        """``start_xy`` (2,) the start position."""
        self._last = _as_xy(start_xy, "start_xy")  # (2,)
        self.value = 0.0

    def update(self, xy) -> None:
        """``xy`` (2,) the position after this step."""
        cur = _as_xy(xy)  # (2,)
        self.value += float(np.linalg.norm(cur - self._last))
        self._last = cur


class Success:
    """1.0 once STOP is called within ``success_distance`` of the goal, else 0.0.

    The decision is taken at the STOP step and frozen afterwards (the episode ends there).
    """

    def __init__(self, success_distance: float = 1.0) -> None:
        if not success_distance > 0:
            raise ValueError(f"success_distance must be > 0, got {success_distance}")
        self.success_distance = float(success_distance)

    def reset(self) -> None:
        self.value = 0.0
        self.stopped = False

    def update(self, called_stop: bool, distance_to_goal: float) -> None:
        if self.stopped:
            return
        if called_stop:
            self.stopped = True
            self.value = float(distance_to_goal <= self.success_distance)


class SPL:
    """Success weighted by (normalised inverse) path length."""

    def reset(self, geodesic_start_distance: float) -> None:
        _check_nonneg(geodesic_start_distance=geodesic_start_distance)
        self.shortest = float(geodesic_start_distance)
        self.value = 0.0

    def update(self, success: float, path_length: float) -> None:
        self.value = spl_value(success, self.shortest, path_length)


class SoftSPL:
    """Habitat's soft-SPL: progress towards the goal instead of binary success."""

    def reset(self, geodesic_start_distance: float) -> None:
        _check_nonneg(geodesic_start_distance=geodesic_start_distance)
        self.start_distance = float(geodesic_start_distance)
        self.value = soft_spl_value(self.start_distance, self.start_distance, 0.0)

    def update(self, distance_to_goal: float, path_length: float) -> None:
        self.value = soft_spl_value(distance_to_goal, self.start_distance, path_length)


class Collisions:
    """Number of steps whose motion was blocked by contact; ``rate`` = count / steps."""

    def reset(self) -> None:
        self.value = 0
        self.steps = 0

    def update(self, collided: bool) -> None:
        self.steps += 1
        self.value += int(bool(collided))

    @property
    def rate(self) -> float:
        return self.value / self.steps if self.steps else 0.0


class EpisodeMeasures:
    """All ObjectNav metrics of one episode, updated once per environment step."""

    def __init__(self, success_distance: float = 1.0) -> None:
        self.success = Success(success_distance)
        self.spl = SPL()
        self.soft_spl = SoftSPL()
        self.distance_to_goal = DistanceToGoal()
        self.collisions = Collisions()
        self.path_length = PathLength()
        self._started = False

    @property
    def success_distance(self) -> float:
        return self.success.success_distance

    def reset(
        self, start_xy, geodesic_start_distance: float, distance_to_goal: float | None = None
    ) -> None:
        """Start an episode at ``start_xy`` (2,) with l* = ``geodesic_start_distance`` (m);
        ``distance_to_goal`` at the start when it is not l* (``inf``: no goal to reach)."""
        _check_nonneg(geodesic_start_distance=geodesic_start_distance)
        self.geodesic_start_distance = float(geodesic_start_distance)
        self.success.reset()
        self.spl.reset(geodesic_start_distance)
        self.soft_spl.reset(geodesic_start_distance)
        start = geodesic_start_distance if distance_to_goal is None else distance_to_goal
        self.distance_to_goal.reset(start)
        self.collisions.reset()
        self.path_length.reset(start_xy)
        self._started = True

    def update(self, xy, distance_to_goal: float, collided: bool, called_stop: bool) -> None:
        """Record one step: position ``xy`` (2,) after it, geodesic distance, flags."""
        if not self._started:
            raise RuntimeError("EpisodeMeasures.update called before reset")
        self.path_length.update(xy)
        self.distance_to_goal.update(distance_to_goal)
        self.collisions.update(collided)
        self.success.update(called_stop, distance_to_goal)
        self.spl.update(self.success.value, self.path_length.value)
        self.soft_spl.update(distance_to_goal, self.path_length.value)

    @property
    def steps(self) -> int:
        return self.collisions.steps

    def as_info(self) -> dict:
        """Current metrics as a flat dict (the env's ``info`` entries)."""
        if not self._started:
            raise RuntimeError("EpisodeMeasures.as_info called before reset")
        return {
            "success": float(self.success.value),
            "spl": float(self.spl.value),
            "soft_spl": float(self.soft_spl.value),
            "distance_to_goal": float(self.distance_to_goal.value),
            "collisions": int(self.collisions.value),
            "collision_rate": float(self.collisions.rate),
            "path_length": float(self.path_length.value),
            "geodesic_start_distance": self.geodesic_start_distance,
            "steps": int(self.steps),
        }


# ----------------------------------------------------------------------------- tables

AGGREGATE_KEYS: tuple[str, ...] = (
    "success",
    "spl",
    "soft_spl",
    "collision_rate",
    "path_length",
    "distance_to_goal",
)


def _collision_rate(info: dict, index: int) -> float:
    if "collision_rate" in info:
        return float(info["collision_rate"])
    if "collisions" not in info or "steps" not in info:
        raise ValueError(f"infos[{index}] needs 'collision_rate' or both 'collisions' and 'steps'")
    return float(info["collisions"]) / info["steps"] if info["steps"] else 0.0


def aggregate(infos: Sequence[dict]) -> dict:
    """Mean of each metric over final episode infos; ``episodes`` is their count.

    ``collision_rate`` is averaged per episode (falls back to collisions / steps).
    """
    if len(infos) == 0:
        raise ValueError("aggregate needs at least one episode info, got an empty list")
    out: dict = {}
    for key in AGGREGATE_KEYS:
        if key == "collision_rate":
            values = [_collision_rate(info, i) for i, info in enumerate(infos)]
        else:
            missing = [i for i, info in enumerate(infos) if key not in info]
            if missing:
                raise ValueError(f"infos[{missing[0]}] lacks the metric {key!r}")
            values = [float(info[key]) for info in infos]
        out[key] = float(np.mean(values))
    out["episodes"] = len(infos)
    return out


def _fmt(value) -> str:
    if isinstance(value, bool | np.bool_):
        return str(bool(value))
    if isinstance(value, int | np.integer):
        return str(int(value))
    if isinstance(value, float | np.floating):
        return f"{float(value):.3f}"
    return str(value)


def format_table(rows: dict[str, dict]) -> str:
    """Markdown table: one row per entry of ``rows``, columns = union of their keys."""
    if not rows:
        raise ValueError("format_table needs at least one row")
    columns: list[str] = []
    for metrics in rows.values():
        for key in metrics:
            if key not in columns:
                columns.append(key)
    header = ["name", *columns]
    body = [
        [str(name)] + [_fmt(m[c]) if c in m else "-" for c in columns] for name, m in rows.items()
    ]
    widths = [max(len(r[i]) for r in [header, *body]) for i in range(len(header))]

    def line(cells: list[str]) -> str:
        return "| " + " | ".join(c.ljust(w) for c, w in zip(cells, widths)) + " |"

    sep = "|" + "|".join("-" * (w + 2) for w in widths) + "|"
    return "\n".join([line(header), sep, *(line(r) for r in body)])
