"""Structured config of ``vla-gr train`` (``training.*``) and of its logging (``logging.*``)."""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass, field

from vla_gr.validation import check_choice, check_positive

SPLITS = ("train", "val", "test")  # the world's splits (disjoint houses)

AMP_MODES = ("none", "fp16", "bf16")
DEVICES = ("auto", "cpu", "cuda")
IF_MISSING = ("error", "collect", "synthetic")
ON_CORRUPT = ("error", "skip")
DDP_BACKENDS = ("auto", "nccl", "gloo")
LOG_LEVELS = ("DEBUG", "INFO", "WARNING", "ERROR")
BEST_METRICS = ("val_loss", "success", "spl", "goal_iou")
#: ``best_metric`` values measured by closed-loop episodes (the rest on held-out windows).
CLOSED_LOOP_METRICS = ("success", "spl")


@dataclass
class S1StageConfig:
    """The learned S1 of a dual-system agent (``training.s1``), trained by a recipe's
    ``s1_data`` stage (the agent's rollouts relabelled by the local teacher, in ``workers``
    processes) and ``s1`` stage (:mod:`vla_gr.training.stages`)."""

    workers: int = 2  # processes that relabel the rollouts (s1_data stage)
    init_s1: bool = False  # start from the input agent's S1 weights instead of fresh ones
    steps: int = 3000  # optimiser steps
    batch_size: int = 256  # samples per step
    lr: float = 1e-3  # learning rate
    settings: list[str] = field(default_factory=list)  # s1.* model settings, e.g. the head

    def __post_init__(self) -> None:
        for key in ("workers", "steps", "batch_size", "lr"):
            check_positive(f"training.s1.{key}", getattr(self, key))


@dataclass
class FramePartStageConfig:
    """A part of S2 trained on stored frames by a recipe stage (the room-type classifier,
    ``training.room_type``; the object-category segmenter, ``training.object_category``)."""

    first: int = 0  # first stored episode read
    episodes: int | None = None  # stored episodes read (None: all from ``first``)
    stride: int = 8  # every stride-th frame
    steps: int = 2000  # optimiser steps
    batch_size: int = 256  # frames per step
    lr: float = 2e-3  # learning rate
    reject_threshold: float = 0.2  # the navigator's rejection threshold written with the part
    background_weight: float = 0.5  # the segmenter's background pixels' loss weight
    settings: list[str] = field(default_factory=list)  # <part>.* model settings

    def __post_init__(self) -> None:
        check_positive("training.<part>.first", self.first, allow_zero=True)
        if self.episodes is not None:
            check_positive("training.<part>.episodes", self.episodes)
        for key in ("stride", "steps", "batch_size", "lr", "background_weight"):
            check_positive(f"training.<part>.{key}", getattr(self, key))
        if not 0.0 <= self.reject_threshold <= 1.0:
            raise ValueError(
                f"training.<part>.reject_threshold={self.reject_threshold} must be in [0, 1]"
            )


#: Hand-written development request sets (``benchmarks/language/<name>.jsonl``) the reader's
#: temperature and threshold are chosen on.
READER_DEV_SETS = (
    "dev_requests", "dev_a", "dev_b", "dev_c", "dev_not_understood", "dev_not_understood_b",
)  # fmt: skip
#: Those and the blind sets measured since, which the intent head's ``min_intent`` is chosen on.
INTENT_DEV_SETS = READER_DEV_SETS + (
    "blind_d", "blind_e", "blind_f", "blind_not_understood", "blind_not_understood_c",
    "blind_not_understood_d", "blind_not_understood_e", "blind_not_understood_f",
    "blind_not_understood_g", "blind_g", "blind_h", "blind_i", "blind_j",
    "blind_not_understood_h", "blind_k", "blind_not_understood_i", "blind_not_understood_j",
    "blind_not_understood_k", "blind_not_understood_n",
)  # fmt: skip


def _request_sets(names) -> list[str]:
    """Paths (from the working directory) of the request sets ``names``."""
    return [f"benchmarks/language/{name}.jsonl" for name in names]


@dataclass
class ReaderStageConfig:
    """The instruction reader trained by a recipe stage on generated requests and
    calibrated on hand-written development sets (``training.instruction_reader``)."""

    count: int = 12000  # generated training requests
    steps: int = 2000  # optimiser steps
    batch_size: int = 128  # requests per step
    lr: float = 3e-3  # learning rate
    # hand-written development requests (JSONL, paths from the working directory)
    dev_sets: list[str] = field(default_factory=lambda: _request_sets(READER_DEV_SETS))
    settings: list[str] = field(default_factory=list)  # instruction_reader.* model settings

    def __post_init__(self) -> None:
        for key in ("count", "steps", "batch_size", "lr"):
            check_positive(f"training.instruction_reader.{key}", getattr(self, key))
        if not self.dev_sets:
            raise ValueError("training.instruction_reader.dev_sets must name at least one file")


