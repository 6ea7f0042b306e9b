"""The evaluation harness: plan the episodes of an eval config, run an agent on them in
worker processes (resumable), write ``episodes.jsonl``, ``metrics.json``, ``report.md`` and
``report.html`` (with episode videos), and compare several agents on the same episodes.
``vla-gr eval`` (:mod:`vla_gr.evaluate`) is its command line; training's pipeline is handed
:func:`evaluate` for its rollout stages.
"""

from __future__ import annotations

import hashlib
import json
import logging
import shutil
import time
from collections.abc import Sequence
from pathlib import Path

from vla_gr.errors import UserError

log = logging.getLogger(__name__)

__all__ = ["DEFAULT_SPLIT_EPISODES", "EvalInputError", "compare", "evaluate", "plan_episodes"]

DEFAULT_SPLIT_EPISODES = 10


class EvalInputError(UserError, ValueError):
    """Bad input found before any episode runs (one line, naming the key or file)."""


def plan_episodes(cfg) -> tuple[list[int], dict, str]:
    """(episode indices, env kwargs, source name) of an eval config; EvalInputError if bad."""
    from vla_gr.data.collect import env_kwargs_from_config
    from vla_gr.envs.episodes import EPISODES_PER_SCENE, load_episodes
    from vla_gr.envs.house import SPLIT_SIZE

    e = cfg.eval
    env_kwargs = env_kwargs_from_config(cfg, e.split, semantic=True)
    env_kwargs.pop("episodes", None)
    if e.episodes:
        try:
            size = len(load_episodes(e.episodes))
        except ValueError as err:
            raise EvalInputError(str(err)) from None
        env_kwargs["episodes"] = str(e.episodes)
        source, what = str(e.episodes), f"episodes file {e.episodes}"
    else:
        size = SPLIT_SIZE * EPISODES_PER_SCENE
        source, what = e.split, f"split {e.split!r}"
    num = e.num_episodes or (size - e.first_episode if e.episodes else DEFAULT_SPLIT_EPISODES)
    if e.first_episode + num > size:
        raise EvalInputError(
            f"eval.first_episode={e.first_episode} + eval.num_episodes={num} exceeds the "
            f"{size} episodes of {what}"
        )
    return list(range(e.first_episode, e.first_episode + num)), env_kwargs, source


def run_header(cfg, agent: str, source: str, indices: Sequence[int]) -> dict:
    """The settings that define an eval run (saved as ``run.json``; compared on resume).

    A variant's header also names the registered agent it builds on (``base_agent``).
    """
    from vla_gr import __version__
    from vla_gr.evaluation.agents import agent_checkpoint, resolve_agent

    base, sub = resolve_agent(agent, cfg)
    checkpoint = agent_checkpoint(base, sub)
    e, env = cfg.eval, cfg.env
    return {
        "agent": agent,
        **({"base_agent": base} if base != agent else {}),
        "checkpoint": checkpoint,
        # what the path held: a run resumed on a checkpoint rewritten in place is refused
        "checkpoint_digest": checkpoint_digest(checkpoint) if checkpoint else None,
        "model_overrides": list(sub.eval.model_overrides) if checkpoint else [],
        "episodes_source": source,
        "first_episode": indices[0],
        "num_episodes": len(indices),
        "seed": cfg.seed,
        "env": {
            "image_size": env.image_size,
            "control_hz": env.control_hz,
            "max_episode_steps": env.max_episode_steps,
            "success_distance": env.success_distance,
            "max_depth": env.max_depth,
            "depth_noise_std": env.depth_noise_std,
            "actuation_noise": env.actuation_noise,
            "num_rooms": env.num_rooms,
            "clutter": env.clutter,
            # recorded when not the default, so runs made before styles existed still resume
            **({"house_style": env.house_style} if env.house_style != "default" else {}),
        },
        "thresholds": {
            "goal_seen_pixels": e.goal_seen_pixels,
            "stuck_steps": e.stuck_steps,
            "stuck_radius": e.stuck_radius,
        },
        "vla_gr_version": __version__,
    }


def checkpoint_digest(path: str | Path) -> str | None:
    """SHA-256 over the weights' and config's hashes in checkpoint ``path``'s manifest (what
    an agent loaded from it does); None for a folder without a manifest."""
    manifest = Path(path) / "manifest.json"
    if not manifest.is_file():
        return None
    try:
        files = json.loads(manifest.read_text())["files"]
        hashes = {name: files[name]["sha256"] for name in ("config.yaml", "model.safetensors")}
    except (ValueError, KeyError, TypeError) as err:
        raise EvalInputError(f"checkpoint {path}: unreadable manifest.json ({err})") from err
    return hashlib.sha256(json.dumps(hashes, sort_keys=True).encode()).hexdigest()


def default_agent(cfg) -> str:
    """``eval.agent``, else ``checkpoint`` when ``eval.checkpoint`` is given, else ``expert``."""
    return cfg.eval.agent or ("checkpoint" if cfg.eval.checkpoint else "expert")


def _output_dir(cfg, agent: str, source: str) -> Path:
    if cfg.eval.output_dir:
        return Path(cfg.eval.output_dir)
    stamp = time.strftime("%Y%m%d-%H%M%S")
    return Path("outputs/eval") / f"{agent}-{Path(source).stem}-{stamp}"


