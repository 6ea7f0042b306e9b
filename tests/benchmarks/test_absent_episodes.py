"""absent_episodes: absent-object episodes and their normal twins, rooms cycling 1-6, in a file
that ``vla-gr eval`` loads (each absent request checked to fit nothing); not_found_traces: the
shipped count replayed on hand-made ticks."""

from __future__ import annotations

import importlib.util
from pathlib import Path

from vla_gr.envs.absent import sample_absent_episode
from vla_gr.envs.episodes import load_episodes, sample_episode, save_episodes

_ROOT = Path(__file__).resolve().parents[2]


def _load(name: str):
    spec = importlib.util.spec_from_file_location(name, _ROOT / "benchmarks" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_indices_give_their_absent_episode_and_normal_twin_in_houses_of_1_to_6_rooms(tmp_path):
    specs, counts = _load("absent_episodes").absent_episodes("val", 30, 7, with_normal=True)
    assert counts == {"absent": 7, "normal": 7} and len(specs) == 14
    assert [s.num_rooms for s in specs[::2]] == [1, 2, 3, 4, 5, 6, 1]
    assert specs[0] == sample_absent_episode("val", 30, num_rooms=1)
    assert specs[1] == sample_episode("val", 30, num_rooms=1)
    assert [s.absent for s in specs] == [True, False] * 7
    assert load_episodes(save_episodes(tmp_path / "absent.jsonl", specs)) == specs  # checked


def test_the_replay_declares_after_the_steps_without_a_way_or_new_house():
    traces = _load("not_found_traces")
    way = traces.RULES["no way at the own radius (shipped)"]

    def tick(step, path=False, thin=False, explored=10.0, mode="explore"):
        return {"step": step, "mode": mode, "committed": False, "path": path, "thin": thin,
                "explored": explored}  # fmt: skip

    look = [tick(0, mode="look_around")]  # then 60 ticks (180 steps) without a way: declared
    quiet = look + [tick(3 * k) for k in range(1, 70)]
    assert traces.fires(quiet, way, 180, 2.0) == 180
    thin = look + [tick(3 * k, path=True, thin=True) for k in range(1, 70)]  # thinner only
    assert traces.fires(thin, way, 180, 2.0) == 180
    assert traces.fires(thin, traces.RULES["no path at any radius"], 180, 2.0) is None
    growing = look + [tick(3 * k, explored=10.0 + 0.11 * k) for k in range(1, 70)]
    assert traces.fires(growing, way, 180, 2.0) is None  # more than 2 m2 new every 19 ticks
    assert traces.fires(growing, way, 180, float("inf")) == 180
