"""Episode order: what a seed means, vector envs that never repeat one another, episode k."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils import seeding

import vla_gr.envs  # noqa: F401  (registers the id)
from vla_gr.envs import ENV_ID
from vla_gr.envs.episode_order import (
    PERMUTATION_LIMIT,
    EpisodeOrder,
    episode_at,
    episode_noise_rng,
)
from vla_gr.envs.episodes import sample_episode, save_episodes

# ----------------------------------------------------------------------------- the order


@pytest.mark.parametrize("count", [1, 7, 20, 1000, 4_000_000])
def test_each_epoch_runs_every_episode_once(count):
    n = min(count, 3000)
    for seed in (0, 5):
        first = [episode_at(seed, p, count) for p in range(n)]
        assert len(set(first)) == n and all(0 <= k < count for k in first)
        if count <= 1000:
            assert sorted(first) == list(range(count))
            second = [episode_at(seed, count + p, count) for p in range(count)]
            assert sorted(second) == list(range(count))
    if count >= 20:  # a seed picks the order
        assert [episode_at(0, p, count) for p in range(10)] != [
            episode_at(1, p, count) for p in range(10)
        ]
        assert [episode_at(3, p, count) for p in range(10)] == [
            episode_at(3, p, count) for p in range(10)
        ]
    assert (count > PERMUTATION_LIMIT) == (count == 4_000_000)  # both paths are tested


def test_places_of_one_seed_share_its_order():
    places = [EpisodeOrder(20, i, 4) for i in range(4)]
    alone = EpisodeOrder(20)
    for i, order in enumerate(places):
        order.seed(9 + i)  # gymnasium seeds sub-env i with seed + i
    alone.seed(9)
    rounds = [[order.next() for order in places] for _ in range(5)]
    assert sum(rounds, []) == [alone.next() for _ in range(20)]
    with pytest.raises(ValueError, match=r"sub_env=\(4, 4\)"):
        EpisodeOrder.for_sub_env(20, (4, 4))


# ----------------------------------------------------------------------------- vector envs


def autoreset_ids(vec, seed: int, resets: int) -> list[list[str]]:
    """Episode ids (resets + 1 rounds of num_envs) of a vector env whose episodes last one step."""
    _, info = vec.reset(seed=seed)
    rounds = [list(info["episode_id"])]
    stop = np.tile(np.array([0.0, 0.0, 1.0], np.float32), (vec.num_envs, 1))
    while len(rounds) <= resets:
        _, _, term, _, info = vec.step(stop)  # every sub-env STOPs
        assert term.all()
        _, _, term, _, info = vec.step(stop)  # next-step autoreset: the new episodes
        assert not term.any()
        rounds.append(list(info["episode_id"]))
    return rounds


def test_vector_sub_envs_never_repeat_one_another_on_a_split():
    vec = gym.make_vec(ENV_ID, num_envs=4, image_size=16, num_rooms=1)
    try:
        ids = sum(autoreset_ids(vec, seed=3, resets=49), [])
    finally:
        vec.close()
    assert len(ids) == 200 and len(set(ids)) == 200


@pytest.fixture(scope="module")
def twenty_episodes(tmp_path_factory):
    specs = [sample_episode("val", k, num_rooms=1) for k in range(20)]  # five houses
    return save_episodes(tmp_path_factory.mktemp("order") / "twenty.jsonl", specs), specs


def test_vector_sub_envs_run_a_file_through_before_repeating(twenty_episodes):
    path, specs = twenty_episodes
    vec = gym.make_vec(ENV_ID, num_envs=4, image_size=16, episodes=str(path), scene_cache_size=5)
    try:
        rounds = autoreset_ids(vec, seed=11, resets=49)
        again = autoreset_ids(vec, seed=11, resets=4)
    finally:
        vec.close()
    ids = sum(rounds, [])
    every = sorted(s.episode_id for s in specs)
    for epoch in range(10):  # 5 rounds of 4 run the 20 episodes once each
        assert sorted(ids[20 * epoch : 20 * (epoch + 1)]) == every
    assert ids[:20] != ids[20:40]  # each epoch has its own order
    assert again == rounds[:5]  # a seed replays its episodes


@pytest.mark.parametrize("mode", ["sync", "async"])
def test_vector_envs_step_and_follow_their_episodes(mode, twenty_episodes):
    path, specs = twenty_episodes
    by_id = {s.episode_id: s for s in specs}
    vec = gym.make_vec(
        ENV_ID, num_envs=2, asynchronous=mode == "async", episodes=str(path), image_size=32
    )
    try:
        for seed in (1, 0):  # the instructions follow the episodes (live shared-memory text)
            obs, info = vec.reset(seed=seed)
            assert list(info["episode_id"]) == [
                f"val-{episode_at(seed, p, 20):06d}" for p in (0, 1)
            ]
            assert tuple(obs["instruction"]) == tuple(
                by_id[i].instruction for i in info["episode_id"]
            )
        assert obs["rgb"].shape == (2, 32, 32, 3) and obs["depth"].shape == (2, 32, 32, 1)
        actions = np.tile(np.array([1.0, 0.2, -1.0], np.float32), (2, 1))
        for _ in range(3):
            obs, _, term, trunc, _ = vec.step(actions)
        assert obs["pose"].shape == (2, 3) and np.all(obs["pose"][:, 0] > 0.05)
        assert not term.any() and not trunc.any()
    finally:
        vec.close()


# ----------------------------------------------------------------------------- episode k

#: (scene seed, goal id, instruction) of a few ``test`` episodes: every figure quoted for
#: ``test`` 0-99 means these episodes.
PINNED_TEST = {
    0: (2000000, 4, "Go to the purple chair by the tv"),
    1: (2000000, 8, "Take me to the black chair in the kitchen"),
    42: (2000010, 5, "Locate the blue plant in the bathroom"),
    99: (2000024, 10, "Navigate to the red chair"),
}


def test_episode_k_of_the_test_split_is_pinned():
    env = gym.make(ENV_ID, split="test", image_size=16)
    try:
        for k, pinned in PINNED_TEST.items():
            _, info = env.reset(options={"episode": k})
            spec = env.unwrapped.episode_spec
            assert info["episode_id"] == f"test-{k:06d}"
            assert (spec.scene_seed, spec.goal_instance_id, spec.instruction) == pinned
            assert spec == sample_episode("test", k)
    finally:
        env.close()


def test_episode_k_draws_its_noise_from_k_and_the_seed():
    """Without a seed, episode k's noise is what ``reset(seed=k)`` drew before episodes were
    ordered (``seeding.np_random(k)``), so figures measured with noise stay reproducible."""

    def first_depth(seed=None, **noise):
        env = gym.make(ENV_ID, split="test", image_size=16, **noise)
        try:
            obs, _ = env.reset(seed=seed, options={"episode": 3})
            return obs["depth"][..., 0]  # (H, W)
        finally:
            env.close()

    clean, noisy = first_depth(), first_depth(depth_noise_std=0.05)
    draws = seeding.np_random(3)[0].normal(0.0, 0.05, clean.shape)  # (H, W)
    inside = (clean > 0.2) & (clean < 9.8)  # where clipping to [0, max_depth] did not act
    assert inside.mean() > 0.5
    np.testing.assert_allclose(noisy[inside], (clean + draws)[inside], atol=1e-5)
    assert np.array_equal(first_depth(0, depth_noise_std=0.05), noisy)  # seed None counts as 0
    other = first_depth(7, depth_noise_std=0.05)
    assert not np.array_equal(other, noisy)
    seeded = episode_noise_rng(3, 7).normal(0.0, 0.05, clean.shape)  # (H, W)
    np.testing.assert_allclose(other[inside], (clean + seeded)[inside], atol=1e-5)


def test_a_bad_episode_index_or_seed_is_one_line_quoting_it():
    env = gym.make(ENV_ID, image_size=16)
    try:
        for options, message in [
            ({"episode": 4_000_000}, r"options\['episode'\]=4000000 must be in \[0, 4000000\)"),
            ({"episode": -1}, r"options\['episode'\]=-1"),
            ({"episode": 1.5}, r"an episode index \(int\) or an EpisodeSpec, got 1.5"),
            ({"episode": True}, "got True"),
        ]:
            with pytest.raises(ValueError, match=message):
                env.reset(options=options)
        with pytest.raises(ValueError, match="seed=-1 must be >= 0"):
            env.reset(seed=-1)
        _, info = env.reset(seed=2**40)  # any seed >= 0 orders the episodes
        assert info["episode_id"].startswith("val-")
    finally:
        env.close()
