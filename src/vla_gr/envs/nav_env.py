"""``VLAGR/ObjectNav-v0``: find the instructed object in a procedural MuJoCo house.

Observation: ``rgb`` uint8 (H, W, 3), ``depth`` float32 (H, W, 1) planar metres clipped to
[0, max_depth], ``pose`` float32 (3,) = (x forward, y left, yaw) relative to the episode
start, ``instruction`` str, and ``semantic`` int32 (H, W) instance ids when asked for.
Action: float32 (3,) in [-1, 1] = (linear fraction of 0.5 m/s, angular fraction of
1.0 rad/s, stop); stop > 0 ends the episode as the agent's STOP. An agent that does not act
ends the episode with ``declare(outcome)`` instead (``"not_understood"``, ``"not_found"``):
no motion, no STOP, ``info["declared"]`` names it (None after every other reset and step).

Instruction: any printable Unicode; the observation's ``instruction`` is the spec's folded to
printable ASCII (:func:`vla_gr.text_fold.fold_to_ascii`), at most
``INSTRUCTION_MAX_LENGTH`` characters after folding (a longer one is refused at reset; in an
``episodes`` file, naming its line when the file is loaded).

Reward: 1 for a successful STOP, else 0 (ObjectNav is judged by ``info``'s metrics,
which also carries ``collided`` for the last step).

Collision rule: a step is a collision when the base touched something during the step
and moved less than half of the commanded distance (a blocked step; sliding along a wall
at a shallow angle is not a collision).

Look: ``house_style`` (:mod:`~vla_gr.envs.house_style`) changes how every house looks, never
what is in it or any label: ``default`` is the training world, ``loft`` a held-out look.

Episode selection: ``reset(options={"episode": k})`` runs episode ``k`` of the split (or of the
``episodes`` file); ``options={"episode": spec}`` runs an :class:`EpisodeSpec`.
Otherwise the episode is the next of the env's seeded order (:mod:`~vla_gr.envs.episode_order`):
``reset(seed=s)`` restarts the order of ``s``, so a seed replays the same episodes and the
sub-envs of ``gymnasium.make_vec`` (which tell each sub-env its place) never repeat one another.
Robustness noise of episode ``k`` is drawn from ``(k, seed)``
(:func:`~vla_gr.envs.episode_order.episode_noise_rng`). ``options["instruction"]`` replaces the
episode's instruction by the user's own words and grounds its goal in the house
(:mod:`~vla_gr.envs.grounding`): the house and start stay. ``options["house"]`` may supply a
hand-built :class:`House` whose seed matches the spec (for tests and tools). An absent-object
spec (``absent``, :mod:`~vla_gr.envs.absent`) runs without a goal object: ``goal`` is None,
``distance_to_goal`` inf, no STOP succeeds; the agent's right outcome is ``declare("not_found")``.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import string
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import gymnasium as gym
import mujoco
import numpy as np

from vla_gr.envs import DECLARED_OUTCOMES
from vla_gr.envs import robot as rb
from vla_gr.envs.episode_order import EpisodeOrder, episode_noise_rng
from vla_gr.envs.episodes import (
    EPISODES_PER_SCENE,
    INSTRUCTION_MAX_LENGTH,
    EpisodeSpec,
    NoEpisodeError,
    folded_instruction,
    load_episodes,
    sample_episode,
    validate_spec,
)
from vla_gr.envs.episodes import (
    goal_field as episode_goal_field,
)
from vla_gr.envs.geodesic import distance_at, traversable_cells
from vla_gr.envs.grounding import ground
from vla_gr.envs.house_style import check_house_style
from vla_gr.envs.instruction_space import InstructionSpace
from vla_gr.envs.metrics import EpisodeMeasures
from vla_gr.envs.rendering import RGBDRenderer, make_gl_context, tune_model_for_speed
from vla_gr.envs.scene import House, ObjectInstance
from vla_gr.geometry.pose2d import wrap_angle
from vla_gr.geometry.robot_spec import MAX_ANGULAR_SPEED, MAX_LINEAR_SPEED

logger = logging.getLogger(__name__)

SUBSTEPS = 10  # 10 ms physics steps: stiff enough contacts (< 1 mm penetration at a wall)
BLOCKED_FRACTION = 0.5  # achieved / commanded displacement below this + contact = collision
INSTRUCTION_CHARSET = "".join(c for c in string.printable if c not in "\t\n\r\x0b\x0c")
RESET_OPTIONS = ("episode", "instruction", "house")
MAX_SKIPPED = 100  # split indices in a row that host no episode before the order gives up


@dataclass
class _Scene:
    """A compiled house: model, data, robot handles, lazily made renderers, goal fields."""

    house: House
    model: mujoco.MjModel
    data: mujoco.MjData
    robot: rb.RobotHandles
    traversable: np.ndarray  # (H, W) bool
    renderers: dict[tuple[int, bool], RGBDRenderer] = field(default_factory=dict)
    goal_fields: dict[int, np.ndarray] = field(default_factory=dict)

    def close(self) -> None:
        for renderer in self.renderers.values():
            renderer.close()
        self.renderers.clear()


def compile_scene(
    house: House,
    image_size: int,
    control_hz: float,
    max_depth: float,
    house_style: str = "default",
) -> _Scene:
    """Build the MuJoCo model of ``house`` with the robot, tuned for fast rendering, drawn in
    ``house_style`` (:mod:`~vla_gr.envs.house_style`)."""
    from vla_gr.envs.house import house_to_mjcf

    robot = rb.robot_body_xml(image_size, image_size)
    xml = house_to_mjcf(house, robot_xml=robot, house_style=house_style)
    spec = mujoco.MjSpec.from_string(xml)
    rb.add_robot_actuators(spec)
    model = spec.compile()
    handles = rb.configure_robot(model, control_hz, SUBSTEPS)
    tune_model_for_speed(model, image_size, image_size)
    extent = float(model.stat.extent)
    if model.vis.map.zfar * extent < 2.0 * max_depth:
        model.vis.map.zfar = 2.0 * max_depth / extent
    return _Scene(
        house=house,
        model=model,
        data=mujoco.MjData(model),
        robot=handles,
        traversable=traversable_cells(house),
    )


class ObjectNavEnv(gym.Env):
    """Language-conditioned ObjectNav in a procedural MuJoCo house (see module docstring)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(
        self,
        split: str = "val",
        image_size: int = 64,
        control_hz: float = 10.0,
        max_episode_steps: int = 1000,
        episodes: str | Path | Sequence[EpisodeSpec] | None = None,
        semantic: bool = False,
        success_distance: float = 1.0,
        max_depth: float = 10.0,
        num_rooms: int | None = None,
        clutter: float = 1.0,
        episodes_per_scene: int = EPISODES_PER_SCENE,
        scene_cache_size: int = 4,
        render_mode: str | None = None,
        depth_noise_std: float = 0.0,
        actuation_noise: float = 0.0,
        sub_env: tuple[int, int] = (0, 1),
        house_style: str = "default",
    ) -> None:
        if split not in ("train", "val", "test"):
            raise ValueError(f"split={split!r} is not valid; choose one of train, val, test")
        if not 16 <= int(image_size) <= 512:
            raise ValueError(f"image_size={image_size} must be in [16, 512]")
        for name, value in (
            ("control_hz", control_hz),
            ("max_episode_steps", max_episode_steps),
            ("success_distance", success_distance),
            ("max_depth", max_depth),
            ("scene_cache_size", scene_cache_size),
        ):
            if not value > 0:
                raise ValueError(f"{name}={value} must be > 0")
        for name, value in (
            ("depth_noise_std", depth_noise_std),
            ("actuation_noise", actuation_noise),
        ):
            if not value >= 0:
                raise ValueError(f"{name}={value} must be >= 0")
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode={render_mode!r} must be None or 'rgb_array'")
        self.split = split
        self.image_size = int(image_size)
        self.control_hz = float(control_hz)
        self.max_episode_steps = int(max_episode_steps)
        self.semantic = bool(semantic)
        self.success_distance = float(success_distance)
        self.max_depth = float(max_depth)
        self.num_rooms = num_rooms
        self.clutter = float(clutter)
        self.episodes_per_scene = int(episodes_per_scene)
        self.scene_cache_size = int(scene_cache_size)
        self.render_mode = render_mode
        # how houses look (walls, floors, light, unnamed finishes); never geometry or labels
        self.house_style = check_house_style(house_style)
        # Robustness noise (off by default), drawn from ``np_random``, which each reset of an
        # episode k seeds from (k, seed): the episode replays its noise.
        self.depth_noise_std = float(depth_noise_std)  # metres, Gaussian, per pixel
        self.actuation_noise = float(actuation_noise)  # relative, per step, on v and w
        self.max_linear_speed = MAX_LINEAR_SPEED
        self.max_angular_speed = MAX_ANGULAR_SPEED
        if episodes is None:
            self.episode_list: list[EpisodeSpec] | None = None
        elif isinstance(episodes, (str, Path)):
            self.episode_list = load_episodes(episodes)
        else:
            self.episode_list = list(episodes)
            if not self.episode_list:
                raise ValueError("episodes must not be empty")
        from vla_gr.envs.house import SPLIT_SIZE

        self.num_episodes = (
            SPLIT_SIZE * self.episodes_per_scene
            if self.episode_list is None
            else len(self.episode_list)
        )
        # sub_env = (place, count) among a vector env's sub-envs (set by gymnasium.make_vec)
        self._order = EpisodeOrder.for_sub_env(self.num_episodes, sub_env)

        s = self.image_size
        spaces = {
            "rgb": gym.spaces.Box(0, 255, (s, s, 3), np.uint8),
            "depth": gym.spaces.Box(0.0, self.max_depth, (s, s, 1), np.float32),
            "pose": gym.spaces.Box(-np.inf, np.inf, (3,), np.float32),
            "instruction": InstructionSpace(
                max_length=INSTRUCTION_MAX_LENGTH, min_length=0, charset=INSTRUCTION_CHARSET
            ),
        }
        if self.semantic:
            spaces["semantic"] = gym.spaces.Box(0, np.iinfo(np.int32).max, (s, s), np.int32)
        self.observation_space = gym.spaces.Dict(spaces)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (3,), np.float32)

        self._scenes: OrderedDict[tuple, _Scene] = OrderedDict()
        self._fresh_house: tuple[tuple, House] | None = None
        self._gl = None  # made on first render, so that constructing an env is cheap and fork-safe
        self._scene: _Scene | None = None
        self._measures = EpisodeMeasures(self.success_distance)
        self._steps = 0
        self._done = True
        self._last_obs: dict | None = None
        self.house: House | None = None
        # ``spec`` stays gymnasium's EnvSpec (wrappers read it); the episode is ``episode_spec``.
        self.episode_spec: EpisodeSpec | None = None
        self.instruction = ""  # the episode's instruction, folded to printable ASCII
        self.goal: ObjectInstance | None = None
        self.traversable: np.ndarray | None = None
        self.goal_distance: np.ndarray | None = None
        self.start_pose_world = np.zeros(3)
        self.trajectory_world: list[tuple[float, float]] = []

    # ------------------------------------------------------------------ ground truth

    @property
    def goal_id(self) -> int | None:
        """The goal object's instance id; None in an absent-object episode (or before reset)."""
        return None if self.goal is None else int(self.goal.instance_id)

    def robot_pose_world(self) -> np.ndarray:
        """World pose (3,) = (x, y, yaw) of the robot, yaw in (-pi, pi]."""
        scene = self._require_scene()
        pose = scene.data.qpos[scene.robot.qpos_adr].copy()  # (3,)
        pose[2] = wrap_angle(pose[2])
        return pose

    # ------------------------------------------------------------------ gymnasium API

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        options = dict(options or {})
        unknown = set(options) - set(RESET_OPTIONS)
        if unknown:
            valid = ", ".join(map(repr, RESET_OPTIONS))
            raise ValueError(f"unknown reset options {sorted(unknown)}; use {valid}")
        if seed is not None:
            self._check_seed(seed)
        super().reset(seed=seed)
        if self.spec is not None and self.spec.max_episode_steps:
            self.max_episode_steps = int(self.spec.max_episode_steps)
        if seed is not None:
            self._order.seed(seed)
        house = options.get("house")
        episode = options.get("episode")
        if isinstance(episode, dict):
            episode = EpisodeSpec.from_dict(episode)
        if episode is None:
            spec, house, index = self._next_in_order(house)
            noise_seed = self._order.base
        elif isinstance(episode, EpisodeSpec):
            spec, index = episode, None  # noise continues np_random (seeded by ``seed``)
        elif isinstance(episode, (int, np.integer)) and not isinstance(episode, bool):
            index, noise_seed = self._check_index(episode), seed
            spec, house = self._episode_at(index, house)
        else:
            raise ValueError(
                f"options['episode'] must be an episode index (int) or an EpisodeSpec, "
                f"got {episode!r}"
            )
        self._start_episode(spec, house, options.get("instruction"))
        if index is not None:
            self.np_random = episode_noise_rng(index, noise_seed)
        obs = self._observe()
        return obs, self._info()

    def step(self, action):
        self._require_running("step")
        act = self.check_action(action)  # (3,)
        scene = self._scene
        called_stop = bool(act[2] > 0.0)
        collided = False
        if not called_stop:
            linear = float(act[0]) * self.max_linear_speed
            angular = float(act[1]) * self.max_angular_speed
            if self.actuation_noise > 0:
                gain = 1.0 + self.actuation_noise * self.np_random.standard_normal(2)  # (2,)
                linear, angular = linear * float(gain[0]), angular * float(gain[1])
            adr = scene.robot.qpos_adr
            x0, y0 = scene.data.qpos[adr[0]], scene.data.qpos[adr[1]]
            touched = rb.drive(scene.model, scene.data, scene.robot, linear, angular, SUBSTEPS)
            x1, y1 = scene.data.qpos[adr[0]], scene.data.qpos[adr[1]]
            commanded = abs(linear) / self.control_hz
            moved = math.hypot(x1 - x0, y1 - y0)
            collided = touched and commanded > 1e-6 and moved < BLOCKED_FRACTION * commanded
        x, y = (
            float(scene.data.qpos[scene.robot.qpos_adr[0]]),
            float(scene.data.qpos[scene.robot.qpos_adr[1]]),
        )
        if not called_stop:
            self.trajectory_world.append((x, y))
        distance = distance_at(self.goal_distance, self.house.grid, x, y)
        self._measures.update((x, y), distance, collided, called_stop)
        self._steps += 1
        terminated = called_stop
        truncated = not terminated and self._steps >= self.max_episode_steps
        self._done = terminated or truncated
        obs = self._observe()
        info = self._info()
        info["collided"] = bool(collided)
        reward = float(terminated and info["success"] > 0)  # sparse: the metrics judge
        return obs, reward, terminated, truncated, info

    def declare(self, outcome: str):
        """End the episode as the agent's declared ``outcome`` (one of ``DECLARED_OUTCOMES``)
        instead of an action: the robot does not move and no STOP is called.

        Returns ``(obs, 0.0, True, False, info)`` like :meth:`step`; the declaration counts as
        one step in which the robot stood still, ``info`` holds the metrics (``success`` 0:
        only a STOP succeeds) and ``info["declared"] = outcome``. The (3,) action and its
        meaning are unchanged: a declaration is never an action.
        """
        if not isinstance(outcome, str) or outcome not in DECLARED_OUTCOMES:
            raise ValueError(
                f"outcome {outcome!r} is not a declared outcome; valid: "
                f"{', '.join(DECLARED_OUTCOMES)}"
            )
        self._require_running("declare")
        scene = self._scene
        adr = scene.robot.qpos_adr
        x, y = float(scene.data.qpos[adr[0]]), float(scene.data.qpos[adr[1]])
        distance = distance_at(self.goal_distance, self.house.grid, x, y)
        self._measures.update((x, y), distance, collided=False, called_stop=False)
        self._steps += 1
        self._done = True
        obs = self._observe()
        info = self._info()
        info["collided"] = False
        info["declared"] = outcome
        return obs, 0.0, True, False, info

    def render(self):
        """The last RGB observation (H, W, 3) uint8 (``render_mode="rgb_array"``)."""
        if self._last_obs is None:
            return None
        return self._last_obs["rgb"]

    def close(self) -> None:
        for scene in self._scenes.values():
            scene.close()
        self._scenes.clear()
        self._scene = None
        if self._gl is not None:
            try:
                self._gl.free()
            except Exception:  # noqa: BLE001 - best effort at shutdown
                logger.debug("GLContext.free failed", exc_info=True)
            self._gl = None
        super().close()

    # ------------------------------------------------------------------ helpers

    @staticmethod
    def check_action(action) -> np.ndarray:
        """Validated, clipped float32 action (3,); ValueError on a wrong shape or NaN/inf."""
        try:
            act = np.asarray(action, dtype=np.float32)
        except (TypeError, ValueError) as err:
            raise ValueError(f"action must be numeric with shape (3,), got {action!r}") from err
        if act.shape != (3,):
            raise ValueError(f"action must have shape (3,) = (v, w, stop), got shape {act.shape}")
        if not np.all(np.isfinite(act)):
            raise ValueError(f"action must be finite (no NaN/inf), got {act.tolist()}")
        return np.clip(act, -1.0, 1.0)

    def render_rgbd(self, size: int) -> tuple[np.ndarray, np.ndarray]:
        """RGB (size, size, 3) uint8 and depth (size, size) float32 from the robot camera."""
        if not 16 <= int(size) <= 1024:
            raise ValueError(f"size={size} must be in [16, 1024]")
        return self._renderer(int(size), False).render(self._require_scene().data)

    def _require_running(self, call: str) -> None:
        if self._done:
            raise RuntimeError(f"{call}() called before reset() or after the episode ended")

    def _require_scene(self) -> _Scene:
        if self._scene is None:
            raise RuntimeError("no episode: call reset() first")
        return self._scene

    @staticmethod
    def _check_seed(seed) -> None:
        """Raise (quoting ``seed``) unless it is an int >= 0."""
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
            raise TypeError(f"seed must be an int >= 0 or None, got {seed!r}")
        if seed < 0:
            raise ValueError(f"seed={seed} must be >= 0")

    def _check_index(self, index) -> int:
        """``index`` as an int; ValueError (quoting it) unless an episode of this env."""
        if not 0 <= index < self.num_episodes:
            where = f"split {self.split!r}" if self.episode_list is None else "the episodes file"
            raise ValueError(
                f"options['episode']={index} must be in [0, {self.num_episodes}): "
                f"{where} has {self.num_episodes} episodes"
            )
        return int(index)

    def _episode_at(self, index: int, house: House | None) -> tuple[EpisodeSpec, House | None]:
        """Episode ``index`` of the file or split (and the house to run it in, if given)."""
        if self.episode_list is not None:
            return self.episode_list[index], house
        house_here = self._split_house(index)
        spec = sample_episode(
            self.split, index, self.num_rooms, self.clutter, self.episodes_per_scene, house_here
        )
        return spec, house

    def _next_in_order(self, house: House | None) -> tuple[EpisodeSpec, House | None, int]:
        """The next episode of the seeded order; split indices whose house hosts no episode
        (:class:`NoEpisodeError`, rare) are passed over."""
        for _ in range(MAX_SKIPPED):
            index = self._order.next()
            try:
                return (*self._episode_at(index, house), index)
            except NoEpisodeError as err:
                logger.debug("episode %d passed over: %s", index, err)
        raise NoEpisodeError(f"{MAX_SKIPPED} episodes in a row host no episode")

    def _split_house(self, index: int) -> House:
        """The house of split episode ``index``: from the scene cache, else generated once."""
        from vla_gr.envs.episodes import scene_seed_for
        from vla_gr.envs.house import generate_house

        seed = scene_seed_for(self.split, index, self.episodes_per_scene)
        key = (seed, self.num_rooms, self.clutter)
        scene = self._scenes.get(key)
        if scene is not None:
            return scene.house
        house = generate_house(seed, num_rooms=self.num_rooms, clutter=self.clutter)
        self._fresh_house = (key, house)  # picked up by _load_scene: no second generation
        return house

    def _load_scene(self, spec: EpisodeSpec, house: House | None) -> _Scene:
        key = ("custom", id(house)) if house is not None else spec.scene_key
        scene = self._scenes.get(key)
        if scene is not None:
            self._scenes.move_to_end(key)
            return scene
        if house is None and self._fresh_house is not None and self._fresh_house[0] == key:
            house = self._fresh_house[1]
        if house is None:
            from vla_gr.envs.house import generate_house

            house = generate_house(spec.scene_seed, num_rooms=spec.num_rooms, clutter=spec.clutter)
        self._fresh_house = None
        scene = compile_scene(
            house, self.image_size, self.control_hz, self.max_depth, self.house_style
        )
        self._scenes[key] = scene
        while len(self._scenes) > self.scene_cache_size:
            _, old = self._scenes.popitem(last=False)  # least recently used
            old.close()
        logger.debug("compiled scene %s (%d geoms)", key, scene.model.ngeom)
        return scene

    def _start_episode(
        self, spec: EpisodeSpec, house: House | None, request: str | None = None
    ) -> None:
        """Run ``spec`` (in ``house`` if given); a ``request`` replaces its instruction and
        its goal becomes the object the request describes (the start stays)."""
        self._scene, self._done = None, True  # the old episode is over even if this one fails
        if request is not None:  # the user's words name an object of the house: not absent
            spec = dataclasses.replace(spec, instruction=request, absent=False)
        instruction = folded_instruction(spec)
        scene = self._load_scene(spec, house)
        if request is not None:
            found = ground(scene.house, instruction)
            spec = dataclasses.replace(
                spec,
                goal_instance_id=found.instance.instance_id,
                goal_category=found.instance.category,
                description=found.fields,
            )
        goal_field = scene.goal_fields.get(spec.goal_instance_id)
        if goal_field is None and spec.goal_instance_id in {
            o.instance_id for o in scene.house.objects
        }:
            goal_field = episode_goal_field(scene.house, spec.goal_instance_id)  # (H, W)
            scene.goal_fields[spec.goal_instance_id] = goal_field
        start_distance = validate_spec(spec, scene.house, scene.traversable, goal_field)
        if request is not None:
            spec = dataclasses.replace(spec, geodesic_start_distance=start_distance)
        elif abs(start_distance - spec.geodesic_start_distance) > 0.05:
            logger.warning(
                "episode %s: geodesic start distance %.3f differs from the spec's %.3f",
                spec.episode_id,
                start_distance,
                spec.geodesic_start_distance,
            )
        self._scene = scene
        self.house = scene.house
        self.episode_spec = spec
        self.instruction = instruction
        self.goal = None if spec.absent else scene.house.object(spec.goal_instance_id)
        self.traversable = scene.traversable
        # no goal object: infinitely far everywhere (no STOP succeeds)
        self.goal_distance = (
            np.full(scene.traversable.shape, np.inf) if spec.absent else goal_field
        )  # (H, W)
        self.start_pose_world = spec.start_pose
        rb.set_robot_pose(scene.model, scene.data, scene.robot, self.start_pose_world)
        self.trajectory_world = [(float(spec.start_x), float(spec.start_y))]
        self._measures.reset(
            (spec.start_x, spec.start_y), start_distance, math.inf if spec.absent else None
        )
        self._steps = 0
        self._done = False

    def _renderer(self, size: int, main: bool) -> RGBDRenderer:
        scene = self._require_scene()
        renderer = scene.renderers.get((size, main))
        if renderer is None:
            if self._gl is None:
                self._gl = make_gl_context(self.image_size, self.image_size)
            glob = scene.model.vis.global_
            glob.offwidth, glob.offheight = max(glob.offwidth, size), max(glob.offheight, size)
            renderer = RGBDRenderer(
                scene.model,
                self._gl,
                size,
                size,
                scene.robot.camera_id,
                self.max_depth,
                hidden_groups=(rb.ROBOT_GROUP,),
            )
            scene.renderers[(size, main)] = renderer
        return renderer

    def _observe(self) -> dict:
        scene = self._scene
        renderer = self._renderer(self.image_size, True)
        rgb, depth = renderer.render(scene.data)  # (H, W, 3), (H, W)
        if self.depth_noise_std > 0:
            noise = self.np_random.normal(0.0, self.depth_noise_std, depth.shape)  # (H, W)
            depth = np.clip(depth + noise, 0.0, self.max_depth).astype(np.float32)
        pose = rb.relative_pose(self.robot_pose_world(), self.start_pose_world)
        obs = {
            "rgb": rgb,
            "depth": depth[..., None],  # (H, W, 1)
            "pose": pose.astype(np.float32),  # (3,)
            "instruction": self.instruction,
        }
        if self.semantic:
            obs["semantic"] = renderer.render_segmentation(scene.data)  # (H, W)
        self._last_obs = obs
        return obs

    def _info(self) -> dict:
        info = self._measures.as_info()
        info["episode_id"] = self.episode_spec.episode_id
        info["declared"] = None  # the outcome of a declare(), which alone sets it
        return info
