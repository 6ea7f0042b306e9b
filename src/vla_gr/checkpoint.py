"""Checkpoint folders: written by training, read by the agent; they survive kills and
refuse to load when corrupt or mismatched.

Below both of its users: ``vla_gr.train`` (via ``training/state.py``) writes them and
``VLAGRPolicy.from_pretrained`` (``policy.py``) reads them back; this module imports
nothing of ``vla_gr``.

A checkpoint is a folder ``checkpoints/step_XXXXXXXX/`` holding

- ``model.safetensors``     weights for evaluation (EMA averages when EMA is on);
- ``config.yaml``           the resolved run config;
- ``trainer_state.json``    step, epoch, sampler position, best metric, scheduler, scaler,
                            optimiser hyper-parameters, Python/NumPy RNG states;
- ``training_state.safetensors``  raw weights, EMA, optimiser moments, torch RNG states;
- ``manifest.json``         format, version and the SHA-256 and size of every file.

A *pretrained folder* (``NavigationPolicy.save_pretrained``, huggingface_hub's
``PyTorchModelHubMixin`` layout) is the same format with ``config.json`` (the ``model`` section
alone) in place of ``config.yaml`` and no training state: ``model.safetensors``,
``config.json``, ``README.md`` (a model card) and ``manifest.json``.

It is written to ``checkpoints/.tmp-*`` and renamed (atomic on POSIX), then the
``latest`` / ``best`` symlinks are swapped with ``os.replace`` (atomic too). A kill at
any moment therefore leaves every link pointing at a complete folder; leftovers of an
interrupted write are removed on the next save. Loading verifies the manifest checksums
and never unpickles: tensors come from safetensors, everything else from JSON / YAML.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import random
import shutil
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
import yaml
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file
from torch import nn

log = logging.getLogger(__name__)

FORMAT_NAME = "vla_gr.checkpoint"
FORMAT_VERSION = 1
MODEL_FILE = "model.safetensors"
CONFIG_FILE = "config.yaml"
HUB_CONFIG_FILE = "config.json"  # a pretrained folder's config: the model section
STATE_FILE = "trainer_state.json"
TRAINING_FILE = "training_state.safetensors"
MANIFEST_FILE = "manifest.json"
LINKS = ("latest", "best")
#: A folder given as a checkpoint that is none is searched this deep for the checkpoints it
#: holds (a pipeline's ``<stage>/run/checkpoints/best``), looking at this many folders at most;
#: the error names this many of them.
SEARCH_DEPTH = 4
SEARCH_FOLDERS = 2000
MAX_NAMED = 6


class CheckpointError(ValueError):
    """A checkpoint that is missing, corrupt or does not fit the model; says which and why."""


@dataclass
class LoadedCheckpoint:
    """Everything read back from a checkpoint folder (tensors on the CPU)."""

    path: Path
    model: dict[str, torch.Tensor]
    state: dict
    config_yaml: str  # the run config; a pretrained folder's config.json as {"model": ...}
    training: dict[str, torch.Tensor] = field(default_factory=dict)
    config_file: str = CONFIG_FILE  # the file the config came from
    manifest: dict = field(default_factory=dict)  # manifest.json, as read and verified

    def group(self, prefix: str) -> dict[str, torch.Tensor]:
        """Entries of ``training_state.safetensors`` under ``prefix.`` (prefix stripped)."""
        p = prefix + "."
        return {k[len(p) :]: v for k, v in self.training.items() if k.startswith(p)}


# --------------------------------------------------------------------------- pure helpers


def sha256_file(path: Path, chunk: int = 1 << 20) -> str:
    """Hex SHA-256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(chunk):
            h.update(block)
    return h.hexdigest()


def flatten_optimizer_state(state: Mapping) -> tuple[dict[str, torch.Tensor], dict]:
    """``optimizer.state_dict()`` -> (tensors ``{"<param idx>.<key>": T}``, JSON-able rest)."""
    tensors: dict[str, torch.Tensor] = {}
    scalars: dict[str, dict] = {}
    for idx, entry in state["state"].items():
        for key, value in entry.items():
            if isinstance(value, torch.Tensor):
                tensors[f"{idx}.{key}"] = value.detach().cpu().contiguous()
            else:
                scalars.setdefault(str(idx), {})[key] = value
    return tensors, {"param_groups": list(state["param_groups"]), "scalars": scalars}


