"""The kinds of stage a training recipe is made of (``pipeline.stages[].kind``).

Each kind is ``(stage, cfg, resolved, folder, inputs, services) -> product path``: ``cfg``
is the stage's validated ``VLAGRConfig`` (the recipe with the stage's overrides),
``folder`` its output folder, ``inputs`` the products of the stages it names (in order) and
``services`` the training loop and evaluation harness the app hands in. A kind resumes
where it can when its folder holds a partial product made with the same settings.

======== ============================================ ==========================
kind      product                                      inputs
======== ============================================ ==========================
collect   ``store.zarr``: expert episodes (appended to   [store]
          a copy of the input store)
train     ``run/checkpoints/<use>``: a trained agent    store [, init checkpoint]
rollout   ``rollouts/``: the agent's closed-loop rows   checkpoint
dagger    ``store.zarr``: a store + the rollouts'       rollout, store
          states with their true masks
s1_data   ``data/``: S1 inputs + local-teacher labels   rollout, checkpoint
s1        ``agent/``: the agent with a learned S1       checkpoint, s1_data...
room_type ``agent/``: + a room-type classifier          checkpoint, store
object_   ``agent/``: + an object-category segmenter    checkpoint, store
category
instruct- ``agent/``: + an instruction reader           checkpoint
ion_reader
request_  ``agent/``: + the reader's request intent      checkpoint
intent    head
room_     ``agent/``: room search on, its prior counted   checkpoint
prior     from houses
graft     ``agent/``: + another agent's ``part``          checkpoint, donor
adapt     ``agent/``: its goal head adapted on the       checkpoint, store
          store's frames (LoRA / OFT merged, or full)
source    an existing checkpoint or store (``path``)    -
export    ``agent/``: the shipping checkpoint           checkpoint
======== ============================================ ==========================

Under torchrun (``WORLD_SIZE`` > 1) the kinds of :data:`EVERY_RANK` run on every rank:
``collect`` and ``rollout`` once, split across the ranks (:mod:`.ranks`); ``train`` with DDP;
``s1``, ``room_type``, ``object_category``, ``instruction_reader`` and ``request_intent``
data parallel
(:mod:`.part_training`), rank 0 writing. The other kinds run on rank 0 while the others wait.
Training kinds run on ``training.device`` in ``training.amp`` precision.
"""

from __future__ import annotations

import dataclasses
import logging
import shutil
from collections.abc import Callable, Sequence
from pathlib import Path

from vla_gr.errors import UserError
from vla_gr.training.distributed import is_main_process, process_rank, wait_for_ranks
from vla_gr.training.part_training import Compute
from vla_gr.training.ranks import collect_on_ranks, rollout_on_ranks

log = logging.getLogger(__name__)

__all__ = ["EVERY_RANK", "STAGES", "Services"]

#: Stage kinds every rank runs under torchrun (see the module docstring).
EVERY_RANK = frozenset(
    {
        "collect",
        "train",
        "rollout",
        "s1",
        "room_type",
        "object_category",
        "instruction_reader",
        "request_intent",
    }  # fmt: skip
)


@dataclasses.dataclass(frozen=True)
class Services:
    """What the app hands the pipeline: ``train(cfg, resolved) -> summary`` (the training
    loop), ``evaluate(cfg) -> metrics`` (the evaluation harness, for rollouts) and, for
    rollouts split across torchrun's ranks, ``merge(cfg, parts) -> metrics`` (eval runs of
    shares of ``cfg``'s episodes written as one run)."""

    train: Callable
    evaluate: Callable
    merge: Callable | None = None


def _inputs(stage, inputs: dict[str, Path], want: int, most: int | None = None) -> list[Path]:
    """The products of the stage's inputs, in order; StageError-like UserError when there
    are fewer than ``want`` or more than ``most``."""
    paths = [inputs[name] for name in stage.inputs]
    most = want if most is None else most
    if not want <= len(paths) <= most:
        count = f"{want}" if want == most else f"{want} to {most}"
        raise UserError(
            f"pipeline.stages[{stage.name}] (kind {stage.kind}) reads {count} inputs; "
            f"inputs={list(stage.inputs)}"
        )
    return paths


