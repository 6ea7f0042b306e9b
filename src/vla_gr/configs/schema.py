"""Structured configuration: dataclasses registered in Hydra's ConfigStore.

YAML files in this folder only compose these; every field has a default and is
validated on construction (``__post_init__``), so a bad value fails before any work
with a message naming the key and the valid choices.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from hydra.core.config_store import ConfigStore
from omegaconf import OmegaConf

from vla_gr.configs.model_schema import FOLLOWS, ModelConfig
from vla_gr.configs.pipeline_schema import PipelineConfig
from vla_gr.configs.training_schema import (
    SPLITS,
    LoggingConfig,
    TrainingConfig,
    check_training_for_agent,
)
from vla_gr.geometry.robot_spec import MAX_DEPTH
from vla_gr.validation import check_choice, check_positive

#: The agent shipped in the repository (paths are from the working directory): what ``vla-gr
#: demo`` and ``vla-gr eval`` run when no agent is named.
SHIPPED_CHECKPOINT = "checkpoints/vla_gr_cpu"
#: Where ``vla-gr eval`` and ``vla-gr collect`` run episodes: worker processes on this machine,
#: or Ray actors on a cluster (``pip install 'vla-gr[ray]'``; ``vla_gr.data.ray_workers``).
BACKENDS = ("local", "ray")


def check_backend(key: str, backend: str) -> None:
    """ValueError naming ``key`` unless ``backend`` is one of :data:`BACKENDS` whose package
    is installed (Ray, an optional extra, is looked for, not imported)."""
    import importlib.util

    check_choice(key, backend, BACKENDS)
    if backend == "ray" and importlib.util.find_spec("ray") is None:
        raise ValueError(f"{key}=ray needs Ray, which is not installed: pip install 'vla-gr[ray]'")


@dataclass
class EnvConfig:
    """The ObjectNav world (see ``vla_gr.envs``)."""

    split: str = "val"  # the episodes' split: train | val | test (disjoint houses)
    image_size: int = 64  # side of the square RGB-D observation, in pixels
    control_hz: float = 10.0  # control steps per simulated second
    max_episode_steps: int = 1000  # steps before an episode is truncated (a timeout)
    success_distance: float = 1.0  # success: STOP within this many metres of the goal
    semantic: bool = False  # observations also carry the instance-id image ("semantic")
    episodes: str | None = None  # optional JSONL file of episode specs
    max_depth: float = MAX_DEPTH  # depth readings are clipped to [0, max_depth] metres
    num_rooms: int | None = None  # house size knob (None: the generator draws 2-5)
    clutter: float = 1.0  # furniture density knob of the house generator
    scene_cache_size: int = 4  # compiled houses kept per env (LRU)
    depth_noise_std: float = 0.0  # robustness: Gaussian depth noise per pixel (m); 0 = off
    actuation_noise: float = 0.0  # robustness: relative noise per step on v and w; 0 = off
    # how houses look (walls, floors, light, unnamed furniture finishes; never an object's
    # named colour): default (the training world) | loft (held out; envs/house_style.py)
    house_style: str = "default"

    def __post_init__(self) -> None:
        from vla_gr.envs.house_style import HOUSE_STYLES

        check_choice("env.split", self.split, SPLITS)
        check_choice("env.house_style", self.house_style, HOUSE_STYLES)
        check_positive("env.depth_noise_std", self.depth_noise_std, allow_zero=True)
        check_positive("env.actuation_noise", self.actuation_noise, allow_zero=True)
        check_positive("env.max_depth", self.max_depth)
        if self.num_rooms is not None and not 1 <= self.num_rooms <= 6:
            raise ValueError(f"env.num_rooms={self.num_rooms} must be None or in [1, 6]")
        check_positive("env.clutter", self.clutter, allow_zero=True)
        check_positive("env.scene_cache_size", self.scene_cache_size)
        if not 16 <= self.image_size <= 512:
            raise ValueError(f"env.image_size={self.image_size} must be in [16, 512]")
        check_positive("env.control_hz", self.control_hz)
        check_positive("env.max_episode_steps", self.max_episode_steps)
        check_positive("env.success_distance", self.success_distance)


@dataclass
class ExpertConfig:
    """The geodesic expert and its DART-style noise injection."""

    noise_std: float = 0.0  # std of Gaussian noise added to the executed (v, w) fractions
    noise_prob: float = 0.0  # probability per step of a noisy excursion

    def __post_init__(self) -> None:
        check_positive("expert.noise_std", self.noise_std, allow_zero=True)
        if not 0.0 <= self.noise_prob <= 1.0:
            raise ValueError(f"expert.noise_prob={self.noise_prob} must be in [0, 1]")


@dataclass
class CollectConfig:
    """``vla-gr collect``: expert episodes into a zarr store."""

    split: str = "train"  # the split whose episodes the expert drives
    num_episodes: int = 32  # episodes recorded
    first_episode: int = 0  # index of the first one in the split
    workers: int = 2  # processes, one env each
    # where episodes run: local (worker processes here) | ray (Ray actors on a cluster)
    backend: str = "local"
    ray_address: str | None = None  # backend=ray: ray.init(address=...); None: a local cluster
    output: str = "data/expert_${collect.split}.zarr"  # the zarr store written
    mode: str = "refuse"  # what to do when the store exists: refuse | append | overwrite
    progress: bool = True  # a progress bar on stderr

    def __post_init__(self) -> None:
        check_choice("collect.split", self.split, SPLITS)
        check_positive("collect.num_episodes", self.num_episodes)
        check_positive("collect.first_episode", self.first_episode, allow_zero=True)
        check_positive("collect.workers", self.workers)
        check_backend("collect.backend", self.backend)
        check_choice("collect.mode", self.mode, ("refuse", "append", "overwrite"))


@dataclass
class DemoConfig:
    """``vla-gr demo``: the shipped agent evaluated on a few episodes (see ``vla_gr.demo``)."""

    agent: str = "checkpoint"  # an eval agent (checkpoint, true_mask, true_category, expert, ...)
    checkpoint: str = SHIPPED_CHECKPOINT  # the agent shipped in the repository
    split: str = "val"  # the split of the episodes run
    num_episodes: int = 20  # episodes run
    first_episode: int = 0  # index of the first one in the split
    workers: int = 2  # processes, one env and one agent each
    output_dir: str = "outputs/demo"  # the evaluation's run folder (emptied first)
    train: bool = False  # collect (if missing) + train this recipe's agent, then evaluate it

    def __post_init__(self) -> None:
        check_choice("demo.split", self.split, SPLITS)
        check_positive("demo.num_episodes", self.num_episodes)
        check_positive("demo.first_episode", self.first_episode, allow_zero=True)
        check_positive("demo.workers", self.workers)


#: Registered eval agents a variant may build on (both load a checkpoint's settings).
VARIANT_AGENTS = ("checkpoint", "true_mask", "true_category")


@dataclass
class VariantConfig:
    """A named eval agent (``eval.variants.<name>``): a registered agent on a checkpoint with
    inference-only overrides, e.g. an ablation of the checkpoint's dual system."""

    checkpoint: str | None = None  # None: eval.checkpoint
    model_overrides: list[str] = field(default_factory=list)  # replace eval.model_overrides
    # the registered agent it builds on: checkpoint | true_mask | true_category
    agent: str = "checkpoint"
    made_by: str | None = None  # the command that writes the checkpoint (shown if missing)

    def __post_init__(self) -> None:
        check_choice("eval.variants.<name>.agent", self.agent, VARIANT_AGENTS)