def unflatten_optimizer_state(tensors: Mapping[str, torch.Tensor], meta: Mapping) -> dict:
    """Inverse of :func:`flatten_optimizer_state`."""
    state: dict[int, dict] = {}
    for name, value in tensors.items():
        idx, key = name.split(".", 1)
        state.setdefault(int(idx), {})[key] = value
    for idx, entries in meta.get("scalars", {}).items():
        state.setdefault(int(idx), {}).update(entries)
    groups = []
    for g in meta["param_groups"]:
        g = dict(g)
        if isinstance(g.get("betas"), list):  # JSON turned the tuple into a list
            g["betas"] = tuple(g["betas"])
        groups.append(g)
    return {"state": state, "param_groups": groups}


def capture_rng() -> tuple[dict, dict[str, torch.Tensor]]:
    """This process's RNG states: (JSON part: Python, NumPy; tensor part: torch CPU/CUDA)."""
    version, internal, gauss = random.getstate()
    name, keys, pos, has_gauss, cached = np.random.get_state()
    json_part = {
        "python": [version, list(internal), gauss],
        "numpy": [name, keys.tolist(), int(pos), int(has_gauss), float(cached)],
    }
    tensors = {"torch": torch.get_rng_state()}
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        tensors["cuda"] = torch.cuda.get_rng_state()
    return json_part, tensors


def restore_rng(json_part: Mapping, tensors: Mapping[str, torch.Tensor]) -> None:
    """Inverse of :func:`capture_rng`."""
    version, internal, gauss = json_part["python"]
    random.setstate((version, tuple(internal), gauss))
    name, keys, pos, has_gauss, cached = json_part["numpy"]
    np.random.set_state((name, np.asarray(keys, dtype=np.uint32), pos, has_gauss, cached))
    torch.set_rng_state(tensors["torch"].to(torch.uint8))
    if "cuda" in tensors and torch.cuda.is_available():
        torch.cuda.set_rng_state(tensors["cuda"].to(torch.uint8))


def config_differences(old: Mapping, new: Mapping, prefix: str = "") -> list[str]:
    """Dotted keys whose values differ between two nested config dicts."""
    diffs = []
    for key in sorted(set(old) | set(new)):
        a, b = old.get(key, "<absent>"), new.get(key, "<absent>")
        name = f"{prefix}{key}"
        if isinstance(a, Mapping) and isinstance(b, Mapping):
            diffs += config_differences(a, b, name + ".")
        elif a != b:
            diffs.append(f"{name}: {a!r} -> {b!r}")
    return diffs


# --------------------------------------------------------------------------- writing


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _write_bytes(path: Path, data: bytes) -> None:
    with open(path, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())


def _default_file_mode() -> int:
    """The permissions ``open`` gives a new file under the process umask."""
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


def _save_tensors(
    path: Path, tensors: Mapping[str, torch.Tensor], metadata: dict[str, str] | None = None
) -> None:
    tensors = {k: v.detach().cpu().contiguous() for k, v in tensors.items()}
    save_file(tensors, str(path), metadata=metadata)
    os.chmod(path, _default_file_mode())  # safetensors writes 0600; match the other files
    with open(path, "rb") as f:
        os.fsync(f.fileno())


def _atomic_symlink(target_name: str, link: Path) -> None:
    tmp = link.with_name(f".{link.name}.tmp-{os.getpid()}")
    if tmp.is_symlink() or tmp.exists():
        tmp.unlink()
    os.symlink(target_name, tmp)
    os.replace(tmp, link)


def save_folder(dst: str | Path, fill: Callable[[Path], None], step: int | None = None) -> Path:
    """Write checkpoint folder ``dst`` whole: ``fill(staging)`` writes its files into
    ``.tmp-<name>-<pid>`` beside it, ``manifest.json`` (with ``step`` when given) is written
    last and the staging folder is renamed ``dst``. An existing checkpoint or empty folder
    ``dst`` is replaced; any other existing path is refused."""
    dst = Path(dst)
    if dst.is_symlink() or (dst.exists() and not _replaceable(dst)):
        raise CheckpointError(
            f"{dst} exists and is not a checkpoint folder; choose another folder or remove it"
        )
    root = dst.parent
    root.mkdir(parents=True, exist_ok=True)
    tmp = root / f".tmp-{dst.name}-{os.getpid()}"
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir()
    try:
        fill(tmp)
        manifest = {"format": FORMAT_NAME, "format_version": FORMAT_VERSION}
        if step is not None:
            manifest["step"] = int(step)
        manifest["files"] = {
            p.name: {"sha256": sha256_file(p), "bytes": p.stat().st_size}
            for p in sorted(tmp.iterdir())
        }
        _write_bytes(tmp / MANIFEST_FILE, json.dumps(manifest, indent=1).encode())  # last
        _fsync_dir(tmp)
    except Exception:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    if dst.exists():  # saved again (the same step): move the old copy aside first
        old = root / f".tmp-old-{dst.name}-{os.getpid()}"
        os.rename(dst, old)
        os.rename(tmp, dst)
        shutil.rmtree(old)
    else:
        os.rename(tmp, dst)
    _fsync_dir(root)
    return dst


