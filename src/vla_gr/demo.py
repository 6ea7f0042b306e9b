"""``vla-gr demo`` (``make demo``): the expert on a few episodes, a metrics table and pictures.

Writes to ``demo.output_dir``: ``episodes.jsonl`` (the specs, replayable),
``episode_XXX.gif`` (RGB | depth | top-down per step), ``episode_XXX_topdown.png``
(the whole trajectory) and ``metrics.json``; prints the metrics table to stdout.
"""

from __future__ import annotations

import json
import logging
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)


def _frame_images(env, obs: dict, size: int) -> tuple[np.ndarray, np.ndarray]:
    """RGB (S, S, 3) and depth (S, S) for the GIF: re-rendered at ``size`` when possible."""
    u = env.unwrapped
    if hasattr(u, "render_rgbd") and size != obs["rgb"].shape[0]:
        return u.render_rgbd(size)
    return obs["rgb"], obs["depth"]


def run_episode_with_pictures(env, expert, index: int, out_dir: Path, cfg_demo) -> dict:
    """Run the expert on episode ``index``; write its GIF and top-down PNG; return its record."""
    from vla_gr.envs.visualize import EpisodeRecorder, save_top_down_png

    obs, _ = env.reset(seed=index)
    expert.reset()
    u = env.unwrapped
    goal_id = int(u.goal.instance_id)
    start = np.asarray(u.start_pose_world, dtype=np.float64)  # (3,)
    max_depth = float(getattr(u, "max_depth", 5.0))
    recorder = EpisodeRecorder(u.house, goal_id, start, cfg_demo.gif_image_size, max_depth)
    size = cfg_demo.gif_image_size
    step, done, info = 0, False, {}
    recorder.add(*_frame_images(env, obs, size), u.robot_pose_world())
    while not done:
        obs, _, terminated, truncated, info = env.step(expert.act(obs))
        done = terminated or truncated
        step += 1
        if step % cfg_demo.gif_stride == 0 or done:
            recorder.add(*_frame_images(env, obs, size), u.robot_pose_world())
    stem = out_dir / f"episode_{index:03d}"
    recorder.save(stem.with_suffix(".gif"), fps=cfg_demo.gif_fps)
    save_top_down_png(
        f"{stem}_topdown.png",
        u.house,
        trajectory=np.asarray(u.trajectory_world),
        start=start,
        goal_id=goal_id,
        robot=u.robot_pose_world(),
        size=cfg_demo.png_size,
    )
    return {
        "episode_index": index,
        "instruction": u.episode_spec.instruction,
        "spec": u.episode_spec.to_dict(),
        "metrics": {k: (v.item() if isinstance(v, np.generic) else v) for k, v in info.items()},
        "gif_frames": len(recorder.frames),
    }


def run_demo(cfg) -> dict:
    """Run the demo for a validated ``VLAGRConfig``; returns the metrics.json content."""
    from vla_gr.data.collect import env_kwargs_from_config, make_env
    from vla_gr.envs.episodes import EpisodeSpec, save_episodes
    from vla_gr.envs.expert import GeodesicExpert
    from vla_gr.envs.metrics import aggregate, format_table

    d = cfg.demo
    out_dir = Path(d.output_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    env = make_env(env_kwargs_from_config(cfg, d.split, semantic=False))
    expert = GeodesicExpert(env, cfg.expert.noise_std, cfg.expert.noise_prob, seed=cfg.seed)
    t0 = time.perf_counter()
    episodes = []
    try:
        for k in range(d.first_episode, d.first_episode + d.num_episodes):
            episodes.append(run_episode_with_pictures(env, expert, k, out_dir, d))
            log.info(
                "episode %d: %s -> success %.0f",
                k,
                episodes[-1]["instruction"],
                episodes[-1]["metrics"].get("success", 0.0),
            )
    finally:
        env.close()
    save_episodes(out_dir / "episodes.jsonl", [EpisodeSpec.from_dict(e["spec"]) for e in episodes])
    infos = [e["metrics"] for e in episodes]
    summary = aggregate(infos)
    rows = {f"episode {e['episode_index']}": _row(e["metrics"]) for e in episodes}
    rows[f"expert (mean of {summary['episodes']})"] = _row(summary)
    table = format_table(rows)
    result = {
        "split": d.split,
        "aggregate": summary,
        "episodes": episodes,
        "seconds": time.perf_counter() - t0,
    }
    (out_dir / "metrics.json").write_text(json.dumps(result, indent=2))
    sys.stdout.write(table + "\n")
    sys.stdout.flush()
    log.info("wrote %s (GIFs, top-down PNGs, metrics.json) in %.1f s", out_dir, result["seconds"])
    return result


def _row(metrics: dict) -> dict:
    keys = ("success", "spl", "soft_spl", "collision_rate", "path_length", "distance_to_goal")
    return {k: metrics[k] for k in keys if k in metrics}


def run_from_cli(config_name: str, overrides: Sequence[str]) -> int:
    """``vla-gr demo [--config-name NAME] [key=value ...]``; returns the exit code."""
    from vla_gr.configs import load_config

    _, cfg = load_config(config_name, overrides)
    run_demo(cfg)
    return 0


if __name__ == "__main__":
    from vla_gr.configs.command import module_main

    sys.exit(module_main("demo", run_from_cli))