@dataclass
class EvalConfig:
    """``vla-gr eval``: closed-loop evaluation of an agent (or several: ``agents``)."""

    # the agent run: a registered agent (checkpoint, expert, random, ...) or a variant; None:
    # checkpoint when a checkpoint is given, else (`vla-gr eval`) the shipped agent. Called as
    # a library, ``evaluate`` given neither runs the expert.
    agent: str | None = None
    agents: list[str] = field(default_factory=list)  # non-empty: compare these agents
    checkpoint: str | None = None  # for agent=checkpoint: <run>/checkpoints/best
    # named agents: a registered agent + checkpoint + overrides (agent=<name>, agents=[...])
    variants: dict[str, VariantConfig] = field(default_factory=dict)
    # inference-only settings changed on the loaded checkpoint, e.g. [navigator.tight.steps=90]
    model_overrides: list[str] = field(default_factory=list)
    split: str = "val"  # the split whose episodes run (without episodes=)
    episodes: str | None = None  # JSONL file of episode specs (instead of the split)
    num_episodes: int | None = None  # None: 10 of a split, or the whole episodes file
    first_episode: int = 0  # index of the first episode run
    workers: int = 1  # processes, one env and one agent each (same rows for any number)
    # where episodes run: local (worker processes here) | ray (Ray actors on a cluster; the
    # same rows, written here in episode order, resumable)
    backend: str = "local"
    ray_address: str | None = None  # backend=ray: ray.init(address=...); None: a local cluster
    output_dir: str | None = None  # None: outputs/eval/<agent>-<split>-<timestamp>
    device: str = "cpu"  # torch device of the agent
    progress: bool = True  # a progress bar on stderr
    goal_seen_pixels: int = 20  # goal instance "seen" when it covers >= this many pixels
    stuck_steps: int = 50  # "stuck": moved < stuck_radius over the last stuck_steps steps
    stuck_radius: float = 0.3  # metres
    video_successes: int = 2  # the report's videos: of the first few successes ...
    video_per_cause: int = 1  # ... and of the first episodes of each failure cause
    video_all: bool = False  # a video of every episode instead (each replayed: slower)
    video_panel: int = 256  # pixels of each video panel (RGB, depth, top-down map)
    video_stride: int = 1  # every n-th step is a video frame (played in real time)

    def __post_init__(self) -> None:
        check_choice("eval.split", self.split, SPLITS)
        if self.num_episodes is not None:
            check_positive("eval.num_episodes", self.num_episodes)
        check_positive("eval.first_episode", self.first_episode, allow_zero=True)
        if self.workers < 1:
            raise ValueError(f"eval.workers={self.workers} must be >= 1")
        check_backend("eval.backend", self.backend)
        check_positive("eval.goal_seen_pixels", self.goal_seen_pixels)
        check_positive("eval.stuck_steps", self.stuck_steps)
        check_positive("eval.stuck_radius", self.stuck_radius)
        check_positive("eval.video_successes", self.video_successes, allow_zero=True)
        check_positive("eval.video_per_cause", self.video_per_cause, allow_zero=True)
        if not 32 <= self.video_panel <= 1024:
            raise ValueError(f"eval.video_panel={self.video_panel} must be in [32, 1024]")
        check_positive("eval.video_stride", self.video_stride)


