"""``vla-gr collect`` end to end on config_debug: a valid store holding the expert's labels."""

import numpy as np
import pytest

from vla_gr.cli import main
from vla_gr.configs import load_config
from vla_gr.data.collect import env_kwargs_from_config, make_env
from vla_gr.data.dataset import EpisodeWindowDataset
from vla_gr.data.store import EpisodeStore

NOISE = ["expert.noise_std=0.3", "expert.noise_prob=0.1"]


def _collect(path, *extra):
    args = ["collect", "--config-name", "config_debug", f"collect.output={path}"]
    return main([*args, "collect.split=val", *NOISE, *extra])


def _replay(index: int, overrides):
    """Re-run episode ``index`` step by step: (labels (T, 3), executed actions (T, 3))."""
    from vla_gr.envs.expert import GeodesicExpert

    _, cfg = load_config("config_debug", overrides)
    env = make_env(env_kwargs_from_config(cfg, "val", semantic=True))
    expert = GeodesicExpert(env, cfg.expert.noise_std, cfg.expert.noise_prob)
    expert.rng = np.random.default_rng((cfg.seed, index))  # as collect seeds it
    obs, _ = env.reset(options={"episode": index})
    expert.reset()
    labels, executed, done = [], [], False
    while not done:
        action = expert.act(obs)
        labels.append(expert.last_label.copy())
        executed.append(action)
        obs, _, terminated, truncated, _ = env.step(action)
        done = terminated or truncated
    env.close()
    return np.array(labels), np.array(executed)


@pytest.fixture(scope="module")
def collected(tmp_path_factory):
    path = tmp_path_factory.mktemp("collect") / "val.zarr"
    assert _collect(path) == 0
    return path


def test_store_is_valid_and_holds_expert_labels(collected):
    store = EpisodeStore.open(collected)
    assert store.num_episodes == 2 and not store.has_uncommitted()
    np.testing.assert_array_equal(store.episode_indices, [0, 1])
    assert store.image_size == (32, 32)
    assert store.info["split"] == "val" and store.info["expert"]["noise_std"] == 0.3
    labels, executed = _replay(1, NOISE)
    ep = store.episode(1)
    assert len(ep["action"]) == len(labels)
    np.testing.assert_array_equal(ep["action"], labels.astype(np.float32))
    # The stored action is the noise-free label, not the (noisy) executed one.
    assert not np.allclose(ep["action"][:, :2], executed[:, :2])
    assert ep["action"][-1, 2] > 0 or store.metrics(1)["steps"] == 300  # STOP or budget
    assert store.episode(0)["pose"][0].tolist() == [0.0, 0.0, 0.0]  # pose from the start
    assert ep["goal_mask"].any()  # the goal is seen at some point
    assert store.metrics(0).keys() >= {"success", "spl", "collisions", "path_length"}
    assert store.spec(0)["split"] == "val" and store.instruction(0) == store.spec(0)["instruction"]
    # Statistics cover exactly the stored actions.
    all_actions = store.data_array("action")[: store.num_frames]
    np.testing.assert_allclose(store.stats["action"]["max"], all_actions.max(0), rtol=1e-6)
    # The dataset reads it.
    ds = EpisodeWindowDataset(collected, n_obs_steps=2, horizon=8, split="all")
    assert len(ds) == store.num_frames
    assert ds[0]["rgb"].shape == (2, 3, 32, 32)


def test_refuse_append_overwrite(collected, tmp_path):
    import shutil

    path = tmp_path / "copy.zarr"
    shutil.copytree(collected, path)
    ends = EpisodeStore.open(path).episode_ends
    assert _collect(path) == 2  # refuse (default): clear error, store untouched
    np.testing.assert_array_equal(EpisodeStore.open(path).episode_ends, ends)
    # Append episodes 1..2: episode 1 is present and skipped, only 2 is run.
    assert _collect(path, "collect.mode=append", "collect.first_episode=1") == 0
    store = EpisodeStore.open(path)
    np.testing.assert_array_equal(store.episode_indices, [0, 1, 2])
    np.testing.assert_array_equal(store.episode_ends[:2], ends)
    # Appending with another image size is refused with a reason.
    assert _collect(path, "collect.mode=append", "env.image_size=48") == 2
    assert _collect(path, "collect.mode=overwrite", "collect.num_episodes=1") == 0
    assert EpisodeStore.open(path).num_episodes == 1


def test_two_spawned_workers_write_the_same_store(collected, tmp_path):
    path = tmp_path / "w2.zarr"
    assert _collect(path, "collect.workers=2") == 0
    a, b = EpisodeStore.open(collected), EpisodeStore.open(path)
    np.testing.assert_array_equal(a.episode_ends, b.episode_ends)
    for key in ("rgb", "depth", "pose", "action", "goal_mask"):
        np.testing.assert_array_equal(a.data_array(key)[:], b.data_array(key)[:], err_msg=key)
    assert a.instructions() == b.instructions()


