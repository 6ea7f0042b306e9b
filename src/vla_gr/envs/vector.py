"""``gymnasium.make_vec("VLAGR/ObjectNav-v0", num_envs=n)``: sub-envs that share one order.

The registered vector entry point builds gymnasium's own ``SyncVectorEnv`` (or
``AsyncVectorEnv`` with ``asynchronous=True``) and tells sub-env ``i`` its place ``(i, n)``: it
runs positions ``i, i + n, ...`` of the seeded episode order
(:mod:`~vla_gr.envs.episode_order`), so no two sub-envs run the same episode until all were run.
Vector envs built otherwise (``vectorization_mode="sync"``, a hand-made ``SyncVectorEnv``) give
no places: each sub-env runs its own seed's order, and they may repeat one another.
"""

from __future__ import annotations

import functools

import gymnasium as gym


def _sub_env(place: int, count: int, env_kwargs: dict) -> gym.Env:
    from vla_gr.envs import ENV_ID

    return gym.make(ENV_ID, sub_env=(place, count), **env_kwargs)


def make_vector_env(
    num_envs: int = 1, asynchronous: bool = False, **env_kwargs
) -> gym.vector.VectorEnv:
    """``num_envs`` sub-envs made with ``env_kwargs``, each told its place; one process
    (``SyncVectorEnv``) or one process per sub-env (``asynchronous``)."""
    if isinstance(num_envs, bool) or not isinstance(num_envs, int) or num_envs < 1:
        raise ValueError(f"num_envs={num_envs!r} must be an int >= 1")
    if "sub_env" in env_kwargs:
        raise ValueError("sub_env is set by the vector env itself; do not pass it")
    fns = [functools.partial(_sub_env, i, num_envs, env_kwargs) for i in range(num_envs)]
    vector = gym.vector.AsyncVectorEnv if asynchronous else gym.vector.SyncVectorEnv
    return vector(fns)
