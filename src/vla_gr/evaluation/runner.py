"""The closed-loop episode loop, its per-episode record, and parallel workers.

:func:`run_episode` is the one rollout loop (``vla_gr.evaluate.rollout_policy`` and
``vla-gr eval`` both use it). Besides the env's final ``info`` it keeps what explains the
episode afterwards: world positions, goal-instance pixel counts (when the env renders
``semantic``), geodesic distances, the executed actions (a deterministic env replays them
exactly, which is how GIFs are made after the run) and the time of each decision.

:func:`iter_episode_rows` runs episodes in ``workers`` spawned processes (MuJoCo GL
contexts do not survive fork), one env and one agent each, and yields rows in the order
of the episode indices, so the output does not depend on ``workers``.
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np
import torch
from torch import nn

from vla_gr.envs.absent import requested_object
from vla_gr.envs.metrics import aggregate
from vla_gr.evaluation.causes import (
    CauseThresholds,
    failure_cause,
    rejected_goal_kind,
    wrong_stop_kind,
)
from vla_gr.geometry.pose2d import robot_to_map

log = logging.getLogger(__name__)

FINAL_KEYS = (
    "success",
    "spl",
    "soft_spl",
    "distance_to_goal",
    "collisions",
    "collision_rate",
    "path_length",
    "geodesic_start_distance",
    "steps",
)


def episode_seed(seed: int, index: int) -> int:
    """Seed of the agent's randomness in episode ``index`` of a run seeded ``seed``."""
    return int(np.random.SeedSequence([int(seed), int(index)]).generate_state(1)[0])


def instruction_kind(instruction: str, description: dict | None = None) -> str:
    """'relation', 'room', 'colour' or 'category': the most specific attribute it names (its
    ``description``, the generator's fields, when the episode has one: a hand-written request
    is not parsed)."""
    from vla_gr.envs.instructions import parse_instruction

    parsed = description if description is not None else parse_instruction(instruction)
    if parsed["near"]:
        return "relation"
    if parsed["room"]:
        return "room"
    if parsed["color"]:
        return "colour"
    return "category"


def _footprint_gap(obj, xy: tuple[float, float]) -> float:
    """Straight-line distance (m) from ``xy`` to ``obj``'s footprint bounding circle: a lower
    bound of the distance to the footprint (negative inside the circle)."""
    return math.hypot(obj.x - xy[0], obj.y - xy[1]) - math.hypot(*obj.half_extents)


def _distractor_distances(env, xy: tuple[float, float]) -> dict[str, float]:
    """Distance (m) from ``xy`` to each object of the goal's category but the goal (every
    one of the category asked for in an absent-object episode).

    Geodesic for distractors whose footprint may lie within ``success_distance``; for the
    others a straight-line lower bound (centre distance minus half-diagonal), which already
    exceeds ``success_distance`` and spares a fast-marching solve.
    """
    from vla_gr.envs.geodesic import distance_at, goal_distance_field

    u = env.unwrapped
    spec = u.episode_spec
    out = {}
    for obj in u.house.objects:
        if obj.category != spec.goal_category or obj.instance_id == spec.goal_instance_id:
            continue
        oid = obj.instance_id
        bound = _footprint_gap(obj, xy)
        if bound > u.success_distance:
            out[str(oid)] = round(bound, 4)
            continue
        field = goal_distance_field(u.house, oid)  # (H, W)
        out[str(oid)] = distance_at(field, u.house.grid, *xy)
    return out


def _object_summary(house, obj) -> dict:
    return {
        "instance_id": int(obj.instance_id),
        "category": obj.category,
        "color": obj.color,
        "room": house.rooms[obj.room_index].room_type,
    }


def _nearest_object(env, xy: tuple[float, float]) -> dict:
    """The object whose footprint is nearest to ``xy`` (straight line from the footprint's
    bounding circle, 0 inside it): id, category, colour, room and that distance (m)."""
    house = env.unwrapped.house
    obj = min(house.objects, key=lambda o: _footprint_gap(o, xy))
    return {**_object_summary(house, obj), "distance": round(max(0.0, _footprint_gap(obj, xy)), 4)}