def collect_stage(stage, cfg, resolved, folder: Path, inputs, services) -> Path:
    """Expert episodes into ``store.zarr`` (``collect.*``), after a copy of the input store
    when there is one; resumes by appending the episodes not yet in the store."""
    from vla_gr.data.collect import collect
    from vla_gr.data.verify import copy_store

    bases = _inputs(stage, inputs, 0, 1)
    store = folder / "store.zarr"
    copied = folder / "copied"  # marks a complete copy of the input store
    rank, world = process_rank()
    if bases and not copied.exists() and rank == 0:
        copy_store(_store_of(bases[0]), store, overwrite=True)
        copied.touch()
    if world > 1:
        wait_for_ranks()  # the copy is complete before any rank reads it
        collect_on_ranks(cfg, store, folder / "ranks")
        return store
    c = dataclasses.replace(cfg.collect, output=str(store), mode="append")
    collect(dataclasses.replace(cfg, collect=c))
    return store


def train_stage(stage, cfg, resolved, folder: Path, inputs, services) -> Path:
    """The training loop (``training.*``) on the input store, starting from the input
    checkpoint's weights when there is one; resumes from ``run/checkpoints/latest``."""
    paths = _inputs(stage, inputs, 1, 2)
    latest = folder / "run" / "checkpoints" / "latest"
    t = dataclasses.replace(
        cfg.training,
        dataset=str(_store_of(paths[0])),
        if_missing="error",
        output_dir=str(folder),
        run_name="run",
        init_from=str(paths[1]) if len(paths) > 1 else cfg.training.init_from,
        resume=str(latest) if latest.exists() else None,
    )
    resolved = resolved.copy()
    for key in ("dataset", "if_missing", "output_dir", "run_name", "init_from", "resume"):
        resolved.training[key] = getattr(t, key)
    services.train(dataclasses.replace(cfg, training=t), resolved)
    return (folder / "run" / "checkpoints" / stage.use).resolve()


def _store_of(product: Path) -> Path:
    """A store product (a ``collect`` or ``dagger`` stage's ``store.zarr``)."""
    if not product.is_dir() or product.suffix != ".zarr":
        raise UserError(f"{product} is not an episode store (a collect or dagger stage's)")
    return product


def rollout_stage(stage, cfg, resolved, folder: Path, inputs, services) -> Path:
    """The input agent, with the stage's ``model_overrides``, closed-loop on ``eval.*``'s
    episodes (``train`` episodes for DAgger and S1 data); resumes the rows already written."""
    (checkpoint,) = _inputs(stage, inputs, 1)
    out = folder / "rollouts"
    e = dataclasses.replace(
        cfg.eval,
        agent="checkpoint",
        agents=[],
        checkpoint=str(checkpoint),
        model_overrides=list(stage.model_overrides),
        output_dir=str(out),
        video_successes=0,
        video_per_cause=0,
    )
    cfg = dataclasses.replace(cfg, eval=e)
    if process_rank()[1] > 1:
        if services.merge is None:
            raise UserError("a rollout stage under torchrun needs the app's merge of eval runs")
        metrics = rollout_on_ranks(cfg, out, folder / "ranks", services.evaluate, services.merge)
    else:
        metrics = services.evaluate(cfg)
    if is_main_process():
        m = metrics["metrics"]
        log.info("stage %s: SR %.3f on %d %s episodes", stage.name, m["success"], m["episodes"],
                 e.split)  # fmt: skip
    return out


def dagger_stage(stage, cfg, resolved, folder: Path, inputs, services) -> Path:
    """A copy of the input store with the rollouts' states relabelled by the world (their
    true goal and distractor masks) appended."""
    from vla_gr.training.dagger import aggregate

    rollouts, base = _inputs(stage, inputs, 2)
    store = folder / "store.zarr"
    if store.exists():  # an interrupted copy or append: start the aggregate again
        shutil.rmtree(store)
    aggregate(rollouts, _store_of(base), store)
    return store