@dataclass
class IntentStageConfig:
    """The reader's request intent head trained by a recipe stage on grammar requests against
    WordNet's statements, ``min_intent`` chosen on development sets (``training.request_intent``,
    :mod:`vla_gr.training.request_intent`)."""

    count: int = 8000  # grammar requests, and as many statements
    steps: int = 1500  # optimiser steps
    batch_size: int = 256  # sentences per step
    lr: float = 3e-3  # learning rate
    # hand-written development requests: the reader's and the blind sets used since
    dev_sets: list[str] = field(default_factory=lambda: _request_sets(INTENT_DEV_SETS))

    def __post_init__(self) -> None:
        for key in ("count", "steps", "batch_size", "lr"):
            check_positive(f"training.request_intent.{key}", getattr(self, key))
        if not self.dev_sets:
            raise ValueError("training.request_intent.dev_sets must name at least one file")


@dataclass
class RoomPriorStageConfig:
    """Where categories stand in houses, counted by a ``room_prior`` stage for the navigator's
    room search (``training.room_prior``, :mod:`vla_gr.training.room_prior`)."""

    houses: int = 1200  # houses counted, their number of rooms cycling 1..6
    split: str = "train"  # whose houses

    def __post_init__(self) -> None:
        check_positive("training.room_prior.houses", self.houses)
        check_choice("training.room_prior.split", self.split, SPLITS)


#: How an ``adapt`` stage fine-tunes the goal head: LoRA / OFT layers (merged before writing)
#: or every goal-head weight (``full``, the comparison).
ADAPT_METHODS = ("lora", "oft", "full")


@dataclass
class AdaptStageConfig:
    """The goal head of a trained agent adapted on stored frames of a shifted world, e.g. a
    held-out house style (``training.adapt``; a recipe's ``adapt`` stage,
    :mod:`vla_gr.training.adapt`). LoRA / OFT weights are merged into the written agent."""

    method: str = "lora"  # lora | oft (peft layers, merged away) | full (all goal-head weights)
    # modules of model.goal_head given adapters (peft's matching: a name or its last parts);
    # lora: Conv2d and Linear layers, oft: Linear layers only; full ignores them
    targets: list[str] = field(default_factory=lambda: ["conv1", "conv2"])
    rank: int = 8  # LoRA rank r; OFT: the number of blocks
    alpha: float = 16.0  # LoRA scale: the update is multiplied by alpha / rank
    steps: int = 600  # optimiser steps
    batch_size: int = 32  # frames per step
    lr: float = 2e-3  # peak learning rate (AdamW, warm-up then cosine)
    warmup_steps: int = 20  # linear warm-up to lr
    weight_decay: float = 1e-4  # AdamW weight decay on >= 2-D weights
    val_ratio: float = 0.1  # stored episodes held out to measure the head before and after
    flip_prob: float = 0.5  # frames mirrored left-right with their masks
    paraphrase_prob: float = 0.3  # instructions rewritten in the training paraphrase words

    def __post_init__(self) -> None:
        check_choice("training.adapt.method", self.method, ADAPT_METHODS)
        if self.method != "full" and not self.targets:
            raise ValueError("training.adapt.targets must name at least one goal-head module")
        for key in ("rank", "alpha", "steps", "batch_size", "lr"):
            check_positive(f"training.adapt.{key}", getattr(self, key))
        check_positive("training.adapt.warmup_steps", self.warmup_steps, allow_zero=True)
        check_positive("training.adapt.weight_decay", self.weight_decay, allow_zero=True)
        if not 0.0 < self.val_ratio < 1.0:
            raise ValueError(f"training.adapt.val_ratio={self.val_ratio} must be in (0, 1)")
        for key in ("flip_prob", "paraphrase_prob"):
            if not 0.0 <= getattr(self, key) <= 1.0:
                raise ValueError(f"training.adapt.{key}={getattr(self, key)} must be in [0, 1]")