def _replaceable(folder: Path) -> bool:
    """Whether ``save_folder`` may replace existing ``folder``: a checkpoint or empty."""
    return folder.is_dir() and ((folder / MANIFEST_FILE).is_file() or not any(folder.iterdir()))


def write_pretrained_files(
    folder: Path, model_tensors: Mapping[str, torch.Tensor], model_config: Mapping
) -> None:
    """A pretrained folder's own files in ``folder``: ``model.safetensors`` (with the
    ``{"format": "pt"}`` metadata of PyTorch's safetensors files) and ``config.json`` (the
    model section, every key)."""
    _save_tensors(folder / MODEL_FILE, model_tensors, metadata={"format": "pt"})
    _write_bytes(folder / HUB_CONFIG_FILE, json.dumps(dict(model_config), indent=2).encode())


def save_checkpoint(
    checkpoints_dir: str | Path,
    step: int,
    model_tensors: Mapping[str, torch.Tensor],
    state: Mapping,
    config_yaml: str,
    training_tensors: Mapping[str, torch.Tensor] | None = None,
    links: Sequence[str] = ("latest",),
) -> Path:
    """Write ``checkpoints_dir/step_<step>`` atomically and point ``links`` at it."""
    root = Path(checkpoints_dir)
    root.mkdir(parents=True, exist_ok=True)
    for link in links:
        if link not in LINKS:
            raise ValueError(f"link {link!r} is not valid; choose from {list(LINKS)}")
    name = f"step_{step:08d}"

    def fill(tmp: Path) -> None:
        files = {MODEL_FILE: model_tensors}
        if training_tensors:
            files[TRAINING_FILE] = training_tensors
        for fname, tensors in files.items():
            _save_tensors(tmp / fname, tensors)
        _write_bytes(tmp / CONFIG_FILE, config_yaml.encode())
        _write_bytes(tmp / STATE_FILE, json.dumps(dict(state), indent=1, sort_keys=True).encode())

    final = save_folder(root / name, fill, step=step)
    for link in links:
        _atomic_symlink(name, root / link)
    _fsync_dir(root)
    log.info("checkpoint %s (%s)", final, ", ".join(links) or "no links")
    return final


def add_files(
    folder: str | Path,
    files: Mapping[str, bytes],
    records: Mapping[str, object],
    drop: Sequence[str] = (),
) -> None:
    """Add ``files`` (name -> bytes) to checkpoint ``folder`` and to its manifest, set the
    manifest's top-level ``records``, and remove the files ``drop`` names (from both).

    Each file is written to a temporary name and renamed, then the manifest likewise; the
    dropped files go last. A kill leaves the old manifest over intact files, or the new one:
    so a file it lists is never rewritten in place (give new contents a new name).
    """
    folder = Path(folder)
    manifest = _parse(folder, MANIFEST_FILE, _read_json)
    listed = manifest["files"]
    for name, data in files.items():
        if name in (MANIFEST_FILE, *listed) and name not in drop:
            raise CheckpointError(f"checkpoint {folder}: {name} is listed already")
        tmp = folder / f".{name}.tmp-{os.getpid()}"
        _write_bytes(tmp, data)
        os.replace(tmp, folder / name)
    for name in drop:
        listed.pop(name, None)
    for name in files:
        listed[name] = {
            "sha256": sha256_file(folder / name),
            "bytes": (folder / name).stat().st_size,
        }
    manifest.update(records)
    manifest["files"] = dict(sorted(listed.items()))
    tmp = folder / f".{MANIFEST_FILE}.tmp-{os.getpid()}"
    _write_bytes(tmp, json.dumps(manifest, indent=1).encode())
    os.replace(tmp, folder / MANIFEST_FILE)
    _fsync_dir(folder)
    for name in drop:
        if name not in files and (folder / name).is_file():
            (folder / name).unlink()