@pytest.mark.slow
def test_killed_collect_leaves_a_readable_store(tmp_path):
    """SIGKILL a running collect; the store opens, and an append run completes it."""
    import subprocess
    import sys
    import time

    path = tmp_path / "killed.zarr"
    cmd = [
        sys.executable,
        "-m",
        "vla_gr.data.collect",
        "--config-name",
        "config_debug",
        f"collect.output={path}",
        "collect.split=val",
        "collect.num_episodes=8",
        *NOISE,
    ]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline and proc.poll() is None:
            if (path / "zarr.json").exists() and EpisodeStore.open(path).num_episodes >= 1:
                break
            time.sleep(0.05)
    finally:
        proc.kill()
        proc.wait()
    assert proc.returncode == -9  # killed mid-run, not finished
    store = EpisodeStore.open(path)
    n = store.num_episodes
    assert 1 <= n <= 8
    assert _collect(path, "collect.mode=append", "collect.num_episodes=3") == 0
    store = EpisodeStore.open(path)
    assert not store.has_uncommitted()
    assert store.episode_indices.tolist() == list(range(max(3, n)))  # in order, no duplicates


def test_distractor_mask_is_the_goals_same_category_objects():
    """Episode 5 of val shows distractors: the recorded mask is semantic in their ids."""
    from vla_gr.data.collect import run_expert_episode
    from vla_gr.envs.expert import GeodesicExpert
    from vla_gr.envs.instructions import distractors

    _, cfg = load_config("config_debug", NOISE)
    env = make_env(env_kwargs_from_config(cfg, "val", semantic=True))
    expert = GeodesicExpert(env, cfg.expert.noise_std, cfg.expert.noise_prob)
    record, _ = run_expert_episode(env, expert, 5, cfg.seed)
    expert.rng = np.random.default_rng((cfg.seed, 5))  # replay with the same noise
    obs, _ = env.reset(options={"episode": 5})
    expert.reset()
    u = env.unwrapped
    ids = distractors(u.house, int(u.goal.instance_id))
    expected, done = [], False
    while not done:
        action = expert.act(obs)
        expected.append(np.isin(obs["semantic"], ids))
        obs, _, terminated, truncated, _ = env.step(action)
        done = terminated or truncated
    env.close()
    np.testing.assert_array_equal(record.distractor_mask, np.stack(expected))
    assert record.distractor_mask.sum() > 100  # this episode shows them
    assert not (record.distractor_mask & record.goal_mask).any()


@pytest.mark.parametrize("rooms", [1, 6])
def test_every_env_setting_of_the_config_reaches_the_env(rooms):
    overrides = [f"env.num_rooms={rooms}", "env.clutter=0.5", "env.scene_cache_size=2"]
    _, cfg = load_config("config_debug", overrides)
    env = make_env(env_kwargs_from_config(cfg, "test"))
    try:
        env.reset(options={"episode": 0})
        nav = env.unwrapped
        assert (nav.num_rooms, nav.clutter, nav.scene_cache_size) == (rooms, 0.5, 2)
        assert len(nav.house.rooms) == rooms  # the house really has that many rooms
    finally:
        env.close()


def test_env_kwargs_cover_every_env_config_key():
    import dataclasses

    from vla_gr.configs.schema import EnvConfig

    _, cfg = load_config("config_debug", [])
    kwargs = env_kwargs_from_config(cfg, "val")
    keys = {f.name for f in dataclasses.fields(EnvConfig)}
    # split is the function's argument; episodes is passed only when a file is named
    assert keys - set(kwargs) == {"episodes"}


def test_an_index_whose_house_hosts_no_episode_is_skipped_and_reported(tmp_path, caplog):
    from vla_gr.data.collect import collect
    from vla_gr.envs.episodes import NoEpisodeError, sample_episode

    with pytest.raises(NoEpisodeError, match="house 1585 has no goal candidates"):
        sample_episode("train", 6340)  # house 1585: no goal with a distractor
    _, cfg = load_config(
        "config_debug",
        [f"collect.output={tmp_path / 's.zarr'}", "collect.split=train",
         "collect.first_episode=6339", "collect.num_episodes=2"],
    )  # fmt: skip
    with caplog.at_level("WARNING", logger="vla_gr.data.collect"):
        summary = collect(cfg)
    assert summary["episodes"] == 1 and summary["skipped"] == [6340]
    assert EpisodeStore.open(tmp_path / "s.zarr").episode_indices.tolist() == [6339]
    assert "episode 6340 skipped" in caplog.text
