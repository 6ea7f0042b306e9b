"""``vla-gr collect``: run the geodesic expert on a range of episodes and write a zarr store.

Episodes run in ``collect.workers`` worker processes (multiprocessing 'spawn': MuJoCo GL
contexts do not survive fork) and are written in episode order by the main process, one
committed episode at a time (see ``data.store``), so an interrupted run loses at most the
episodes in flight. With ``collect.backend=ray`` the workers are Ray actors on a cluster
(``collect.ray_address``; :mod:`vla_gr.data.ray_workers`) and the records come back to this
process, which writes the store. The expert may execute DART-noised actions (``expert.noise_std``,
``expert.noise_prob``); the store keeps its noise-free label for the same observation.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import sys
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path

import numpy as np

from vla_gr import __version__
from vla_gr.data.store import EpisodeRecord, EpisodeStore, StoreError
from vla_gr.errors import ConfigError

log = logging.getLogger(__name__)


def env_kwargs_from_config(cfg, split: str, semantic: bool = True) -> dict:
    """Keyword arguments of ``gymnasium.make("VLAGR/ObjectNav-v0", ...)`` from a VLAGRConfig."""
    kwargs = {
        "split": split,
        "image_size": cfg.env.image_size,
        "control_hz": cfg.env.control_hz,
        "max_episode_steps": cfg.env.max_episode_steps,
        "success_distance": cfg.env.success_distance,
        "semantic": semantic,
        "max_depth": cfg.env.max_depth,
        "num_rooms": cfg.env.num_rooms,
        "clutter": cfg.env.clutter,
        "scene_cache_size": cfg.env.scene_cache_size,
        "depth_noise_std": cfg.env.depth_noise_std,
        "actuation_noise": cfg.env.actuation_noise,
        "house_style": cfg.env.house_style,
    }
    if cfg.env.episodes:
        kwargs["episodes"] = cfg.env.episodes
    return kwargs


def make_env(env_kwargs: dict):
    """A ``VLAGR/ObjectNav-v0`` env (registration happens on ``import vla_gr.envs``)."""
    import gymnasium as gym

    from vla_gr.envs import ENV_ID

    return gym.make(ENV_ID, **env_kwargs)


def _jsonable(value):
    """Plain-Python copy of an info value (numpy scalars/arrays -> float/int/list)."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


def run_expert_episode(env, expert, index: int, seed: int = 0) -> tuple[EpisodeRecord, dict]:
    """Run ``expert`` on episode ``index`` of ``env``'s split; returns (record, final info).

    Step t stores the observation before action t and the expert's noise-free label for it;
    the executed action may be noisy. ``seed`` and ``index`` seed the expert's noise.
    The env must be made with ``semantic=True`` (for the goal and distractor masks).
    """
    from vla_gr.envs.instructions import distractors

    expert.rng = np.random.default_rng((seed, index))
    obs, info = env.reset(options={"episode": index})
    if "semantic" not in obs:
        raise ValueError("the env must be made with semantic=True to record goal masks")
    expert.reset()
    u = env.unwrapped
    goal_id = int(u.goal.instance_id)
    distractor_ids = np.asarray(distractors(u.house, goal_id), dtype=np.int32)  # (K,)
    rgb, depth, pose, mask, others, labels = [], [], [], [], [], []
    done = False
    while not done:
        action = expert.act(obs)  # (3,) executed
        rgb.append(obs["rgb"])  # (H, W, 3)
        depth.append(obs["depth"])  # (H, W, 1)
        pose.append(obs["pose"])  # (3,)
        mask.append(obs["semantic"] == goal_id)  # (H, W)
        others.append(np.isin(obs["semantic"], distractor_ids))  # (H, W)
        labels.append(np.asarray(expert.last_label, dtype=np.float32))  # (3,)
        obs, _, terminated, truncated, info = env.step(action)
        done = terminated or truncated
    spec = u.episode_spec.to_dict()
    record = EpisodeRecord(
        episode_index=index,
        rgb=np.stack(rgb),  # (T, H, W, 3)
        depth=np.stack(depth),  # (T, H, W, 1)
        pose=np.stack(pose),  # (T, 3)
        action=np.stack(labels),  # (T, 3)
        goal_mask=np.stack(mask),  # (T, H, W)
        distractor_mask=np.stack(others),  # (T, H, W)
        instruction=str(spec.get("instruction", obs.get("instruction", ""))),
        spec=_jsonable(spec),
        metrics=_jsonable(info),
    )
    return record, record.metrics


