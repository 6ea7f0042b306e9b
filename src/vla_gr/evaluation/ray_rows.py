"""``eval.backend=ray``: the rows of :func:`~vla_gr.evaluation.runner.iter_episode_rows` from
Ray actors, each running the local workers' own ``_init_worker`` and ``_work``
(:func:`vla_gr.data.ray_workers.map_on_ray`).

The agent's checkpoint travels as bytes through Ray's object store (the files its manifest
lists, and the manifest), is written to a temporary folder on the worker and loaded from
there, which checks every file against its SHA-256 in the manifest; an episodes file travels
as its specs. No worker reads a path of the driver's machine.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path

from vla_gr.evaluation.runner import _WORKER, _init_worker, _work

#: This worker's copy of the checkpoint (removed when the worker closes).
_LOCAL: dict = {}


def checkpoint_files(path: str | Path) -> dict[str, bytes]:
    """{file name: bytes} of checkpoint ``path``: the files its manifest lists and the
    manifest (not what else lies in the folder)."""
    from vla_gr.checkpoint import MANIFEST_FILE

    path = Path(path)
    names = [*json.loads((path / MANIFEST_FILE).read_text())["files"], MANIFEST_FILE]
    return {name: (path / name).read_bytes() for name in names}


def write_checkpoint_files(files: dict[str, bytes], folder: Path) -> Path:
    """Write :func:`checkpoint_files`' ``files`` into ``folder`` (file names only, no paths)."""
    for name, data in files.items():
        if Path(name).name != name or name in ("", ".", ".."):
            raise ValueError(f"checkpoint file name {name!r} is not a plain file name")
        (folder / name).write_bytes(data)
    return folder


def _init_remote(files: dict[str, bytes] | None, cfg, agent: str, env_kwargs: dict, warm) -> None:
    """A Ray worker's ``_init_worker``, on its own copy of the checkpoint (``files``)."""
    if files is not None:
        folder = write_checkpoint_files(files, Path(tempfile.mkdtemp(prefix="vla_gr_ckpt_")))
        _LOCAL["folder"] = folder
        cfg = dataclasses.replace(cfg, eval=dataclasses.replace(cfg.eval, checkpoint=str(folder)))
    try:
        _init_worker(cfg, agent, env_kwargs, warm)
    except BaseException:
        _remove_copy()
        raise


def _remove_copy() -> None:
    folder = _LOCAL.pop("folder", None)
    if folder is not None:
        shutil.rmtree(folder, ignore_errors=True)


def _close_remote() -> None:
    _WORKER.pop("env").close()
    _WORKER.clear()
    _remove_copy()


def ray_episode_rows(
    cfg, agent_name: str, env_kwargs: dict, indices: Sequence[int], workers: int
) -> Iterator[dict]:
    """:func:`~vla_gr.evaluation.runner.iter_episode_rows` on the Ray cluster of
    ``eval.ray_address``: the same rows, in the order of ``indices``.

    A variant is resolved here (its registered agent and config), so the one checkpoint the
    agent loads is the one that travels.
    """
    from vla_gr.data.ray_workers import map_on_ray, portable_env_kwargs
    from vla_gr.evaluation.agents import agent_checkpoint, resolve_agent

    base, sub = resolve_agent(agent_name, cfg)
    path = agent_checkpoint(base, sub)
    files = checkpoint_files(path) if path else None
    init_args = (files, sub, base, portable_env_kwargs(env_kwargs), tuple(indices))
    address = cfg.eval.ray_address
    gpus = 1.0 if cfg.eval.device.startswith("cuda") else 0.0  # an agent on a GPU gets one
    yield from map_on_ray(
        _init_remote, init_args, _work, indices, workers, _close_remote, address, "eval", gpus
    )
