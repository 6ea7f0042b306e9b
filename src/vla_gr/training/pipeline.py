"""The staged training app: a recipe's stages run in order, each resumable and skipped when
its output already records the same inputs and settings.

Each stage (``pipeline.stages[i]``, :class:`~vla_gr.configs.pipeline_schema.StageConfig`)
runs on the recipe's config with its own ``overrides`` and reads the products of the
earlier stages it names. Its folder ``pipeline.output_dir/<name>/`` holds its product and

- ``started.json``: the stage's input and config hashes, written before any work, so an
  interrupted stage is resumed only under the same inputs and settings;
- ``stage.json``: written last (atomically), the same hashes, the product's path and
  SHA-256 digest, and the seconds of each attempt. Its presence means the stage is done.

At the next run a done stage with the same hashes is skipped; one made from other inputs
or settings reruns (``pipeline.on_stale=rerun``) or stops the run naming it (``refuse``).
A stage interrupted under the same hashes runs again and resumes where its kind can
(training from ``latest``, collection and rollouts from the episodes already written).

The stage kinds live in :mod:`vla_gr.training.stages`; the training loop and the
evaluation harness are handed in (:class:`~vla_gr.training.stages.Services`), so this
package imports no app.

Under torchrun every rank runs this loop on the same records; rank 0 alone writes them (and
removes a stale output), and the ranks wait for one another before each stage and after it. A
stage of a kind in :data:`~vla_gr.training.stages.EVERY_RANK` runs on every rank, any other on
rank 0 alone.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import shutil
import time
from collections.abc import Mapping
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from vla_gr.errors import UserError
from vla_gr.training.distributed import is_main_process, wait_for_ranks

log = logging.getLogger(__name__)

__all__ = ["StageError", "run_pipeline", "stage_config", "tree_digest"]

STAGE_FILE = "stage.json"
STARTED_FILE = "started.json"


class StageError(UserError):
    """A stage that cannot run: a stale output under ``on_stale=refuse``, a missing input."""


def tree_digest(path: Path) -> str:
    """SHA-256 over every file below ``path`` (relative name and content), in sorted order;
    of the file itself when ``path`` is a file. Symbolic links are followed."""
    h = hashlib.sha256()
    root = Path(path).resolve()
    files = [root] if root.is_file() else sorted(p for p in root.rglob("*") if p.is_file())
    for f in files:
        h.update(str(f.relative_to(root) if f != root else f.name).encode() + b"\0")
        with f.open("rb") as stream:
            for block in iter(lambda: stream.read(1 << 20), b""):
                h.update(block)
        h.update(b"\0")
    return h.hexdigest()


def stage_config(resolved: DictConfig, stage) -> tuple[DictConfig, object]:
    """(the resolved config, the validated ``VLAGRConfig``) of ``stage``: the recipe without
    its stages, with the stage's ``overrides`` applied."""
    from vla_gr.configs.schema import VLAGRConfig

    base = OmegaConf.to_container(resolved, resolve=False)
    base["pipeline"]["stages"] = []
    try:
        merged = OmegaConf.merge(
            OmegaConf.structured(VLAGRConfig),
            OmegaConf.create(base),
            OmegaConf.from_dotlist(list(stage.overrides)),
        )
        cfg = OmegaConf.to_object(merged)
    except Exception as err:  # noqa: BLE001 - any schema failure names the stage and key
        first = str(err).strip().splitlines()[0]
        key = getattr(err, "full_key", None)
        where = f" ({key})" if key else ""
        raise StageError(f"pipeline.stages[{stage.name}].overrides{where}: {first}") from None
    return merged, cfg


def _config_digest(stage, merged: DictConfig) -> str:
    """What decides a stage's output: its kind, inference overrides and resolved config
    (minus where outputs go, how progress is shown and which episodes are filmed)."""
    tree = OmegaConf.to_container(merged, resolve=True)
    tree.pop("pipeline", None)
    for section in ("collect", "eval", "logging"):
        tree.get(section, {}).pop("progress", None)
    tree.get("eval", {}).pop("workers", None)  # any number of workers gives the same rows
    tree.get("collect", {}).pop("workers", None)
    for key in [k for k in tree.get("eval", {}) if k.startswith("video_")]:
        tree["eval"].pop(key)  # which episodes are filmed: pictures, not the product
    tree.get("training", {}).pop("eval_videos", None)
    # recomputing activations in backward gives the same weights: memory, not the product
    tree.get("training", {}).pop("gradient_checkpointing", None)
    payload = {"kind": stage.kind, "model_overrides": list(stage.model_overrides), "cfg": tree}
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()


