"""The word table kept on disk: read back equal to the one built from WordNet, rebuilt when
the file is corrupt or of another shape, and never half-written."""

from __future__ import annotations

import gzip
import json

import pytest

from vla_gr.agent.reading import table_cache
from vla_gr.agent.reading.vocabulary import WordTable, word_table


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("VLA_GR_CACHE", str(tmp_path))
    return tmp_path


def _check(state: dict) -> None:
    if set(state) != {"words"} or not isinstance(state["words"], list):
        raise ValueError("not a table")


def test_the_first_call_builds_and_writes_and_the_next_reads_without_building(cache):
    builds = []

    def build():
        builds.append(1)
        return {"words": ["chair", "sofa"]}

    assert table_cache.load_or_build(build, _check) == {"words": ["chair", "sofa"]}
    path = table_cache.cache_path()
    assert path.parent == cache and path.is_file()
    assert table_cache.load_or_build(build, _check) == {"words": ["chair", "sofa"]}
    assert len(builds) == 1
    assert [p.name for p in cache.iterdir()] == [path.name]  # no temporary file left


@pytest.mark.parametrize(
    "content",
    [b"not gzip at all", gzip.compress(b"{truncated"), gzip.compress(b'{"other": 1}')],
)
def test_a_corrupt_or_foreign_file_is_rebuilt_and_replaced(cache, content, caplog):
    path = table_cache.cache_path()
    path.write_bytes(content)
    state = table_cache.load_or_build(lambda: {"words": ["bed"]}, _check)
    assert state == {"words": ["bed"]} and "rebuilding" in caplog.text
    with gzip.open(path, "rt") as f:
        assert json.load(f) == {"words": ["bed"]}


def test_a_folder_that_cannot_be_written_costs_only_the_time(tmp_path, monkeypatch, caplog):
    blocked = tmp_path / "file"
    blocked.write_text("a file where the folder would be")
    monkeypatch.setenv("VLA_GR_CACHE", str(blocked / "cache"))
    assert table_cache.load_or_build(lambda: {"words": []}, _check) == {"words": []}
    assert "not cached" in caplog.text


def test_the_table_read_from_its_state_equals_the_one_built_from_wordnet():
    built = WordTable()  # from WordNet
    read = WordTable.from_state(json.loads(json.dumps(built.to_state())))
    for name in ("objects", "rooms", "colours", "other_colours", "known", "_targets",
                 "dwellings", "compounds", "_depth", "slip_targets"):  # fmt: skip
        assert getattr(read, name) == getattr(built, name), name
    assert read._nouns == built._nouns
    assert word_table().to_state() == built.to_state()  # the process's table, cached or not
    with pytest.raises(ValueError, match="holds"):
        WordTable.from_state({"objects": []})
