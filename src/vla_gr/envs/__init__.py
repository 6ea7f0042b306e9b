"""vla_gr.envs: the MuJoCo house world and the ``VLAGR/ObjectNav-v0`` task.

Importing this package registers the Gymnasium id ``VLAGR/ObjectNav-v0``; without the
import, ``gymnasium.make("vla_gr.envs:VLAGR/ObjectNav-v0")`` imports it on demand.
Heavier names (the env class, the expert and the local teacher, episode helpers) load
lazily on first use.
"""

from __future__ import annotations

import importlib
import os

# Headless by default: without a display MuJoCo's default (GLFW) cannot open a context.
# Must happen before mujoco is first imported; an explicit MUJOCO_GL always wins.
if "MUJOCO_GL" not in os.environ and not os.environ.get("DISPLAY"):
    os.environ["MUJOCO_GL"] = "egl"
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
# Mesa's llvmpipe reads this once, when the process creates its first GL context: with
# render threads alive, a forked child (AsyncVectorEnv's default) hangs in its first render.
# Single-threaded rendering is no slower at policy resolutions. An explicit value wins.
os.environ.setdefault("LP_NUM_THREADS", "0")

from gymnasium.envs.registration import register, registry

ENV_ID = "VLAGR/ObjectNav-v0"
#: Outcomes an agent may declare instead of acting (``ObjectNavEnv.declare``): the request
#: names nothing it can ground; the reachable house was searched and the goal is not in it.
DECLARED_OUTCOMES: tuple[str, ...] = ("not_understood", "not_found")

if ENV_ID not in registry:
    register(
        id=ENV_ID,
        entry_point="vla_gr.envs.nav_env:ObjectNavEnv",
        # gymnasium.make_vec's default: sub-envs told their place share one episode order
        vector_entry_point="vla_gr.envs.vector:make_vector_env",
        # Truncation is the env's own (``max_episode_steps`` kwarg, default 1000), so metrics
        # and ``truncated`` agree; gymnasium.make(..., max_episode_steps=N) also works.
        max_episode_steps=None,
        # gymnasium's PassiveEnvChecker breaks the env for good when the first reset raises
        # (its first step unpacks the missing reset result); the env is checked with
        # ``check_env`` in its tests instead. ``disable_env_checker=False`` brings it back.
        disable_env_checker=True,
    )

_LAZY = {
    "ObjectNavEnv": "vla_gr.envs.nav_env",
    "compile_scene": "vla_gr.envs.nav_env",
    "EpisodeSpec": "vla_gr.envs.episodes",
    "sample_episode": "vla_gr.envs.episodes",
    "validate_spec": "vla_gr.envs.episodes",
    "save_episodes": "vla_gr.envs.episodes",
    "load_episodes": "vla_gr.envs.episodes",
    "GeodesicExpert": "vla_gr.envs.expert",
    "LocalTeacher": "vla_gr.envs.local_teacher",
    "LocalTeacherConfig": "vla_gr.envs.local_teacher",
    "EpisodeMeasures": "vla_gr.envs.metrics",
    "RGBDRenderer": "vla_gr.envs.rendering",
}

__all__ = ["DECLARED_OUTCOMES", "ENV_ID", *_LAZY]


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'vla_gr.envs' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value