def _read(path: Path) -> dict | None:
    return json.loads(path.read_text()) if path.is_file() else None


def _write_atomic(path: Path, record: Mapping) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}")
    tmp.write_text(json.dumps(record, indent=1, sort_keys=True))
    os.replace(tmp, path)


def run_pipeline(resolved: DictConfig, cfg, services) -> dict[str, dict]:
    """Run the stages of ``cfg.pipeline`` (``resolved`` is the recipe as composed); returns
    each stage's record (``stage.json``) by name."""
    from vla_gr.training.stages import EVERY_RANK, STAGES

    p = cfg.pipeline
    root = Path(p.output_dir)
    main = is_main_process()
    root.mkdir(parents=True, exist_ok=True)
    records: dict[str, dict] = {}
    for stage in p.stages:
        folder = root / stage.name
        merged, stage_cfg = stage_config(resolved, stage)
        wanted = {
            "kind": stage.kind,
            "config_sha256": _config_digest(stage, merged),
            "inputs": {name: records[name]["product_sha256"] for name in stage.inputs},
        }
        done, started = _read(folder / STAGE_FILE), _read(folder / STARTED_FILE)
        wait_for_ranks()  # every rank has read the records before rank 0 changes them
        if done is not None and _same(done, wanted):
            log.info("stage %s: up to date (%s), skipped", stage.name, done["product"])
            records[stage.name] = done
            continue
        previous = done or started
        if previous is not None and not _same(previous, wanted):
            why = _why_stale(previous, wanted)
            if p.on_stale == "refuse":
                raise StageError(
                    f"stage {stage.name}: {folder} was made with other {why}; remove it or "
                    "pass pipeline.on_stale=rerun"
                )
            log.info("stage %s: %s changed since %s was made; running it again", stage.name,
                     why, folder)  # fmt: skip
            if main:
                shutil.rmtree(folder)
            previous = None
        attempts = list((previous or {}).get("attempts", []))
        if main:
            folder.mkdir(parents=True, exist_ok=True)
            _write_atomic(folder / STARTED_FILE, {**wanted, "attempts": attempts})
        wait_for_ranks()
        products = {name: Path(records[name]["product"]) for name in stage.inputs}
        log.info("stage %s (%s): running in %s", stage.name, stage.kind, folder)
        t0 = time.time()
        product = None
        if main or stage.kind in EVERY_RANK:
            product = STAGES[stage.kind](stage, stage_cfg, merged, folder, products, services)
        attempts.append({"started": t0, "seconds": round(time.time() - t0, 1)})
        if main:
            record = {
                **wanted,
                "product": str(Path(product)),
                "product_sha256": tree_digest(Path(product)),
                "attempts": attempts,
                "seconds": round(sum(a["seconds"] for a in attempts), 1),
            }
            _write_atomic(folder / STAGE_FILE, record)
            log.info("stage %s: done in %.0f s -> %s", stage.name, record["seconds"], product)
        wait_for_ranks()
        records[stage.name] = _read(folder / STAGE_FILE)  # rank 0's record, on every rank
    return records


def _same(record: Mapping, wanted: Mapping) -> bool:
    return all(record.get(k) == v for k, v in wanted.items())


def _why_stale(record: Mapping, wanted: Mapping) -> str:
    """Which of the stage's inputs or settings differ from those its output was made with."""
    if (
        record.get("kind") != wanted["kind"]
        or record.get("config_sha256") != wanted["config_sha256"]
    ):
        return "settings"
    changed = [k for k, v in wanted["inputs"].items() if record.get("inputs", {}).get(k) != v]
    return f"inputs ({', '.join(changed)})" if changed else "inputs"
