"""Expert data: the zarr episode store, training windows, normalisation, collection.

Names load lazily, so worker processes that only need the store skip importing torch.
"""

from __future__ import annotations

import importlib

_LAZY = {
    "EpisodeWindowDataset": "vla_gr.data.dataset",
    "split_episodes": "vla_gr.data.dataset",
    "window_indices": "vla_gr.data.dataset",
    "MinMaxNormalizer": "vla_gr.data.normalize",
    "compute_stats": "vla_gr.data.normalize",
    "merge_stats": "vla_gr.data.normalize",
    "normalizers_from_stats": "vla_gr.data.normalize",
    "FORMAT_VERSION": "vla_gr.data.store",
    "EpisodeRecord": "vla_gr.data.store",
    "EpisodeStore": "vla_gr.data.store",
    "StoreError": "vla_gr.data.store",
    "fake_episode": "vla_gr.data.store",
    "run_expert_episode": "vla_gr.data.collect",
    "verify_store": "vla_gr.data.verify",
}

__all__ = list(_LAZY)


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'vla_gr.data' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value