@dataclass
class VLAGRConfig:
    """Root of every recipe."""

    seed: int = 0  # seeds the noise draws of episodes, data order and initial weights
    env: EnvConfig = field(default_factory=EnvConfig)
    expert: ExpertConfig = field(default_factory=ExpertConfig)
    collect: CollectConfig = field(default_factory=CollectConfig)
    demo: DemoConfig = field(default_factory=DemoConfig)
    eval: EvalConfig = field(default_factory=EvalConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    training: TrainingConfig = field(default_factory=TrainingConfig)
    logging: LoggingConfig = field(default_factory=LoggingConfig)
    pipeline: PipelineConfig = field(default_factory=PipelineConfig)  # the staged recipe

    def __post_init__(self) -> None:
        check_training_for_agent(self.training, self.model.agent)


def register_configs() -> None:
    """Register the schema under the name ``base_config`` (idempotent).

    The agent's view of the sensor follows the world's unless a recipe sets it
    (``model.image_size``, ``model.encoders.max_depth``, ``model.gr_field.max_depth`` and
    ``model.goal_head.max_depth`` follow ``env.*``), and the component fields in
    :data:`~vla_gr.configs.model_schema.FOLLOWS` follow their model key.
    """
    node = OmegaConf.structured(VLAGRConfig)
    node.model.image_size = "${env.image_size}"
    node.model.encoders.max_depth = "${env.max_depth}"
    node.model.gr_field.max_depth = "${env.max_depth}"
    node.model.goal_head.max_depth = "${env.max_depth}"
    for (component, attr), key in FOLLOWS.items():
        node.model[component][attr] = "${model." + key + "}"
    ConfigStore.instance().store(name="base_config", node=node)