# ----------------------------------------------------------------------------- workers

_WORKER: dict = {}


def _init_worker(env_kwargs: dict, expert_kwargs: dict, seed: int) -> None:
    """Per-process env + expert, made once and reused for every episode of the worker."""
    from vla_gr.envs.expert import GeodesicExpert

    env = make_env(env_kwargs)
    _WORKER.update(env=env, expert=GeodesicExpert(env, **expert_kwargs), seed=seed)


def _work(index: int) -> EpisodeRecord | int:
    """The record of episode ``index``, or the index itself when its house cannot host one."""
    from vla_gr.envs.episodes import NoEpisodeError

    try:
        record, _ = run_expert_episode(_WORKER["env"], _WORKER["expert"], index, _WORKER["seed"])
    except NoEpisodeError as err:
        log.warning("episode %d skipped: %s", index, err)
        return index
    return record


def _close_worker() -> None:
    _WORKER.pop("env").close()
    _WORKER.clear()


def map_in_workers(
    init: Callable, init_args: tuple, work: Callable, items: Sequence, workers: int, close: Callable
) -> Iterator:
    """``work(item)`` for each of ``items``, yielded in that order, from ``workers`` processes.

    Each spawned process runs ``init(*init_args)`` once (its env, its agent). With
    ``workers == 1`` everything runs in this process and ``close()`` tears it down after.
    """
    if workers < 1:
        raise ValueError(f"workers={workers} must be >= 1")
    if not items:
        return
    if workers == 1 or len(items) <= 1:
        init(*init_args)
        try:
            for item in items:
                yield work(item)
        finally:
            close()
        return
    ctx = mp.get_context("spawn")
    n = min(workers, len(items))
    with ctx.Pool(n, initializer=init, initargs=init_args) as pool:
        yield from pool.imap(work, items, chunksize=1)


def iter_expert_episodes(
    indices: Sequence[int],
    env_kwargs: dict,
    expert_kwargs: dict,
    seed: int = 0,
    workers: int = 1,
    backend: str = "local",
    ray_address: str | None = None,
) -> Iterator[EpisodeRecord]:
    """Records of episodes ``indices``, in that order, from ``workers`` spawned processes;
    an index whose house cannot host an episode (``NoEpisodeError``) comes back as the int.

    With ``workers == 1`` everything runs in this process. ``backend="ray"``: the workers are
    Ray actors on the cluster at ``ray_address`` (:func:`~vla_gr.data.ray_workers.map_on_ray`),
    whose records come back here.
    """
    if backend == "ray":
        from vla_gr.data.ray_workers import map_on_ray, portable_env_kwargs

        init_args = (portable_env_kwargs(env_kwargs), expert_kwargs, seed)
        yield from map_on_ray(
            _init_worker, init_args, _work, indices, workers, _close_worker, ray_address,
            "collect",
        )  # fmt: skip
        return
    init_args = (env_kwargs, expert_kwargs, seed)
    yield from map_in_workers(_init_worker, init_args, _work, indices, workers, _close_worker)


# ----------------------------------------------------------------------------- the command


def open_output_store(path: Path, mode: str, image_size: int, info: dict) -> EpisodeStore:
    """Create or open the output store according to ``mode`` (refuse | append | overwrite)."""
    if mode not in ("refuse", "append", "overwrite"):
        raise ValueError(f"collect.mode={mode!r} is not valid; choose refuse, append, overwrite")
    if path.exists():
        if mode == "refuse":
            raise FileExistsError(
                f"store {path} already exists; pass collect.mode=append to add episodes "
                "or collect.mode=overwrite to replace it"
            )
        if mode == "append":
            store = EpisodeStore.open(path, mode="a")
            if "distractor_mask" not in store.frame_keys:
                raise StoreError(
                    f"cannot append to {path}: it was written before stores recorded "
                    "distractor_mask; collect into a new store (collect.mode=overwrite)"
                )
            for key in ("split", "image_size", "control_hz"):
                if key in store.info and store.info[key] != info[key]:
                    raise StoreError(
                        f"cannot append to {path}: it holds {key}={store.info[key]!r}, "
                        f"this run has {key}={info[key]!r}"
                    )
            return store
    return EpisodeStore.create(path, image_size, overwrite=mode == "overwrite", info=info)


