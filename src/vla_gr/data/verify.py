"""``vla-gr store verify`` / ``copy``: a store's health chunk by chunk, and rewriting it.

``copy_store`` rewrites a store in the current format (checksums for a format-1 store) or
salvages the intact episodes of a damaged one.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Sequence
from pathlib import Path

import zarr

from vla_gr.data.integrity import Damage, is_checksummed, short_list
from vla_gr.data.store import EpisodeRecord, EpisodeStore, StoreError

log = logging.getLogger(__name__)


def health_lines(
    path: Path,
    version: int,
    num_episodes: int,
    num_frames: int,
    arrays: dict[str, zarr.Array],
    damage: Sequence[Damage],
    deep: bool,
) -> list[str]:
    """A human-readable health report: the store, one line per array, then the verdict."""
    checksummed = all(is_checksummed(a) for a in arrays.values())
    lines = [
        f"store {path}: format {version} ({'CRC32C per chunk' if checksummed else 'NO checksums'})"
        f", {num_episodes} episodes, {num_frames} frames"
    ]
    for name, arr in arrays.items():
        bad = sum(d.array == name for d in damage)
        shape = f"{tuple(arr.shape)} {arr.dtype}"
        lines.append(
            f"  {name:<20} {shape:<28} {arr.nchunks:>6} chunks  {f'{bad} BAD' if bad else 'ok'}"
        )
    checks = "present, checksums" + (", decoded, values in range" if deep else ", actions/poses")
    if not damage:
        lines.append(f"OK: every chunk of the {num_episodes} episodes checked ({checks})")
        return lines
    episodes = sorted({e for d in damage for e in d.episodes})
    lines.append(
        f"DAMAGED: {len(damage)} bad chunk(s) in {len(episodes)} episode(s) "
        f"{short_list(episodes, 50)} (checked: {checks})"
    )
    lines.extend(f"  {d.describe()}" for d in damage)
    return lines


def verify_store(path: str | Path, deep: bool = True) -> tuple[bool, list[str]]:
    """Check every chunk of the store at ``path``: (healthy, report lines).

    ``deep`` decodes every chunk and checks its values (depth too); otherwise presence,
    checksums, actions and poses (what ``open`` checks). A store whose structure is
    broken is reported as damaged; a path that is not a store raises ``StoreError``.
    """
    path = Path(path)
    if not (path / "zarr.json").is_file():
        raise StoreError(f"{path} is not an episode store (no zarr.json)")
    try:
        group = zarr.open_group(str(path), mode="r")
        store = EpisodeStore(path, group, "r", on_corrupt="report", deep=deep)
    except StoreError as err:
        return False, [f"DAMAGED: {err}"]
    lines = health_lines(
        path,
        int(group.attrs["format_version"]),
        store.num_episodes,
        store.num_frames,
        store.arrays(),
        store.damage,
        deep,
    )
    return not store.damage, lines


def create_like(source: EpisodeStore, dst: str | Path, overwrite: bool = False) -> EpisodeStore:
    """A new empty store ``dst`` with ``source``'s image size, info and frame arrays (without
    ``distractor_mask`` when ``source`` lacks it: only collecting again records it)."""
    return EpisodeStore.create(
        dst,
        source.image_size,
        overwrite=overwrite,
        info=source.info,
        distractors="distractor_mask" in source.frame_keys,
    )


def copy_episodes(source: EpisodeStore, target: EpisodeStore, rows: Iterable[int]) -> int:
    """Append the episodes at store rows ``rows`` of ``source`` to ``target``, in that order
    (frames, instruction, spec, metrics, episode index); returns how many."""
    indices = source.episode_indices
    count = 0
    for e in rows:
        target.append(
            EpisodeRecord(
                episode_index=int(indices[e]),
                **source.episode(e),
                instruction=source.instruction(e),
                spec=source.spec(e),
                metrics=source.metrics(e),
            )
        )
        count += 1
    return count


def copy_store(
    src: str | Path, dst: str | Path, on_corrupt: str = "error", overwrite: bool = False
) -> EpisodeStore:
    """Copy the episodes of ``src`` into a new store ``dst`` in the current format.

    Rewrites a format-1 store with checksums; ``on_corrupt="skip"`` salvages the intact
    episodes of a damaged one. Statistics are recomputed from the copied episodes. A source
    without ``distractor_mask`` gives a copy without it (only collecting again records it).
    """
    source = EpisodeStore.open(src, mode="r", on_corrupt=on_corrupt)
    target = create_like(source, dst, overwrite=overwrite)
    skipped = set(source.damaged_episodes)
    copy_episodes(source, target, [e for e in range(source.num_episodes) if e not in skipped])
    log.info(
        "copied %d of %d episodes from %s to %s",
        target.num_episodes,
        source.num_episodes,
        source.path,
        target.path,
    )
    return target