def s1_data_stage(stage, cfg, resolved, folder: Path, inputs, services) -> Path:
    """S1's inputs and the local teacher's labels at every state of the rollouts (made with
    the input checkpoint's agent)."""
    from vla_gr.training.s1_data import relabel_run

    rollouts, checkpoint = _inputs(stage, inputs, 2)
    data = folder / "data"
    if data.exists():  # an interrupted relabelling: start it again
        shutil.rmtree(data)
    relabel_run(rollouts, checkpoint, data, workers=cfg.training.s1.workers)
    return data


def s1_stage(stage, cfg, resolved, folder: Path, inputs, services) -> Path:
    """The learned S1 (``training.s1.*``) trained on the S1 data inputs, written with the
    input agent's S2 as a new agent."""
    from vla_gr.training.s1 import train_s1

    checkpoint, *data = _inputs(stage, inputs, 2, 99)
    s = cfg.training.s1
    agent = folder / "agent"
    train_s1(
        checkpoint, agent, data, steps=s.steps, batch_size=s.batch_size, lr=s.lr,
        seed=cfg.seed, settings=s.settings, init_s1=s.init_s1, compute=_compute(cfg),
    )  # fmt: skip
    return agent


def _compute(cfg) -> Compute:
    """Where and in which precision a part stage trains: ``training.device``, ``.amp``."""
    return Compute(device=cfg.training.device, amp=cfg.training.amp)


def _frame_part_stage(part: str, stage, cfg, folder: Path, inputs) -> Path:
    """Train ``model.<part>`` (``training.<part>``) of the input agent on the input store's
    frames; the product is the whole agent with it."""
    from vla_gr.training import object_category, room_type

    checkpoint, store = _inputs(stage, inputs, 2)
    p = getattr(cfg.training, part)
    if part == "room_type":
        labels, read = room_type.labels(p.settings), room_type.room_frames
        train = room_type.train_room_type
        extra = {}
    else:
        labels, read = object_category.labels(p.settings), object_category.category_frames
        train = object_category.train_object_category
        extra = {"background_weight": p.background_weight}
    frames = read(_store_of(store), labels, p.first, p.episodes, p.stride)
    agent = folder / "agent"
    train(
        checkpoint, agent, frames, labels, steps=p.steps, batch_size=p.batch_size, lr=p.lr,
        seed=cfg.seed, settings=p.settings, reject_threshold=p.reject_threshold,
        compute=_compute(cfg), **extra,
    )  # fmt: skip
    return agent


def room_type_stage(stage, cfg, resolved, folder: Path, inputs, services) -> Path:
    """The room-type classifier (S2's room check) trained on the store's frames."""
    return _frame_part_stage("room_type", stage, cfg, folder, inputs)


def object_category_stage(stage, cfg, resolved, folder: Path, inputs, services) -> Path:
    """The object-category segmenter (S2's object checks) trained on the store's frames."""
    return _frame_part_stage("object_category", stage, cfg, folder, inputs)


def instruction_reader_stage(stage, cfg, resolved, folder: Path, inputs, services) -> Path:
    """The instruction reader (``training.instruction_reader``) trained on generated requests
    and calibrated on the development sets, written with the input agent."""
    from vla_gr.training.instruction_reader import train_instruction_reader

    (checkpoint,) = _inputs(stage, inputs, 1)
    r = cfg.training.instruction_reader
    agent = folder / "agent"
    train_instruction_reader(
        checkpoint, agent, dev_sets=r.dev_sets, count=r.count, steps=r.steps,
        batch_size=r.batch_size, lr=r.lr, seed=cfg.seed, settings=r.settings,
        compute=_compute(cfg),
    )  # fmt: skip
    return agent