def _resume_rows(out_dir: Path, header: dict, indices: Sequence[int]) -> list[dict]:
    """Finished rows of an earlier run of the same settings in ``out_dir`` (else [])."""
    from vla_gr.evaluation.runner import read_rows

    run_file = out_dir / "run.json"
    if not run_file.is_file():
        return []
    old = json.loads(run_file.read_text())
    changed = [k for k in header if old.get(k) != header[k] and k != "num_episodes"]
    if changed:
        key = changed[0]
        raise EvalInputError(
            f"output folder {out_dir} holds a run with {key}={old.get(key)!r}, this one has "
            f"{key}={header[key]!r}; pass another output_dir"
        )
    wanted = set(indices)
    rows = [r for r in read_rows(out_dir / "episodes.jsonl") if r["episode_index"] in wanted]
    if rows:
        log.info("resuming %s: %d of %d episodes already done", out_dir, len(rows), len(indices))
    return rows


def evaluate(cfg, agent: str | None = None) -> dict:
    """Run one agent's evaluation for a validated ``VLAGRConfig``; returns metrics.json."""
    from tqdm import tqdm

    from vla_gr.data.collect import make_env
    from vla_gr.evaluation.agents import check_agent
    from vla_gr.evaluation.report import replay_pictures, select_episodes, write_report
    from vla_gr.evaluation.runner import RowWriter, iter_episode_rows
    from vla_gr.evaluation.summary import summarize_rows
    from vla_gr.machine import describe_machine

    agent = agent or default_agent(cfg)
    check_agent(agent, cfg)
    indices, env_kwargs, source = plan_episodes(cfg)
    header = run_header(cfg, agent, source, indices)
    out_dir = _output_dir(cfg, agent, source)
    out_dir.mkdir(parents=True, exist_ok=True)
    done = {r["episode_index"]: r for r in _resume_rows(out_dir, header, indices)}
    (out_dir / "run.json").write_text(json.dumps(header, indent=1))
    writer = RowWriter(out_dir / "episodes.jsonl", list(done.values()))
    todo = [k for k in indices if k not in done]
    t0 = time.perf_counter()
    successes = sum(r["metrics"]["success"] for r in done.values())
    bar = tqdm(
        total=len(indices), initial=len(done), desc=f"eval {agent}", unit="ep",
        disable=not cfg.eval.progress,
    )  # fmt: skip
    no_episode: dict[int, str] = {}  # index -> why its house hosts no episode
    try:
        with bar:
            for row in iter_episode_rows(cfg, agent, env_kwargs, todo, cfg.eval.workers):
                bar.update(1)
                if "no_episode" in row:
                    no_episode[row["episode_index"]] = row["no_episode"]
                    continue
                writer.write(row)
                done[row["episode_index"]] = row
                successes += row["metrics"]["success"]
                bar.set_postfix(SR=f"{successes / len(done):.2f}")
    finally:
        writer.close()
    if no_episode:
        log.warning(
            "%d of %d episode indices skipped, their house hosts no episode: %s",
            len(no_episode), len(indices), "; ".join(f"{k}: {v}" for k, v in no_episode.items()),
        )  # fmt: skip
    rows = [done[k] for k in indices if k in done]
    if not rows:
        first, last = indices[0], indices[-1]
        raise EvalInputError(f"no episode to run: no house of {source} {first}-{last} hosts one")
    seconds = time.perf_counter() - t0
    metrics = summarize_rows(
        rows, header, seconds, cfg.eval.workers, ran=len(todo) - len(no_episode),
        machine=describe_machine(),
    )  # fmt: skip
    metrics["timing"]["backend"] = cfg.eval.backend  # where the episodes ran (local, ray)
    # (index -> why), so that "num_episodes" above and "episodes" in "metrics" add up
    metrics["skipped_episodes"] = {str(k): v for k, v in sorted(no_episode.items())}
    (out_dir / "metrics.json").write_text(json.dumps(metrics, indent=1))
    e = cfg.eval
    chosen = rows if e.video_all else select_episodes(rows, e.video_successes, e.video_per_cause)
    pictures = {}
    if chosen:
        video = shutil.which("ffmpeg") is not None
        if not video:
            log.warning("no ffmpeg on PATH: the report has no videos (apt-get install ffmpeg)")
        env = make_env({**env_kwargs, "semantic": False})
        try:
            for row in chosen:
                pictures[row["episode_index"]] = replay_pictures(
                    env, row, out_dir, e.video_panel, e.video_stride, video
                )
        finally:
            env.close()
    write_report(out_dir, metrics, rows, pictures)
    log.info("wrote %s (metrics.json, episodes.jsonl, report.md, report.html)", out_dir)
    return metrics


def compare(cfg) -> dict:
    """Run every agent of ``eval.agents`` on the same episodes; write compare.md/json.
    Returns the output folder, the table, its rows and each agent's metrics.json."""
    import dataclasses

    from vla_gr.envs.metrics import format_table
    from vla_gr.evaluation.agents import check_agent
    from vla_gr.evaluation.report import agent_row, agents_table, table_row

    agents = list(cfg.eval.agents)
    for agent in agents:  # every input error (variants included) before the first episode
        check_agent(agent, cfg)
    _, _, source = plan_episodes(cfg)
    out_dir = _output_dir(cfg, "compare", source)
    rows, setups, runs = {}, {}, {}
    for agent in agents:
        sub = dataclasses.replace(cfg.eval, output_dir=str(out_dir / agent))
        runs[agent] = metrics = evaluate(dataclasses.replace(cfg, eval=sub), agent)
        rows[agent], setups[agent] = table_row(metrics), agent_row(metrics)
    table = format_table(rows)
    both = {k: {**setups[k], **rows[k]} for k in agents}
    (out_dir / "compare.json").write_text(json.dumps(both, indent=1))
    (out_dir / "compare.md").write_text(
        f"# Comparison on {source}\n\n{table}\n\n## Agents\n\n{agents_table(setups)}\n"
    )
    return {"output_dir": str(out_dir), "table": table, "rows": both, "metrics": runs}
