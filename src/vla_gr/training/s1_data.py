"""S1's training data: the agent's own rollouts, relabelled by the privileged local teacher.

One round: ``vla-gr eval`` rolls the agent out on ``train`` episodes and records its actions;
:func:`relabel_episode` replays them with the agent's S2 running on its usual schedule, and at
every control step writes what S1 would read (the RGB-D pooled to ``model.s1.image_size``, the
plan vector of :mod:`vla_gr.agent.followers.s1_inputs`) and what the
:class:`~vla_gr.envs.local_teacher.LocalTeacher` would do there (drive to S2's current
waypoint on the true map; STOP only when S2 asks and the goal is inside success distance).
The labels never point at anything the agent has not observed: the teacher follows S2.


A data folder holds ``part-*.safetensors`` (arrays: ``rgb`` (N, 3, s, s) uint8, ``depth``
(N, 1, s, s) float16 metres, ``plan`` (N, P) float32, ``teacher`` (N, 3) float32 (v, w, stop),
``episode`` (N,) int64) and ``manifest.json`` with each part's sha256; :func:`load_s1_data`
verifies them and refuses parts made for another S1 layout.

A recipe's ``s1_data`` stage runs it (inputs: the rollouts, the agent that made them).
"""

from __future__ import annotations

import json
import logging
import multiprocessing as mp
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from safetensors.numpy import load_file, save_file

from vla_gr.agent.followers.s1_inputs import PlanMemory, pool_rgbd
from vla_gr.checkpoint import sha256_file
from vla_gr.data.collect import make_env
from vla_gr.errors import UserError
from vla_gr.training.dagger import check_replay_end, train_run

log = logging.getLogger(__name__)

__all__ = ["S1_ARRAYS", "load_s1_data", "relabel_episode", "relabel_run", "write_s1_part"]

FORMAT = "vla-gr-s1-data"
VERSION = 1
S1_ARRAYS = ("rgb", "depth", "plan", "teacher", "episode")


def relabel_episode(env, policy, teacher, row: dict) -> dict[str, np.ndarray]:
    """Replay one recorded episode; S1's inputs and the teacher's labels at every step."""
    s1 = policy.config.s1
    index = int(row["episode_index"])
    obs, _ = env.reset(options={"episode": index})
    policy.reset()
    teacher.reset()
    system = policy.dual_system
    memory = PlanMemory(s1.path_points)
    rgbs, depths, plans, labels = [], [], [], []
    for t, action in enumerate(row["actions"]):
        pose = np.asarray(obs["pose"], dtype=np.float64)  # (3,)
        if system.plan_if_due(obs) is not None:
            memory.set_plan(system.plan, pose, t)
        small_rgb, small_depth = pool_rgbd(obs["rgb"], obs["depth"], s1.image_size)
        plan = system.plan
        waypoints = memory.waypoints_world
        labels.append(
            teacher.act(
                pose,
                np.zeros((0, 2)) if waypoints is None else waypoints,
                command=plan.command,
                stop_requested=bool(plan.stop),
            )
        )  # (3,)
        rgbs.append(small_rgb)  # (3, s, s)
        depths.append(small_depth.astype(np.float16))  # (1, s, s)
        plans.append(memory.vector(pose, t))  # (P,)
        system.steps += 1
        obs, _, terminated, truncated, _ = env.step(np.asarray(action, dtype=np.float32))
        if terminated or truncated:
            break
    check_replay_end(env, row)
    return {
        "rgb": np.stack(rgbs),  # (T, 3, s, s)
        "depth": np.stack(depths),  # (T, 1, s, s)
        "plan": np.stack(plans).astype(np.float32),  # (T, P)
        "teacher": np.stack(labels).astype(np.float32),  # (T, 3)
        "episode": np.full(len(rgbs), index, np.int64),  # (T,)
    }


# ----------------------------------------------------------------------------- workers

_WORKER: dict = {}


def _init_worker(checkpoint: str, env_kwargs: dict) -> None:
    import torch

    from vla_gr.envs.local_teacher import LocalTeacher
    from vla_gr.policy import VLAGRPolicy

    torch.set_num_threads(1)
    env = make_env(env_kwargs)
    _WORKER.update(
        env=env, policy=VLAGRPolicy.from_pretrained(checkpoint), teacher=LocalTeacher(env)
    )


def _work(row: dict) -> dict[str, np.ndarray]:
    return relabel_episode(_WORKER["env"], _WORKER["policy"], _WORKER["teacher"], row)


