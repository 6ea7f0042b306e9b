"""Choosing the "not found" rule: per-tick navigator traces of the shipped agent on absent-object
episodes and their normal twins, and candidate rules replayed on them.

    python benchmarks/not_found_traces.py collect --split val --first 200 --count 20 \
        --out outputs/not_found/traces_val200-219.jsonl
    python benchmarks/not_found_traces.py replay outputs/not_found/traces_val200-219.jsonl

``collect`` runs each index's absent-object episode and normal twin (rooms cycling 1..6, as
``benchmarks/absent_episodes.py``) with ``navigator.not_found.steps=0`` (never declared) and
writes, per episode, every S2 tick's (step, mode, committed, has_path, thin, explored m2, goals
rejected so far, whether a goal was ever seen).
``replay`` runs the shipped count (``SearchCount``) on them per rule, length and ``new_area``:
how many absent episodes it would declare and the median step, and the normal episodes it would
declare (those that succeeded: lost). A declaration only ends an episode, so up to the step it
fires a replay is the run the agent would have made.
"""

from __future__ import annotations

import argparse
import functools
import json

import numpy as np


def _own_radius(tick: dict) -> bool:
    """A tick's path opens a way at the robot's own radius (not planning thinner)."""
    return tick["path"] and not tick["thin"]


#: (rule, whether a tick's path opens a way) replayed by ``replay``.
RULES = {
    "no path at any radius": lambda tick: tick["path"],
    "no way at the own radius (shipped)": _own_radius,
}


def collect(split: str, first: int, count: int, out: str, kinds=("absent", "normal")) -> None:
    import gymnasium as gym
    import torch

    from vla_gr.envs.absent import sample_absent_episode
    from vla_gr.envs.episodes import NoEpisodeError, sample_episode
    from vla_gr.evaluation.agents import PolicyAgent
    from vla_gr.policy import load_policy

    torch.set_num_threads(1)
    policy = load_policy("checkpoints/vla_gr_cpu", overrides=["navigator.not_found.steps=0"])
    agent, nav = PolicyAgent(policy), policy.dual_system.navigator
    cell_area = nav.field.cell_size**2
    with open(out, "a", encoding="utf-8") as f:
        for k in range(count):
            index, rooms = first + k, 1 + k % 6
            for kind, sample in (("absent", sample_absent_episode), ("normal", sample_episode)):
                if kind not in kinds:
                    continue
                try:
                    spec = sample(split, index, num_rooms=rooms)
                except NoEpisodeError:
                    continue
                env = gym.make("VLAGR/ObjectNav-v0", split=split, image_size=64, episodes=[spec])
                obs, info = env.reset(options={"episode": 0})
                agent.reset(0)
                ticks, done = [], False
                with torch.inference_mode():
                    while not done and agent.declared_outcome is None:  # not understood
                        action = agent.act(obs)
                        if nav.ticks and nav.ticks != len(ticks):  # an S2 tick this step
                            maps, out_ = nav.field.maps, nav.last_output
                            ticks.append({
                                "step": int(info["steps"]), "mode": nav.mode,
                                "committed": nav.committed, "path": bool(out_.has_path[0]),
                                "thin": nav.tight_left > 0,
                                "explored": float(maps.explored[0].sum()) * cell_area,
                                "rejected": int(nav.rejections), "seen": nav.ever_seen_goal,
                            })  # fmt: skip
                        obs, _, terminated, truncated, info = env.step(action)
                        done = terminated or truncated
                env.close()
                row = {"kind": kind, "index": index, "rooms": rooms, "steps": info["steps"],
                       "success": info["success"], "ticks": ticks}  # fmt: skip
                f.write(json.dumps(row) + "\n")
                f.flush()
                print(kind, index, rooms, info["steps"], info["success"], flush=True)


def fires(
    ticks: list[dict], way, steps: int, new_area: float, plan_every: int = 3,
    unrejected: int | None = None,
):  # fmt: skip
    """The step at which the shipped count (:class:`~vla_gr.agent.navigator.search.SearchCount`)
    declares with ``way`` deciding whether a tick's path opens a way, or None; with
    ``unrejected``, the count needs that many steps instead while no goal had been rejected."""
    from vla_gr.agent.navigator.config import NotFoundConfig
    from vla_gr.agent.navigator.search import SearchCount

    count = SearchCount(NotFoundConfig(steps, new_area), -(-steps // plan_every))
    longer = None if unrejected is None else -(-unrejected // plan_every)  # planner ticks
    for tick in ticks:
        quiet = tick["committed"] or tick["mode"] in ("look_around", "stop")
        searched = count.update(quiet or way(tick), tick["explored"])
        if longer is not None and not tick["rejected"]:
            searched = count.ticks >= longer
        if searched:
            return tick["step"]
    return None


def _load(path: str) -> tuple[list[dict], list[dict]]:
    """(absent-object episodes, normal twins) of a traces file."""
    with open(path, encoding="utf-8") as f:
        rows = [json.loads(line) for line in f]
    return [r for r in rows if r["kind"] == "absent"], [r for r in rows if r["kind"] == "normal"]


def _scores(absent: list[dict], normal: list[dict], fire) -> str:
    """Table cells of one rule (``fire(ticks)``: the declaring step or None): absent episodes
    declared, their median step, normal ones declared and how many of those succeeded."""
    hit = [s for s in (fire(r["ticks"]) for r in absent) if s is not None]
    wrong = [r for r in normal if fire(r["ticks"]) is not None]
    median = int(np.median(hit)) if hit else "-"
    lost = sum(r["success"] > 0 for r in wrong)
    return f"{len(hit)}/{len(absent)} | {median} | {len(wrong)} | {lost}"


def replay_two_lengths(path: str, steps=(120, 180), unrejected=(180, 270, 360, 450, 600)):
    """Absent and normal episodes declared when the count needs longer while no goal was
    rejected in the episode."""
    absent, normal = _load(path)
    print("| steps (a goal rejected) | steps (none rejected) | absent declared | median step | "
          "normal declared | of them succeeded |")  # fmt: skip
    print("|---|---|---|---|---|---|")
    for short in steps:
        for long in unrejected:
            fire = functools.partial(fires, way=_own_radius, steps=short, new_area=2.0,
                                     unrejected=long)  # fmt: skip
            print(f"| {short} | {long} | {_scores(absent, normal, fire)} |")


def replay(path: str, lengths=(90, 150, 180, 200), areas=(float("inf"), 2.0)) -> None:
    absent, normal = _load(path)
    print("| rule | steps | new_area | absent declared | median step | normal declared | "
          "of them succeeded |")  # fmt: skip
    print("|---|---|---|---|---|---|---|")
    for name, way in RULES.items():
        for area in areas:
            for steps in lengths:
                fire = functools.partial(fires, way=way, steps=steps, new_area=area)
                print(f"| {name} | {steps} | {area} | {_scores(absent, normal, fire)} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    c = sub.add_parser("collect")
    c.add_argument("--split", default="val", choices=("train", "val", "test"))
    c.add_argument("--first", type=int, required=True)
    c.add_argument("--count", type=int, required=True)
    c.add_argument("--out", required=True)
    c.add_argument("--kinds", nargs="+", default=["absent", "normal"], choices=("absent", "normal"))
    r = sub.add_parser("replay")
    r.add_argument("traces")
    args = parser.parse_args()
    if args.command == "collect":
        collect(args.split, args.first, args.count, args.out, tuple(args.kinds))
    else:
        replay(args.traces)
        replay_two_lengths(args.traces)


if __name__ == "__main__":
    main()