@dataclass
class TrainingConfig:
    """Optimisation, data, precision, distribution and checkpointing of a training run."""

    # Data.
    dataset: str = "data/expert_train.zarr"  # the episode store (zarr) trained on
    if_missing: str = "error"  # dataset absent: error | collect (run the expert) | synthetic
    on_corrupt: str = "error"  # damaged store: error (refuse) | skip (train on intact episodes)
    synthetic_episodes: int = 8  # for if_missing=synthetic
    synthetic_length: int = 24  # steps of each synthetic episode
    val_ratio: float = 0.1  # held-out episodes for the validation loss
    num_workers: int = 0  # DataLoader worker processes (0: in the training process)
    # hold depth in float16 in memory (half its bytes; rounding <= 2**-11 relative, 2.4 mm
    # at 5 m); masks are always held bit-packed. For stores that would not fit otherwise.
    depth_float16: bool = False
    # Optimisation.
    steps: int = 2000  # optimiser steps
    batch_size: int = 32  # micro-batch per process
    grad_accum: int = 1  # micro-batches per optimiser step
    lr: float = 3e-4  # peak learning rate (AdamW, cosine schedule)
    min_lr_ratio: float = 0.1  # cosine floor as a fraction of lr
    warmup_steps: int = 100  # linear warm-up to lr
    weight_decay: float = 1e-4  # AdamW weight decay
    betas: list[float] | None = None  # AdamW betas; None = (0.9, 0.999)
    grad_clip: float = 1.0  # max global grad norm; 0 disables
    ema_decay: float = 0.995  # 0 disables EMA
    ema_warmup: bool = True  # decay ramps up as min(decay, (1 + s) / (10 + s))
    optimizer_offload: bool = False  # keep AdamW state (and fp32 master weights) on the CPU
    # Precision / speed.
    device: str = "auto"  # auto (cuda if available) | cpu | cuda
    amp: str = "none"  # none | fp16 (autocast + GradScaler) | bf16 (autocast)
    compile: bool = False  # torch.compile the policy
    # recompute the goal head's stage activations in backward (model.agent=dual_system; the
    # end-to-end agent sets model.encoders / model.head.gradient_checkpointing): less memory
    # for one more forward of each stage; outputs, gradients and weights are unchanged
    gradient_checkpointing: bool = False
    ddp_backend: str = "auto"  # auto: nccl on CUDA, gloo on CPU
    init_from: str | None = None  # checkpoint folder whose weights initialise the model
    # init_from may lack entries the model has (a newly added output keeps its fresh
    # initialisation, and the log lists it); extra or mis-shaped entries still fail
    init_allow_missing: bool = False
    # share of training instructions rewritten in the TRAINING paraphrase vocabulary
    # (envs/paraphrase.py; disjoint from the held-out set robustness is measured on)
    paraphrase_prob: float = 0.0
    # share of goal-head training frames mirrored left-right with their masks (instructions
    # never say left or right); dual system only: an end-to-end action would need mirroring
    flip_prob: float = 0.0
    # Evaluation / checkpointing.
    val_every: int = 200  # optimiser steps between validation losses (0 = never)
    val_batches: int = 8  # batches per validation (per process)
    eval_episodes: int = 0  # closed-loop `val` episodes (0..N-1) at each validation; 0 = off
    eval_max_steps: int = 300  # step budget of each closed-loop episode during training
    # closed-loop episodes (the first ones) whose videos go to TensorBoard at each validation
    eval_videos: int = 1
    # What picks `best`: val_loss (lowest) | success | spl (closed loop, highest) | goal_iou
    # (the goal head's held-out pixel IoU, highest; model.agent=dual_system).
    best_metric: str = "val_loss"
    checkpoint_every: int = 200  # optimiser steps between `latest` checkpoints (0 = end only)
    keep_checkpoints: int = 2  # step folders kept besides the one `best` points to
    resume: str | None = None  # <run>/checkpoints/latest
    output_dir: str = "outputs/train"  # the run folder is output_dir/run_name
    run_name: str | None = None  # default: a timestamp
    log_every: int = 10  # optimiser steps between logged metrics
    s1: S1StageConfig = field(default_factory=S1StageConfig)
    # S2's parts trained on frames or generated instructions by recipe stages
    room_type: FramePartStageConfig = field(default_factory=FramePartStageConfig)
    object_category: FramePartStageConfig = field(
        default_factory=lambda: FramePartStageConfig(
            steps=3000, batch_size=64, reject_threshold=0.3
        )
    )  # the object-category segmenter's stage
    # the instruction reader's stage
    instruction_reader: ReaderStageConfig = field(default_factory=ReaderStageConfig)
    # the reader's request intent head (a request_intent stage)
    request_intent: IntentStageConfig = field(default_factory=IntentStageConfig)
    # where categories stand in houses (a room_prior stage), for the navigator's room search
    room_prior: RoomPriorStageConfig = field(default_factory=RoomPriorStageConfig)
    # the goal head adapted to a shifted world (an adapt stage): LoRA, OFT or full
    adapt: AdaptStageConfig = field(default_factory=AdaptStageConfig)

    def __post_init__(self) -> None:
        check_choice("training.if_missing", self.if_missing, IF_MISSING)
        check_choice("training.on_corrupt", self.on_corrupt, ON_CORRUPT)
        check_positive("training.synthetic_episodes", self.synthetic_episodes)
        check_positive("training.synthetic_length", self.synthetic_length)
        if not 0.0 <= self.val_ratio < 1.0:
            raise ValueError(f"training.val_ratio={self.val_ratio} must be in [0, 1)")
        check_positive("training.num_workers", self.num_workers, allow_zero=True)
        for key in ("steps", "batch_size", "grad_accum", "lr", "log_every", "val_batches"):
            check_positive(f"training.{key}", getattr(self, key))
        for key in ("paraphrase_prob", "flip_prob"):
            if not 0.0 <= getattr(self, key) <= 1.0:
                raise ValueError(f"training.{key}={getattr(self, key)} must be in [0, 1]")
        if not 0.0 <= self.min_lr_ratio <= 1.0:
            raise ValueError(f"training.min_lr_ratio={self.min_lr_ratio} must be in [0, 1]")
        for key in ("warmup_steps", "weight_decay", "grad_clip", "val_every", "checkpoint_every"):
            check_positive(f"training.{key}", getattr(self, key), allow_zero=True)
        if self.betas is not None and (
            len(self.betas) != 2 or not all(0.0 <= b < 1.0 for b in self.betas)
        ):
            raise ValueError(f"training.betas={self.betas} must be two numbers in [0, 1)")
        if not 0.0 <= self.ema_decay < 1.0:
            raise ValueError(f"training.ema_decay={self.ema_decay} must be in [0, 1)")
        check_choice("training.device", self.device, DEVICES)
        check_choice("training.amp", self.amp, AMP_MODES)
        check_choice("training.ddp_backend", self.ddp_backend, DDP_BACKENDS)
        check_positive("training.keep_checkpoints", self.keep_checkpoints)
        check_positive("training.eval_episodes", self.eval_episodes, allow_zero=True)
        check_positive("training.eval_max_steps", self.eval_max_steps)
        check_positive("training.eval_videos", self.eval_videos, allow_zero=True)
        check_choice("training.best_metric", self.best_metric, BEST_METRICS)
        if self.best_metric in CLOSED_LOOP_METRICS and self.eval_episodes == 0:
            raise ValueError(
                f"training.best_metric={self.best_metric!r} needs closed-loop evaluation: set "
                "training.eval_episodes > 0 or use training.best_metric=val_loss"
            )
        if self.best_metric == "goal_iou" and (self.val_ratio == 0 or self.val_every == 0):
            raise ValueError(
                "training.best_metric='goal_iou' is measured on held-out windows: set "
                "training.val_ratio > 0 and training.val_every > 0"
            )
        if self.eval_episodes > 0 and self.val_every == 0:
            raise ValueError(
                f"training.eval_episodes={self.eval_episodes} runs at each validation, but "
                "training.val_every=0 never validates; set training.val_every > 0"
            )