def request_intent_stage(stage, cfg, resolved, folder: Path, inputs, services) -> Path:
    """The input agent's reader with a request intent head (``training.request_intent``)
    trained on grammar requests and remarks, ``min_intent`` chosen on the development sets."""
    from vla_gr.training.request_intent import train_request_intent

    (checkpoint,) = _inputs(stage, inputs, 1)
    r = cfg.training.request_intent
    agent = folder / "agent"
    train_request_intent(
        checkpoint, agent, dev_sets=r.dev_sets, count=r.count, steps=r.steps,
        batch_size=r.batch_size, lr=r.lr, seed=cfg.seed, compute=_compute(cfg),
    )  # fmt: skip
    return agent


def room_prior_stage(stage, cfg, resolved, folder: Path, inputs, services) -> Path:
    """The input agent with the navigator's room search on: where categories stand counted
    from ``training.room_prior.houses`` houses of its split, and the stage's
    ``model_overrides`` (e.g. ``navigator.room_search.keep``)."""
    from vla_gr.policy.export import export_pretrained
    from vla_gr.training.room_prior import fit_room_prior, room_search_overrides

    (checkpoint,) = _inputs(stage, inputs, 1)
    r = cfg.training.room_prior
    overrides = room_search_overrides(fit_room_prior(r.houses, r.split))
    return export_pretrained(checkpoint, folder / "agent", overrides + list(stage.model_overrides))


def graft_stage(stage, cfg, resolved, folder: Path, inputs, services) -> Path:
    """The input agent with model part ``part`` and its weights taken from the donor (the
    second input), with the stage's ``model_overrides`` (e.g. the part's threshold)."""
    from vla_gr.training.agent_stage import graft_part

    checkpoint, donor = _inputs(stage, inputs, 2)
    return graft_part(checkpoint, donor, stage.part, folder / "agent", stage.model_overrides)


def adapt_stage(stage, cfg, resolved, folder: Path, inputs, services) -> Path:
    """The input agent with its goal head adapted on the input store's frames
    (``training.adapt``: LoRA / OFT merged into the weights, or full fine-tuning); an
    interrupted stage starts again (minutes)."""
    from vla_gr.training.adapt import adapt_goal_head

    checkpoint, store = _inputs(stage, inputs, 2)
    agent = folder / "agent"
    adapt_goal_head(
        checkpoint, _store_of(store), agent, cfg.training.adapt, seed=cfg.seed,
        compute=_compute(cfg),
    )  # fmt: skip
    return agent


def source_stage(stage, cfg, resolved, folder: Path, inputs, services) -> Path:
    """An existing checkpoint or store (``path``) as a stage's product, e.g. the shipped
    agent an ablation starts from; its digest decides whether later stages rerun."""
    _inputs(stage, inputs, 0)
    path = Path(stage.path)
    if not path.exists():
        raise UserError(f"pipeline.stages[{stage.name}].path={stage.path} does not exist")
    return path


def export_stage(stage, cfg, resolved, folder: Path, inputs, services) -> Path:
    """The input agent as a shipping checkpoint with the stage's inference settings."""
    from vla_gr.policy.export import export_pretrained

    (checkpoint,) = _inputs(stage, inputs, 1)
    return export_pretrained(checkpoint, folder / "agent", list(stage.model_overrides))


STAGES: dict[str, Callable[..., Path]] = {
    "collect": collect_stage,
    "train": train_stage,
    "rollout": rollout_stage,
    "dagger": dagger_stage,
    "s1_data": s1_data_stage,
    "s1": s1_stage,
    "export": export_stage,
    "room_type": room_type_stage,
    "object_category": object_category_stage,
    "instruction_reader": instruction_reader_stage,
    "request_intent": request_intent_stage,
    "room_prior": room_prior_stage,
    "source": source_stage,
    "graft": graft_stage,
    "adapt": adapt_stage,
}


def check_kinds(kinds: Sequence[str]) -> None:
    """Every kind the schema names has an implementation (a test asserts it)."""
    missing = sorted(set(kinds) - set(STAGES))
    if missing:
        raise RuntimeError(f"stage kinds without an implementation: {missing}")