def prune_checkpoints(checkpoints_dir: str | Path, keep: int) -> list[Path]:
    """Delete step folders beyond the ``keep`` newest, never one a link points at, and the
    leftovers of interrupted writes; returns what was removed."""
    root = Path(checkpoints_dir)
    linked = {(root / link).resolve() for link in LINKS if (root / link).is_symlink()}
    removed = []
    steps = sorted(p for p in root.glob("step_*") if p.is_dir())
    for p in steps[: max(0, len(steps) - keep)]:
        if p.resolve() not in linked:
            shutil.rmtree(p, ignore_errors=True)
            removed.append(p)
    for p in root.glob(".tmp-*"):
        if not p.name.endswith(f"-{os.getpid()}"):
            shutil.rmtree(p, ignore_errors=True) if p.is_dir() else p.unlink()
            removed.append(p)
    return removed


# --------------------------------------------------------------------------- reading


def read_checkpoint(
    path: str | Path, verify: bool = True, prefer: str = "best"
) -> LoadedCheckpoint:
    """Read and verify a checkpoint folder (or a ``latest``/``best`` link to one) or a
    pretrained folder (``config.json``: its config is ``{"model": <config.json>}``).

    A folder that holds checkpoints (a run, its ``checkpoints/``, a pipeline's stage) is
    refused naming them and suggesting one (a ``prefer`` link first: ``best`` to run an agent,
    ``latest`` to resume)."""
    path = Path(path)
    if not path.exists():
        hint = " (broken link)" if path.is_symlink() else ""
        raise CheckpointError(f"checkpoint {path} does not exist{hint}")
    if not path.is_dir():
        raise CheckpointError(f"checkpoint {path} is not a folder")
    if not (path / MANIFEST_FILE).is_file():
        raise _not_a_checkpoint(path, prefer)
    manifest = _parse(path, MANIFEST_FILE, _read_json)
    if manifest.get("format") != FORMAT_NAME:
        raise CheckpointError(f"checkpoint {path}: format {manifest.get('format')!r} unknown")
    if int(manifest.get("format_version", 10**9)) > FORMAT_VERSION:
        raise CheckpointError(
            f"checkpoint {path}: format_version {manifest.get('format_version')} is newer "
            f"than this library reads ({FORMAT_VERSION})"
        )
    config_file = _config_file(path, manifest["files"])
    required = [MODEL_FILE, config_file] + ([STATE_FILE] if config_file == CONFIG_FILE else [])
    for fname in required:
        if fname not in manifest["files"]:
            raise CheckpointError(f"checkpoint {path}: manifest lists no {fname}")
    for fname, meta in manifest["files"].items():
        f = path / fname
        if not f.is_file():
            raise CheckpointError(f"checkpoint {path}: {fname} is missing")
        if f.stat().st_size != meta["bytes"]:
            raise CheckpointError(
                f"checkpoint {path}: {fname} has {f.stat().st_size} bytes, manifest says "
                f"{meta['bytes']} (truncated or modified)"
            )
        if verify and sha256_file(f) != meta["sha256"]:
            raise CheckpointError(f"checkpoint {path}: {fname} fails its SHA-256 check (corrupt)")
    training = {}
    if (path / TRAINING_FILE).is_file():
        training = _parse(path, TRAINING_FILE, _read_tensors)
    state = _parse(path, STATE_FILE, _read_json) if STATE_FILE in manifest["files"] else {}
    read_config = _read_yaml_text if config_file == CONFIG_FILE else _read_model_json
    return LoadedCheckpoint(
        path=path,
        model=_parse(path, MODEL_FILE, _read_tensors),
        state=state,
        config_yaml=_parse(path, config_file, read_config),
        training=training,
        config_file=config_file,
        manifest=manifest,
    )


def _config_file(path: Path, files: Mapping) -> str:
    """The config a manifest lists: ``config.yaml`` (training) or ``config.json`` (pretrained);
    CheckpointError when it lists both or none."""
    listed = [f for f in (CONFIG_FILE, HUB_CONFIG_FILE) if f in files]
    if len(listed) != 1:
        what = "both" if listed else "neither of"
        raise CheckpointError(
            f"checkpoint {path}: manifest lists {what} {CONFIG_FILE} (a training checkpoint) "
            f"and {HUB_CONFIG_FILE} (a pretrained folder); a checkpoint has one config"
        )
    return listed[0]


