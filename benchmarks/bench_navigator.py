"""S2 navigator + pure-pursuit follower with the TRUE goal mask: the planner's ceiling.

    python benchmarks/bench_navigator.py --split val --first 0 --episodes 50 --plan-every 3

Episodes ``first .. first + episodes - 1`` of a split run closed loop: every ``plan-every``
control steps the navigator ticks (GR field update + behaviour) on the goal likelihood
``semantic == goal instance`` (distractors of the same category are never goal pixels), and
the follower drives every step on the latest waypoints. Prints SR, SPL, soft SPL, collision
rate, steps, a failure breakdown and the tick latency; writes ``<out>.json`` and ``<out>.md``.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import time
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent
CAUSES = ("success", "stopped_wrong_place", "timeout_goal_never_seen",
          "timeout_goal_seen_not_confirmed", "timeout_goal_confirmed")  # fmt: skip


def failure_cause(record: dict) -> str:
    """One simple cause per episode (``success`` for a success)."""
    if record["success"]:
        return "success"
    if record["stopped"]:
        return "stopped_wrong_place"
    if record["committed_ever"]:
        return "timeout_goal_confirmed"
    if record["seen_ever"]:
        return "timeout_goal_seen_not_confirmed"
    return "timeout_goal_never_seen"


def save_pictures(out_dir: Path, k: int, env, nav, trajectory: list) -> None:
    """Top-down truth with the trajectory | the navigator's GR field, side by side (PNG)."""
    import imageio.v3 as iio
    from PIL import Image

    from vla_gr.envs.visualize import draw_top_down

    u = env.unwrapped
    truth = draw_top_down(u.house, np.array(trajectory), u.start_pose_world,
                          u.goal.instance_id, u.robot_pose_world(), 384, legend=False)  # fmt: skip
    fld = nav.field.render(0, scale=2)  # (2H, 2W, 3)
    fld = np.asarray(Image.fromarray(fld[::-1]).resize((384, 384), Image.NEAREST))
    out_dir.mkdir(parents=True, exist_ok=True)
    iio.imwrite(out_dir / f"episode_{k:04d}.png", np.concatenate([truth, fld], axis=1))


def run_episodes(indices, split, image_size, plan_every, max_steps, pictures) -> list[dict]:
    """Run navigator + follower on episodes ``indices`` in one env; per-episode records."""
    import gymnasium as gym
    import torch

    import vla_gr.envs  # noqa: F401  (registers VLAGR/ObjectNav-v0)
    from vla_gr.agent.followers.pure_pursuit import PurePursuit, PursuitConfig
    from vla_gr.agent.navigator.navigator import Navigator, NavigatorConfig

    torch.set_num_threads(1)
    env = gym.make("VLAGR/ObjectNav-v0", split=split, image_size=image_size, semantic=True,
                   max_episode_steps=max_steps)  # fmt: skip
    pursuit = PursuitConfig()
    nav = Navigator(NavigatorConfig(), plan_every=plan_every, lookahead=pursuit.lookahead)
    follower = PurePursuit(pursuit)
    records = []
    try:
        for k in indices:
            t0 = time.perf_counter()
            obs, info = env.reset(options={"episode": k})
            goal_id = env.unwrapped.episode_spec.goal_instance_id
            nav.reset()
            follower.reset()
            latencies, modes, trajectory = [], Counter(), [env.unwrapped.robot_pose_world()[:2]]
            committed_ever = seen_ever = False
            steps, terminated, truncated = 0, False, False
            while not (terminated or truncated):
                if steps % plan_every == 0:
                    like = (obs["semantic"] == goal_id).astype(np.float32)  # (H, W) true mask
                    plan = nav.plan(obs, like)
                    latencies.append(nav.last_latency)
                    modes[plan.mode] += 1
                    committed_ever |= nav.committed
                    seen_ever |= nav.ever_seen_goal
                    follower.set_plan(plan, obs["pose"])
                action = follower.act(obs["depth"], obs["pose"])
                obs, _, terminated, truncated, info = env.step(action)
                trajectory.append(env.unwrapped.robot_pose_world()[:2])
                steps += 1
            record = {key: (v.item() if isinstance(v, np.generic) else v)
                      for key, v in info.items()}  # fmt: skip
            record.update(
                episode_index=k, steps=steps, stopped=bool(terminated),
                committed_ever=committed_ever, seen_ever=seen_ever,
                recoveries=nav.recoveries, modes=dict(modes),
                latency_ms=[1e3 * t for t in latencies], wall_s=time.perf_counter() - t0,
            )  # fmt: skip
            record["cause"] = failure_cause(record)
            if pictures and record["cause"] != "success":
                save_pictures(Path(pictures), k, env, nav, trajectory)
            records.append(record)
            logging.getLogger("bench_navigator").info(
                "episode %d: %s spl %.2f steps %d coll %.3f rec %d modes %s", k,
                record["cause"], record["spl"], steps, record["collision_rate"],
                nav.recoveries, dict(modes),
            )  # fmt: skip
    finally:
        env.close()
    return records