@dataclass
class WandbConfig:
    """Weights & Biases mirror of the metrics (off by default; needs ``pip install wandb``)."""

    enabled: bool = False  # mirror the metrics to Weights & Biases
    project: str = "vla-gr"  # the wandb project
    entity: str | None = None  # the wandb team or user (None: your default)
    mode: str = "online"  # online | offline | disabled

    def __post_init__(self) -> None:
        check_choice("logging.wandb.mode", self.mode, ("online", "offline", "disabled"))
        if self.enabled and importlib.util.find_spec("wandb") is None:
            raise ValueError(
                "logging.wandb.enabled=true but the wandb package is not installed; "
                "install it with `pip install 'vla-gr[wandb]'` or set logging.wandb.enabled=false"
            )


@dataclass
class LoggingConfig:
    """Where training metrics go: metrics.jsonl always, TensorBoard, progress bar, wandb."""

    tensorboard: bool = True  # TensorBoard event files in <run>/tensorboard
    progress: bool = True  # a progress bar on stderr
    level: str = "INFO"  # log level: DEBUG | INFO | WARNING | ERROR
    wandb: WandbConfig = field(default_factory=WandbConfig)

    def __post_init__(self) -> None:
        check_choice("logging.level", self.level, LOG_LEVELS)


def check_training_for_agent(training: TrainingConfig, agent: str) -> None:
    """Cross-checks of ``training.*`` against ``model.agent``; raises ``ValueError``."""
    if training.best_metric == "goal_iou" and agent != "dual_system":
        raise ValueError(
            f"training.best_metric='goal_iou' needs the goal head of model.agent=dual_system "
            f"(model.agent={agent!r})"
        )
    if training.gradient_checkpointing and agent != "dual_system":
        raise ValueError(
            f"training.gradient_checkpointing=true recomputes the goal head of "
            f"model.agent=dual_system (model.agent={agent!r} sets "
            "model.encoders.gradient_checkpointing and model.head.gradient_checkpointing)"
        )
    if training.flip_prob > 0.0 and agent != "dual_system":
        raise ValueError(
            f"training.flip_prob={training.flip_prob} mirrors goal-head frames; "
            f"model.agent={agent!r} learns actions, which a mirror would falsify (set it to 0)"
        )