#: A rejected goal cell this close (m) to an object's footprint is taken to be that object.
REJECTED_NEAR_DISTANCE = 0.5


def _rejected_goals(env, rejections: Sequence[dict], goal: dict) -> list[dict]:
    """Each goal the agent rejected (its ``episode_summary()['rejections']``: ``reason`` and
    ``xy`` in the episode-start frame) with the object nearest to it in the world and what
    that object was against ``goal`` (the goal's :func:`_object_summary`;
    :func:`rejected_goal_kind`)."""
    start = env.unwrapped.start_pose_world  # (3,)
    out = []
    for r in rejections:
        xy = robot_to_map(np.asarray([r["xy"]], np.float64), start)[0]  # (2,)
        near = _nearest_object(env, (float(xy[0]), float(xy[1])))
        kind = rejected_goal_kind(goal, near, REJECTED_NEAR_DISTANCE)
        out.append({"reason": r["reason"], "kind": kind, "near": near})
    return out


def _goal_pixels(obs: dict, goal_id: int) -> int:
    semantic = obs.get("semantic")
    return -1 if semantic is None else int(np.count_nonzero(semantic == goal_id))


def run_episode(
    env, agent, index: int, seed: int = 0, thresholds: CauseThresholds | None = None
) -> dict:
    """Run ``agent`` on episode ``index`` of ``env`` (``reset(options={"episode": index})``: its
    noise too is the episode's own); the episode's row.

    After each ``agent.act`` an agent that declared an outcome (``agent.declared_outcome``)
    ends the episode through ``env.unwrapped.declare(outcome)`` instead of ``env.step`` (its
    action, no STOP, is still recorded).

    Row keys: ``episode_index``, ``episode_id``, ``spec``, ``metrics`` (the final info),
    ``stopped`` (a STOP ended it; False when declared), ``cause`` (None on success; the
    outcome's name when declared), ``declared`` (the outcome, else None),
    ``declared_not_found`` (it was ``"not_found"``), ``absent`` (an absent-object episode: no
    goal, a STOP is false, "not found" is right; see :mod:`vla_gr.envs.absent`), ``reading`` (the
    agent's ``reading()``: how it read the request, None without a reader), ``num_rooms``,
    ``goal_category``, ``instruction_kind``, ``distractor_distances``, ``stopped_near`` (the
    nearest object) and ``wrong_stop`` (its :func:`wrong_stop_kind`) after a wrong STOP,
    ``rejected_goals`` (each goal the agent rejected: reason, kind and nearest object; see
    :func:`_rejected_goals`), ``trace`` (``xy`` (T+1, 2), ``goal_pixels`` (T+1,) or -1
    without semantic, ``distance`` (T+1,)), ``actions`` (T, 3), ``latency_ms`` ({part:
    (T,)}), ``parameters``, ``agent`` (the agent's ``episode_summary()``, {} without one).
    """
    th = thresholds or CauseThresholds(success_distance=env.unwrapped.success_distance)
    obs, info = env.reset(options={"episode": int(index)})
    u = env.unwrapped
    goal_id = int(u.episode_spec.goal_instance_id)  # -1 (no object) when absent
    agent.reset(episode_seed(seed, index))
    xy = [tuple(float(v) for v in u.robot_pose_world()[:2])]
    pixels = [_goal_pixels(obs, goal_id)]
    distance = [float(info["distance_to_goal"])]
    actions: list[list[float]] = []
    latency: dict[str, list[float]] = {}
    terminated = truncated = False
    clock = time.perf_counter
    with torch.inference_mode():
        while not (terminated or truncated):
            t0 = clock()
            action = agent.act(obs)  # (3,)
            elapsed = clock() - t0
            latency.setdefault("decision", []).append(elapsed * 1e3)
            for part, seconds in agent.last_timings.items():
                latency.setdefault(part, []).append(seconds * 1e3)
            outcome = agent.declared_outcome
            if outcome is None:
                obs, _, terminated, truncated, info = env.step(action)
            else:  # the agent does not act on this episode: no motion, no STOP
                obs, _, terminated, truncated, info = u.declare(outcome)
            actions.append([float(a) for a in np.asarray(action, dtype=np.float32)])
            pose = u.robot_pose_world()
            xy.append((float(pose[0]), float(pose[1])))
            pixels.append(_goal_pixels(obs, goal_id))
            distance.append(float(info["distance_to_goal"]))
    metrics = {k: info[k] for k in FINAL_KEYS}
    metrics = {k: (v.item() if isinstance(v, np.generic) else v) for k, v in metrics.items()}
    declared = info["declared"]
    stopped = bool(terminated) and declared is None
    wrong_stop = stopped and not metrics["success"]
    distractor = _distractor_distances(env, xy[-1]) if wrong_stop else {}
    near = _nearest_object(env, xy[-1]) if wrong_stop else {}
    spec = u.episode_spec
    cause = failure_cause(
        bool(metrics["success"]),
        stopped,
        np.array(xy),
        pixels,
        list(distractor.values()),
        th,
        declared=declared,
    )
    summary = agent.episode_summary()
    goal = requested_object(spec) if u.goal is None else _object_summary(u.house, u.goal)
    return {
        "episode_index": int(index),
        "episode_id": spec.episode_id,
        "spec": spec.to_dict(),
        "metrics": metrics,
        "stopped": stopped,
        "cause": cause,
        "declared": declared,
        "declared_not_found": declared == "not_found",
        "absent": spec.absent,
        "reading": agent.reading(),
        "num_rooms": len(u.house.rooms),
        "goal_category": spec.goal_category,
        "instruction_kind": instruction_kind(spec.instruction, spec.description),
        "distractor_distances": distractor,
        "stopped_near": near,
        "wrong_stop": wrong_stop_kind(goal, near) if near else None,
        "rejected_goals": _rejected_goals(env, summary.get("rejections", []), goal),
        "trace": {
            "xy": [[round(x, 4), round(y, 4)] for x, y in xy],
            "goal_pixels": pixels,
            "distance": [round(d, 4) for d in distance],
        },
        "actions": actions,
        "latency_ms": {k: [round(v, 4) for v in vals] for k, vals in latency.items()},
        "parameters": agent.parameters(),
        "agent": summary,
    }