def _not_a_checkpoint(path: Path, prefer: str) -> CheckpointError:
    """The error for folder ``path`` without a manifest: the checkpoints it holds, the
    ``prefer`` link (else the other link, else the newest) suggested; an incomplete write when
    it holds a checkpoint's files; else what a checkpoint looks like."""
    found = checkpoints_in(path)
    if not found:
        if any(
            (path / f).is_file() for f in (MODEL_FILE, CONFIG_FILE, HUB_CONFIG_FILE, STATE_FILE)
        ):
            return CheckpointError(f"checkpoint {path} has no {MANIFEST_FILE}: incomplete write?")
        return CheckpointError(
            f"{path} is not a checkpoint: it holds no {MANIFEST_FILE}, nor do the folders in it "
            "(a checkpoint is a folder like <run>/checkpoints/best)"
        )

    def order(p: Path) -> tuple:  # the preferred link, the other links, then the newest
        return 0 if p.name == prefer else 1 if p.name in LINKS else 2, -p.stat().st_mtime

    found.sort(key=str, reverse=True)  # equal times: step_00000002 before step_00000001
    found.sort(key=order)
    kind = "folder"
    if any(p.parent == path / "checkpoints" for p in found):
        kind = "run folder"
    elif path.name == "checkpoints":
        kind = "checkpoints folder"
    names = [str(p.relative_to(path)) for p in found]
    more = f" and {len(names) - MAX_NAMED} more" if len(names) > MAX_NAMED else ""
    return CheckpointError(
        f"{path} is a {kind}, not a checkpoint; did you mean {found[0]}? "
        f"It holds {', '.join(names[:MAX_NAMED])}{more}"
    )


def checkpoints_in(folder: Path) -> list[Path]:
    """The checkpoint folders (holding a manifest) below ``folder``, at most ``SEARCH_DEPTH``
    levels down (a run's ``checkpoints/best``, a pipeline's ``<stage>/run/checkpoints/best``);
    hidden folders (unfinished writes) and zarr stores are not entered, and the search stops
    after ``SEARCH_FOLDERS`` folders."""
    found, level, seen = [], [folder], 0
    for _ in range(SEARCH_DEPTH):
        below = []
        for parent in level:
            try:
                children = sorted(parent.iterdir())
            except OSError:
                continue
            for child in children:
                if child.name.startswith(".") or child.suffix == ".zarr" or not child.is_dir():
                    continue
                seen += 1
                if seen > SEARCH_FOLDERS:
                    return found
                (found if (child / MANIFEST_FILE).is_file() else below).append(child)
        level = below
    return found


def _read_json(file: Path):
    return json.loads(file.read_text())


def _read_tensors(file: Path) -> dict[str, torch.Tensor]:
    return load_file(str(file))


def _read_model_json(file: Path) -> str:
    """A pretrained folder's ``config.json`` (the model section) as a run config's YAML."""
    model = json.loads(file.read_text())
    if not isinstance(model, dict):
        raise ValueError("not a JSON object")
    return yaml.safe_dump({"model": model}, sort_keys=False)


def _read_yaml_text(file: Path) -> str:
    text = file.read_text()
    if not isinstance(yaml.safe_load(text), dict):
        raise ValueError("not a YAML mapping")
    return text


def _parse(path: Path, fname: str, reader):
    """``reader(path / fname)``; a file that does not parse is a CheckpointError naming it."""
    try:
        return reader(path / fname)
    except (ValueError, yaml.YAMLError, SafetensorError) as err:  # JSON and Unicode errors too
        raise CheckpointError(f"checkpoint {path}: {fname} is unreadable ({err})") from None


def load_model_state(
    model: nn.Module,
    tensors: Mapping[str, torch.Tensor],
    source: str,
    allow_missing: bool = False,
) -> list[str]:
    """``model.load_state_dict(tensors)`` with a clear message on missing / extra / mis-shaped
    entries (``source`` names the checkpoint in the message).

    With ``allow_missing`` the model's entries absent from ``tensors`` keep their current
    values (a warm start of a model with a new output); they are returned, sorted.
    """
    expected = model.state_dict()
    missing = sorted(set(expected) - set(tensors))
    extra = sorted(set(tensors) - set(expected))
    shapes = [
        f"{k}: checkpoint {tuple(tensors[k].shape)} vs model {tuple(v.shape)}"
        for k, v in expected.items()
        if k in tensors and tuple(tensors[k].shape) != tuple(v.shape)
    ]
    problems = []
    if missing and not allow_missing:
        problems.append(f"{len(missing)} missing (e.g. {missing[:3]})")
    if extra:
        problems.append(f"{len(extra)} unexpected (e.g. {extra[:3]})")
    if shapes:
        problems.append(f"{len(shapes)} with other shapes (e.g. {shapes[:3]})")
    if problems:
        raise CheckpointError(
            f"checkpoint {source} does not fit this model: "
            + "; ".join(problems)
            + ". Was it trained with another model.* config?"
        )
    model.load_state_dict(dict(tensors), strict=not allow_missing)
    return missing  # empty unless allow_missing (a strict load raised above)