def check_episode_range(cfg) -> None:
    """ConfigError unless episodes ``collect.first_episode`` .. ``+ collect.num_episodes`` exist
    in ``env.episodes`` (an EpisodeFileError naming its line if the file is bad) or the split."""
    from vla_gr.envs.episodes import EPISODES_PER_SCENE, load_episodes
    from vla_gr.envs.house import SPLIT_SIZE

    c = cfg.collect
    size, what = SPLIT_SIZE * EPISODES_PER_SCENE, f"split {c.split!r}"
    if cfg.env.episodes:
        size, what = len(load_episodes(cfg.env.episodes)), f"episodes file {cfg.env.episodes}"
    if c.first_episode + c.num_episodes > size:
        raise ConfigError(
            f"collect.first_episode={c.first_episode} + collect.num_episodes={c.num_episodes} "
            f"exceeds the {size} episodes of {what}"
        )


def collect(cfg) -> dict:
    """Run ``vla-gr collect`` for a validated ``VLAGRConfig``; returns the summary dict."""
    from tqdm import tqdm

    c = cfg.collect
    path = Path(c.output)
    env_kwargs = env_kwargs_from_config(cfg, c.split, semantic=True)
    expert_kwargs = {"noise_std": cfg.expert.noise_std, "noise_prob": cfg.expert.noise_prob}
    info = {
        "split": c.split,
        "image_size": cfg.env.image_size,
        "control_hz": cfg.env.control_hz,
        "max_episode_steps": cfg.env.max_episode_steps,
        "success_distance": cfg.env.success_distance,
        "expert": expert_kwargs,
        **({"house_style": cfg.env.house_style} if cfg.env.house_style != "default" else {}),
        "seed": cfg.seed,
        "vla_gr_version": __version__,
    }
    check_episode_range(cfg)  # a bad episodes file or range fails before the store is created
    store = open_output_store(path, c.mode, cfg.env.image_size, info)
    wanted = list(range(c.first_episode, c.first_episode + c.num_episodes))
    present = set(store.episode_indices.tolist())
    todo = [i for i in wanted if i not in present]
    if len(todo) < len(wanted):
        log.info(
            "%d of %d episodes already in %s; skipped", len(wanted) - len(todo), len(wanted), path
        )
    t0 = time.perf_counter()
    frames, metrics = 0, []
    skipped: list[int] = []
    records: Iterable[EpisodeRecord | int] = iter_expert_episodes(
        todo, env_kwargs, expert_kwargs, cfg.seed, c.workers, c.backend, c.ray_address
    )
    bar = tqdm(total=len(todo), desc=f"collect {c.split}", unit="ep", disable=not c.progress)
    with bar:
        for record in records:
            bar.update(1)
            if isinstance(record, int):
                skipped.append(record)
                continue
            store.append(record)
            frames += len(record)
            metrics.append(record.metrics)
            bar.set_postfix(frames=frames)
    elapsed = time.perf_counter() - t0
    summary = {
        "store": str(path),
        "episodes": len(metrics),
        "skipped": skipped,  # indices whose house cannot host an episode
        "frames": frames,
        "seconds": elapsed,
        "frames_per_s": frames / elapsed if elapsed > 0 else 0.0,
        "expert_sr": float(np.mean([m.get("success", 0.0) for m in metrics])) if metrics else 0.0,
        "expert_spl": float(np.mean([m.get("spl", 0.0) for m in metrics])) if metrics else 0.0,
        "store_episodes": store.num_episodes,
        "store_frames": store.num_frames,
    }
    log.info(
        "collected %d episodes, %d frames in %.1f s (%.0f frames/s), expert SR %.3f SPL %.3f; "
        "store %s now holds %d episodes / %d frames",
        summary["episodes"],
        frames,
        elapsed,
        summary["frames_per_s"],
        summary["expert_sr"],
        summary["expert_spl"],
        path,
        store.num_episodes,
        store.num_frames,
    )
    return summary


def run_from_cli(config_name: str, overrides: Sequence[str]) -> int:
    """``vla-gr collect [--config-name NAME] [key=value ...]``; returns the exit code."""
    from vla_gr.configs import load_config

    _, cfg = load_config(config_name, overrides)
    collect(cfg)  # an existing or mismatched store: a user error (exit code 2)
    return 0


if __name__ == "__main__":
    from vla_gr.configs.command import module_main

    sys.exit(module_main("data.collect", run_from_cli))
