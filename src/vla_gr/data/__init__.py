"""Expert data: the zarr episode store, training windows, normalisation, collection."""

from vla_gr.data.dataset import EpisodeWindowDataset, split_episodes, window_indices
from vla_gr.data.normalize import (
    MinMaxNormalizer,
    compute_stats,
    merge_stats,
    normalizers_from_stats,
)
from vla_gr.data.store import (
    FORMAT_VERSION,
    EpisodeRecord,
    EpisodeStore,
    StoreError,
    fake_episode,
)

__all__ = [
    "FORMAT_VERSION",
    "EpisodeRecord",
    "EpisodeStore",
    "EpisodeWindowDataset",
    "MinMaxNormalizer",
    "StoreError",
    "compute_stats",
    "fake_episode",
    "merge_stats",
    "normalizers_from_stats",
    "split_episodes",
    "window_indices",
]