def rollout_rows(
    policy, env_kwargs: dict, episodes: Sequence[int], device: torch.device | str = "cpu"
) -> list[dict]:
    """Run ``policy`` on each episode index of ``episodes``; each episode's row
    (:func:`run_episode`).

    ``policy`` has the interface of :class:`vla_gr.policy.NavigationPolicy` (``reset()``,
    ``select_action(obs) -> (A,)``, ``last_timings``, ``episode_summary()``); an ``nn.Module`` is
    moved to ``device`` and put in eval mode for the rollout (its train/eval mode is restored
    afterwards). ``env_kwargs`` go to ``gymnasium.make("VLAGR/ObjectNav-v0", ...)``
    (``max_episode_steps`` is the step budget). Episode ``k`` is
    ``env.reset(options={"episode": k})``.
    Each episode seeds torch (replayable sampling) inside a forked RNG: the caller's random
    streams (a training run's) are left as they were.
    """
    from vla_gr.data.collect import make_env
    from vla_gr.evaluation.agents import PolicyAgent

    if len(episodes) == 0:
        raise ValueError("episodes must name at least one episode index")
    is_module = isinstance(policy, nn.Module)
    was_training = policy.training if is_module else False
    if is_module:
        policy.to(device).eval()
    env = make_env(dict(env_kwargs))
    agent = PolicyAgent(policy, device)
    try:
        with torch.random.fork_rng():
            return [run_episode(env, agent, int(k)) for k in episodes]
    finally:
        env.close()
        if is_module:
            policy.train(was_training)


def rollout_policy(
    policy, env_kwargs: dict, episodes: Sequence[int], device: torch.device | str = "cpu"
) -> list[dict]:
    """:func:`rollout_rows`' final info of each episode (with its ``episode_index``)."""
    rows = rollout_rows(policy, env_kwargs, episodes, device)
    return [dict(row["metrics"], episode_index=row["episode_index"]) for row in rows]


def summarize(infos: Sequence[dict]) -> dict:
    """Mean success, SPL, soft-SPL, collision rate, path length, final distance; ``episodes``."""
    return aggregate(infos)


# ----------------------------------------------------------------------------- workers

_WORKER: dict = {}