def summarize(records: list[dict]) -> dict:
    from vla_gr.envs.metrics import aggregate

    summary = aggregate(records)
    summary["steps"] = float(np.mean([r["steps"] for r in records]))
    lat = np.concatenate([r["latency_ms"] for r in records])
    summary["tick_ms_p50"] = float(np.percentile(lat, 50))
    summary["tick_ms_p95"] = float(np.percentile(lat, 95))
    summary["recoveries"] = float(np.mean([r["recoveries"] for r in records]))
    counts = Counter(r["cause"] for r in records)
    summary["causes"] = {c: counts.get(c, 0) for c in CAUSES}
    return summary


def to_markdown(results: dict) -> str:
    from vla_gr.machine import machine_line

    s = results["summary"]
    lines = [
        f"# Navigator with the true goal mask ({results['split']} "
        f"{results['first']}–{results['first'] + results['episodes'] - 1}, "
        f"plan_every {results['plan_every']})",
        "",
        f"`{results['command']}`",
        "",
        "| episodes | SR | SPL | soft SPL | collision rate | steps | recoveries | "
        "tick p50 ms | tick p95 ms |",
        "|---|---|---|---|---|---|---|---|---|",
        f"| {s['episodes']} | {s['success']:.3f} | {s['spl']:.3f} | {s['soft_spl']:.3f} | "
        f"{s['collision_rate']:.3f} | {s['steps']:.0f} | {s['recoveries']:.2f} | "
        f"{s['tick_ms_p50']:.1f} | {s['tick_ms_p95']:.1f} |",
        "",
        "| cause | episodes |",
        "|---|---|",
        *[f"| {c} | {n} |" for c, n in s["causes"].items()],
        "",
        f"{machine_line(results['machine'])} Workers: {results['workers']}; torch threads 1; "
        f"wall {results['wall_s']:.0f} s.",
        "",
    ]
    return "\n".join(lines)


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--split", default="val")
    parser.add_argument("--first", type=int, default=0)
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--plan-every", type=int, default=3)
    parser.add_argument("--workers", type=int, default=1, choices=(1, 2))
    parser.add_argument("--max-steps", type=int, default=1000)
    parser.add_argument("--image-size", type=int, default=64)
    parser.add_argument("--pictures", default="", help="folder for failure pictures")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    if args.plan_every < 1:
        parser.error("--plan-every must be >= 1")
    out = args.out or ROOT / "results" / (
        f"bench_navigator_{args.split}{args.first}-{args.first + args.episodes - 1}"
        f"_pe{args.plan_every}"
    )
    indices = list(range(args.first, args.first + args.episodes))
    job = (args.split, args.image_size, args.plan_every, args.max_steps, args.pictures)
    t0 = time.perf_counter()
    if args.workers == 1:
        records = run_episodes(indices, *job)
    else:
        chunks = [indices[w :: args.workers] for w in range(args.workers)]
        with ProcessPoolExecutor(args.workers, mp_context=get_context("spawn")) as pool:
            futures = [pool.submit(run_episodes, chunk, *job) for chunk in chunks]
            records = [r for f in futures for r in f.result()]
    records.sort(key=lambda r: r["episode_index"])
    from vla_gr.machine import describe_machine

    results = {
        "command": "python benchmarks/bench_navigator.py "
        f"--split {args.split} --first {args.first} --episodes {args.episodes} "
        f"--plan-every {args.plan_every} --workers {args.workers} --max-steps {args.max_steps}",
        "split": args.split, "first": args.first, "episodes": args.episodes,
        "plan_every": args.plan_every, "workers": args.workers,
        "machine": describe_machine(),
        "wall_s": time.perf_counter() - t0,
        "summary": summarize(records),
        "episodes_detail": [{k: v for k, v in r.items() if k != "latency_ms"} for r in records],
    }  # fmt: skip
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(results, indent=2) + "\n")
    text = to_markdown(results)
    out.with_suffix(".md").write_text(text)
    print(text)
    return results


if __name__ == "__main__":
    main()