def relabel_run(
    run_dir: str | Path, checkpoint: str | Path, out_dir: str | Path, workers: int = 1
) -> dict:
    """Relabel every episode of eval run ``run_dir`` (made with this agent) into ``out_dir``."""
    from vla_gr.policy import VLAGRPolicy

    out = Path(out_dir)
    if (out / "manifest.json").exists():
        raise UserError(f"{out} already holds S1 data; choose a new folder for this round")
    _, rows, env_kwargs = train_run(run_dir)
    env_kwargs = env_kwargs | {"semantic": False}
    s1 = VLAGRPolicy.from_pretrained(checkpoint).config.s1
    args = (str(checkpoint), env_kwargs)
    parts: list[dict[str, np.ndarray]] = []
    if workers <= 1:
        _init_worker(*args)
        parts = [_work(row) for row in rows]
    else:
        ctx = mp.get_context("spawn")
        with ctx.Pool(workers, initializer=_init_worker, initargs=args) as pool:
            parts = list(pool.imap(_work, rows))
    arrays = {k: np.concatenate([p[k] for p in parts]) for k in S1_ARRAYS}
    return write_s1_part(out, "part-0000", arrays, s1, source=str(run_dir))


def _layout(s1) -> dict:
    from vla_gr.agent.followers.s1_inputs import plan_vector_size

    return {
        "image_size": int(s1.image_size),
        "path_points": [float(p) for p in s1.path_points],
        "plan_dim": plan_vector_size(s1.path_points),
    }


def write_s1_part(out_dir: str | Path, name: str, arrays: dict, s1, source: str = "") -> dict:
    """Write ``arrays`` (the :data:`S1_ARRAYS`) as part ``name`` of the data folder ``out_dir``
    for S1 config ``s1``; returns the manifest."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    missing = [k for k in S1_ARRAYS if k not in arrays]
    if missing:
        raise ValueError(f"S1 data part {name} lacks arrays {missing}")
    n = len(arrays["episode"])
    if any(len(arrays[k]) != n for k in S1_ARRAYS):
        raise ValueError(f"S1 data part {name}: arrays of different lengths")
    path = out / f"{name}.safetensors"
    save_file({k: np.ascontiguousarray(arrays[k]) for k in S1_ARRAYS}, str(path))
    manifest_path = out / "manifest.json"
    manifest = (
        json.loads(manifest_path.read_text())
        if manifest_path.exists()
        else {"format": FORMAT, "version": VERSION, **_layout(s1), "parts": {}}
    )
    if {k: manifest[k] for k in _layout(s1)} != _layout(s1):
        raise UserError(f"{out} holds S1 data of another layout ({manifest_path})")
    manifest["parts"][path.name] = {
        "sha256": sha256_file(path),
        "frames": n,
        "episodes": int(len(np.unique(arrays["episode"]))),
        "stops": int((arrays["teacher"][:, 2] > 0).sum()),
        "source": source,
    }
    manifest_path.write_text(json.dumps(manifest, indent=1))
    log.info("S1 data %s: %d frames of %s", path, n, source)
    return manifest


def load_s1_data(folders: Sequence[str | Path], s1) -> dict[str, np.ndarray]:
    """Every part of every folder, verified against its manifest and S1 config ``s1``.

    Episode ids are made unique across parts (``episode`` counts parts in its high digits).
    """
    merged: dict[str, list[np.ndarray]] = {k: [] for k in S1_ARRAYS}
    part_index = 0
    for folder in folders:
        folder = Path(folder)
        manifest_path = folder / "manifest.json"
        if not manifest_path.is_file():
            raise UserError(f"{folder} is not an S1 data folder (no manifest.json)")
        manifest = json.loads(manifest_path.read_text())
        if manifest.get("format") != FORMAT or manifest.get("version") != VERSION:
            raise UserError(f"{manifest_path}: not {FORMAT} version {VERSION}")
        layout = {k: manifest.get(k) for k in _layout(s1)}
        if layout != _layout(s1):
            raise UserError(
                f"{folder} was made for S1 inputs {layout}, this model reads {_layout(s1)}"
            )
        for name, meta in sorted(manifest["parts"].items()):
            path = folder / name
            if not path.is_file() or sha256_file(path) != meta["sha256"]:
                raise UserError(f"{path} is missing or damaged (sha256 differs from manifest)")
            arrays = load_file(str(path))
            if len(arrays["episode"]) != meta["frames"]:
                raise UserError(
                    f"{path}: {len(arrays['episode'])} frames, manifest says {meta['frames']}"
                )
            arrays["episode"] = arrays["episode"] + part_index * 10**9
            for k in S1_ARRAYS:
                merged[k].append(arrays[k])
            part_index += 1
    if not part_index:
        raise UserError(f"no S1 data in {list(map(str, folders))}")
    return {k: np.concatenate(v) for k, v in merged.items()}
