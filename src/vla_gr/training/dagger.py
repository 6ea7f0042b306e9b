"""DAgger data: the states the agent itself reached, labelled by the world, aggregated.

One round: ``vla-gr eval`` rolls the agent out on ``train`` episodes (never ``val`` or
``test``) and records its actions in ``episodes.jsonl``; :func:`relabelled_records` replays
those actions in the same deterministic episodes with the instance segmentation on, so every
frame the agent saw gets its true goal mask and distractor mask (what the goal head must
learn, now on the agent's own views: the rooms it explores, the objects it mistook for the
goal); :func:`aggregate` appends them to a copy of the training store. Retrain on the result
(``training.dataset=<it> training.init_from=<checkpoint>``) and keep the round only if it
helps on ``val``.

The stored action of a frame is the action the agent executed there (the goal head does not
read actions; a learned S1 would be relabelled by its teacher instead).

A recipe's ``rollout`` then ``dagger`` stages run it (inputs: the rollouts, the base store).
"""

from __future__ import annotations

import json
import logging
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np

from vla_gr.data.collect import make_env, run_expert_episode
from vla_gr.data.store import EpisodeRecord, EpisodeStore
from vla_gr.errors import UserError

log = logging.getLogger(__name__)

__all__ = ["ReplayDriver", "aggregate", "check_replay_end", "relabelled_records", "train_run"]


class ReplayDriver:
    """Plays back recorded actions (T, 3) with the interface collection drives episodes with."""

    def __init__(self, actions: Sequence[Sequence[float]]) -> None:
        self.actions = np.asarray(actions, dtype=np.float32).reshape(-1, 3)  # (T, 3)
        self.rng = np.random.default_rng(0)  # unused: the replay is deterministic
        self.reset()

    def reset(self) -> None:
        self.t = 0
        self.last_label = np.zeros(3, np.float32)

    def act(self, obs) -> np.ndarray:
        if self.t >= len(self.actions):
            raise RuntimeError("the replay ran past the recorded actions (env not deterministic?)")
        action = np.clip(self.actions[self.t], -1.0, 1.0)  # (3,)
        self.t += 1
        self.last_label = action
        return action


def _run_rows(run_dir: Path) -> tuple[dict, list[dict]]:
    header_path, rows_path = run_dir / "run.json", run_dir / "episodes.jsonl"
    if not header_path.is_file() or not rows_path.is_file():
        raise UserError(f"{run_dir} is not a vla-gr eval run folder (run.json, episodes.jsonl)")
    header = json.loads(header_path.read_text())
    rows = [json.loads(line) for line in rows_path.read_text().splitlines() if line.strip()]
    return header, rows


def train_run(run_dir: str | Path) -> tuple[dict, list[dict], dict]:
    """``(header, rows, env_kwargs)`` of an eval run that must have run on ``train`` episodes;
    ``env_kwargs`` rebuild its env (with instance segmentation) for a replay."""
    header, rows = _run_rows(Path(run_dir))
    source = header["episodes_source"]
    if not source.startswith("train"):
        raise UserError(
            f"{run_dir} ran on {source!r}: DAgger data must come from train episodes only"
        )
    env_keys = ("image_size", "control_hz", "max_episode_steps", "success_distance")
    env_kwargs = {k: header["env"][k] for k in env_keys} | {"split": "train", "semantic": True}
    env_kwargs["house_style"] = header["env"].get("house_style", "default")  # the run's look
    return header, rows, env_kwargs


def check_replay_end(env, row: dict) -> None:
    """Raise if the replayed episode did not end where the recorded run ended."""
    end = env.unwrapped.robot_pose_world()[:2]
    if not np.allclose(end, row["trace"]["xy"][-1], atol=1e-3):
        raise RuntimeError(f"episode {row['episode_index']}: the replay ended elsewhere")


def relabelled_records(run_dir: str | Path) -> Iterator[EpisodeRecord]:
    """One record per episode of an eval run on ``train`` episodes: the agent's frames with
    their true goal and distractor masks (replayed; must end where the run ended)."""
    _, rows, env_kwargs = train_run(run_dir)
    env = make_env(env_kwargs)
    try:
        for row in rows:
            record, info = run_expert_episode(
                env, ReplayDriver(row["actions"]), row["episode_index"]
            )
            check_replay_end(env, row)
            yield record
    finally:
        env.close()


def aggregate(run_dir: str | Path, base_store: str | Path, out_store: str | Path) -> dict:
    """Copy ``base_store`` to ``out_store`` and append the run's relabelled episodes."""
    from vla_gr.data.verify import copy_store

    out = Path(out_store)
    if out.exists():
        raise UserError(f"{out} exists; choose a new store for this DAgger round")
    _, rows = _run_rows(Path(run_dir))
    shared = set(EpisodeStore.open(base_store).episode_indices.tolist())
    shared &= {row["episode_index"] for row in rows}
    if shared:
        raise UserError(
            f"{base_store} already holds train episodes {sorted(shared)[:5]}: roll the agent "
            "out on other train episodes (eval first_episode=...)"
        )
    copy_store(Path(base_store), out)
    store = EpisodeStore.open(out, mode="a")
    before = store.num_episodes
    frames = 0
    for record in relabelled_records(run_dir):
        store.append(record)
        frames += len(record)
    summary = {
        "store": str(out),
        "base_episodes": before,
        "added_episodes": store.num_episodes - before,
        "added_frames": frames,
    }
    log.info("DAgger round: %s", summary)
    return summary