def _init_worker(cfg, agent_name: str, env_kwargs: dict, warm_indices: Sequence[int]) -> None:
    """Per-process env + agent, made once and reused for every episode of the worker.

    One untimed decision on the first of ``warm_indices`` whose house hosts an episode first,
    so that lazy initialisation (first kernels, caches) does not land in the latency of the
    first timed decision.
    """
    from vla_gr.data.collect import make_env
    from vla_gr.envs.episodes import NoEpisodeError
    from vla_gr.evaluation.agents import make_agent

    torch.set_num_threads(1)
    env = make_env(env_kwargs)
    agent = make_agent(agent_name, cfg, env)
    for index in warm_indices:
        try:
            obs, _ = env.reset(options={"episode": int(index)})
        except NoEpisodeError:
            continue
        agent.reset(0)
        with torch.inference_mode():
            agent.act(obs)
        break
    _WORKER.update(env=env, agent=agent, cfg=cfg)


def _work(index: int) -> dict:
    """Episode ``index``'s row, or ``{"episode_index", "no_episode": why}`` when its house
    cannot host an episode (:class:`~vla_gr.envs.episodes.NoEpisodeError`)."""
    from vla_gr.envs.episodes import NoEpisodeError

    cfg = _WORKER["cfg"]
    th = thresholds_from_config(cfg)
    try:
        return run_episode(_WORKER["env"], _WORKER["agent"], index, cfg.seed, th)
    except NoEpisodeError as err:
        return {"episode_index": int(index), "no_episode": str(err)}


def thresholds_from_config(cfg) -> CauseThresholds:
    e = cfg.eval
    return CauseThresholds(
        cfg.env.success_distance, e.goal_seen_pixels, e.stuck_steps, e.stuck_radius
    )


def iter_episode_rows(
    cfg, agent_name: str, env_kwargs: dict, indices: Sequence[int], workers: int = 1
) -> Iterator[dict]:
    """Rows of episodes ``indices``, in that order, from ``workers`` processes (1: here).

    An index whose house cannot host an episode gives ``{"episode_index", "no_episode"}``.

    Every worker, this process included, runs torch on one thread: the same arithmetic,
    so the rows do not depend on ``workers``. With ``eval.backend=ray`` the workers are Ray
    actors running the same functions (:mod:`vla_gr.evaluation.ray_rows`).
    """
    from vla_gr.data.collect import map_in_workers

    if cfg.eval.backend == "ray":
        from vla_gr.evaluation.ray_rows import ray_episode_rows

        yield from ray_episode_rows(cfg, agent_name, env_kwargs, indices, workers)
        return

    threads = torch.get_num_threads()

    def close() -> None:
        _WORKER.pop("env").close()
        _WORKER.clear()
        torch.set_num_threads(threads)

    init_args = (cfg, agent_name, env_kwargs, tuple(indices))
    yield from map_in_workers(_init_worker, init_args, _work, indices, workers, close)


# ----------------------------------------------------------------------------- rows on disk


def read_rows(path: Path) -> list[dict]:
    """Complete rows of an ``episodes.jsonl`` (a torn last line, from a kill, is dropped)."""
    if not path.is_file():
        return []
    rows = []
    lines = path.read_text(encoding="utf-8").split("\n")
    for lineno, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            rows.append(json.loads(line))
        except json.JSONDecodeError:
            if lineno != len(lines):
                raise ValueError(f"{path}:{lineno}: not a JSON row (edited by hand?)") from None
            log.warning("%s: dropped a torn last row (interrupted run)", path)
    return rows


class RowWriter:
    """Appends rows to ``episodes.jsonl``, one flushed line each (a kill loses no row)."""

    def __init__(self, path: Path, keep: Sequence[dict]) -> None:
        tmp = path.with_name(path.name + ".tmp")
        with tmp.open("w", encoding="utf-8") as f:  # rewrite the complete rows only
            for row in keep:
                f.write(json.dumps(row) + "\n")
        tmp.replace(path)
        self._file = path.open("a", encoding="utf-8")

    def write(self, row: dict) -> None:
        self._file.write(json.dumps(row) + "\n")
        self._file.flush()

    def close(self) -> None:
        self._file.close()
