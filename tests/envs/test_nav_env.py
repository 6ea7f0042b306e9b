"""VLAGR/ObjectNav-v0: sensors, collisions, replay, action checks, STOP, episode selection."""

import dataclasses
import math

import gymnasium as gym
import numpy as np
import pytest

import vla_gr.envs  # noqa: F401  (registers the id)
from vla_gr.envs import ENV_ID
from vla_gr.envs.episodes import EpisodeSpec, goal_field, sample_start, save_episodes
from vla_gr.envs.geodesic import ROBOT_RADIUS, sample_field

from .test_episodes import box_room_house

EAST_WALL = 6.1  # inner face of box_room_house's east wall


def room_spec(x: float, y: float, yaw: float, goal: int = 3, **kw) -> EpisodeSpec:
    fields = dict(
        episode_id="room-0",
        split="val",
        scene_seed=5,
        num_rooms=1,
        clutter=1.0,
        start_x=x,
        start_y=y,
        start_yaw=yaw,
        goal_instance_id=goal,
        goal_category="chair",
        instruction="find the red chair",
        geodesic_start_distance=0.0,
    )
    fields.update(kw)
    return EpisodeSpec(**fields)


@pytest.fixture(scope="module")
def room():
    return box_room_house()


@pytest.fixture
def env(room):
    e = gym.make(ENV_ID, image_size=64, semantic=True)
    yield e
    e.close()


def run_room(env, room, spec):
    return env.reset(options={"episode": spec, "house": room})


def house_specs(n: int = 3, index: int = 0) -> list[EpisodeSpec]:
    """Specs on a generated val house (explicit, so these tests need no sampler)."""
    from vla_gr.envs.house import generate_house, split_seed

    seed = split_seed("val", index)
    house = generate_house(seed)
    specs = []
    for i, obj in enumerate(house.objects[:n]):
        rng = np.random.default_rng(i)
        x, y, yaw, dist = sample_start(house, goal_field(house, obj.instance_id), rng)
        specs.append(
            EpisodeSpec(
                f"gen-{i}",
                "val",
                seed,
                None,
                1.0,
                x,
                y,
                yaw,
                obj.instance_id,
                obj.category,
                f"find the {obj.color} {obj.category}",
                dist,
            )
        )
    return specs


# ----------------------------------------------------------------------------- spaces, sensors


def test_observation_and_info_contract(env, room):
    obs, info = run_room(env, room, room_spec(1.0, 1.0, 0.3))
    assert env.observation_space.contains(obs)
    assert obs["rgb"].shape == (64, 64, 3) and obs["rgb"].dtype == np.uint8
    assert obs["depth"].shape == (64, 64, 1) and obs["depth"].dtype == np.float32
    assert obs["pose"].dtype == np.float32 and np.all(obs["pose"] == 0)
    assert obs["semantic"].shape == (64, 64) and obs["semantic"].dtype == np.int32
    assert obs["instruction"] == "find the red chair"
    for key in ("success", "spl", "soft_spl", "distance_to_goal", "collisions", "path_length"):
        assert key in info
    assert info["episode_id"] == "room-0"
    u = env.unwrapped
    assert u.traversable.shape == room.grid.shape == u.goal_distance.shape
    assert u.goal.instance_id == 3 and u.episode_spec.start_x == 1.0
    start = sample_field(u.goal_distance, room.grid, 1.0, 1.0)
    assert info["geodesic_start_distance"] == pytest.approx(start)
    assert info["distance_to_goal"] == pytest.approx(start)
    np.testing.assert_allclose(u.robot_pose_world(), [1.0, 1.0, 0.3])


@pytest.mark.parametrize("x", [2.0, 4.3, 5.5])
def test_depth_centre_pixel_reads_wall(env, room, x):
    obs, _ = run_room(env, room, room_spec(x, 1.0, 0.0))  # facing the east wall
    centre = obs["depth"][31:33, 31:33, 0]
    np.testing.assert_allclose(centre, EAST_WALL - x, atol=0.02)
    rgb, depth = env.unwrapped.render_rgbd(128)  # GIF-size frames from the same camera
    assert rgb.shape == (128, 128, 3) and depth.shape == (128, 128)
    np.testing.assert_allclose(depth[63:65, 63:65], EAST_WALL - x, atol=0.02)


def test_semantic_shows_goal_when_facing_it(env, room):
    obs, _ = run_room(env, room, room_spec(3.5, 2.0, 0.0))  # the chair is 1.25 m ahead
    ids = obs["semantic"]
    assert (ids == 3).mean() > 0.02
    assert set(np.unique(ids)) <= {0, 3, 4}
    cols = np.nonzero((ids == 3).any(axis=0))[0]
    assert cols.min() < 32 < cols.max()  # centred in the image
    obs, _ = run_room(env, room, room_spec(3.5, 2.0, math.pi))  # facing away
    assert not (obs["semantic"] == 3).any()


# ----------------------------------------------------------------------------- motion


def test_pose_is_relative_to_start(env, room):
    run_room(env, room, room_spec(1.0, 1.0, math.pi / 2))  # facing north (+y)
    for _ in range(10):
        obs, *_ = env.step(np.array([1.0, 0.0, -1.0], np.float32))
    np.testing.assert_allclose(obs["pose"], [0.5, 0.0, 0.0], atol=0.02)
    np.testing.assert_allclose(env.unwrapped.robot_pose_world()[:2], [1.0, 1.5], atol=0.02)
    for _ in range(5):
        obs, *_ = env.step(np.array([0.0, 1.0, -1.0], np.float32))
    assert obs["pose"][2] == pytest.approx(0.5, abs=0.02)
    for _ in range(10):  # drive 0.5 m along the new heading (start-frame angle 0.5 rad)
        obs, _, _, _, info = env.step(np.array([1.0, 0.0, -1.0], np.float32))
    expect = np.array([0.5 + 0.5 * math.cos(0.5), 0.5 * math.sin(0.5)])
    np.testing.assert_allclose(obs["pose"][:2], expect, atol=0.03)
    assert info["path_length"] == pytest.approx(1.0, abs=0.03)
    assert info["collisions"] == 0
    u = env.unwrapped
    assert len(u.trajectory_world) == 26 and u.trajectory_world[0] == (1.0, 1.0)
    np.testing.assert_allclose(u.trajectory_world[-1], u.robot_pose_world()[:2])
    np.testing.assert_allclose(u.start_pose_world, [1.0, 1.0, math.pi / 2])


def test_driving_into_wall_counts_collisions_and_stops(env, room):
    run_room(env, room, room_spec(5.2, 1.0, 0.0))
    flags = []
    for _ in range(40):  # 0.72 m of free space (~15 steps), then 25 steps pushing the wall
        _, _, term, trunc, info = env.step(np.array([1.0, 0.0, -1.0], np.float32))
        flags.append(info["collided"])
        x = env.unwrapped.robot_pose_world()[0]
        assert x <= EAST_WALL - ROBOT_RADIUS + 0.01  # never through the wall
    assert not any(flags[:14]) and all(flags[16:])
    assert info["collisions"] == sum(flags) >= 24
    assert x == pytest.approx(EAST_WALL - ROBOT_RADIUS, abs=0.01)
    assert not (term or trunc)
    # Turning in place against the wall is not a collision.
    _, _, _, _, info = env.step(np.array([0.0, 1.0, -1.0], np.float32))
    assert not info["collided"]


# ----------------------------------------------------------------------------- actions, STOP


def test_action_validation(env, room):
    run_room(env, room, room_spec(1.0, 1.0, 0.0))
    with pytest.raises(ValueError, match="finite"):
        env.step(np.array([np.nan, 0.0, -1.0], np.float32))
    with pytest.raises(ValueError, match="finite"):
        env.step(np.array([0.0, np.inf, -1.0]))
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(2, np.float32))
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros((1, 3), np.float32))
    obs_big, *_ = env.step(np.array([7.0, -3.0, -5.0], np.float32))  # clipped to (1, -1, -1)
    run_room(env, room, room_spec(1.0, 1.0, 0.0))
    obs_one, *_ = env.step(np.array([1.0, -1.0, -1.0], np.float32))
    assert obs_big["pose"].tobytes() == obs_one["pose"].tobytes()
    assert obs_big["rgb"].tobytes() == obs_one["rgb"].tobytes()


def test_stop_success_iff_within_success_distance(env, room):
    run_room(env, room, room_spec(4.0, 2.0, 0.0))  # 0.75 m from the chair's footprint
    _, reward, term, trunc, info = env.step(np.array([0.0, 0.0, 1.0], np.float32))
    assert term and not trunc and reward == 1.0
    assert info["success"] == 1.0 and info["spl"] == pytest.approx(1.0)
    assert info["distance_to_goal"] == pytest.approx(0.75, abs=0.06)
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(3, np.float32))
    run_room(env, room, room_spec(2.5, 2.0, 0.0))  # 2.25 m away: STOP fails
    _, reward, term, _, info = env.step(np.array([0.0, 0.0, 0.5], np.float32))
    assert term and info["success"] == 0.0 and info["spl"] == 0.0 and reward == 0.0


# ----------------------------------------------------------------------------- declared outcomes


def test_declared_outcomes_are_exported():
    from vla_gr.envs import DECLARED_OUTCOMES

    assert DECLARED_OUTCOMES == ("not_understood", "not_found")


@pytest.mark.parametrize("outcome", ["not_understood", "not_found"])
def test_declare_ends_the_episode_without_moving_or_a_stop(env, room, outcome):
    # 0.75 m from the chair: a STOP here would succeed, a declaration never does
    obs, info = run_room(env, room, room_spec(4.0, 2.0, 0.0))
    assert info["declared"] is None
    for _ in range(2):  # turn in place: still within the success distance
        obs, _, _, _, info = env.step(np.array([0.0, 0.5, -1.0], np.float32))
        assert info["declared"] is None
    u = env.unwrapped
    pose, before = u.robot_pose_world(), dict(info)
    obs, reward, terminated, truncated, info = u.declare(outcome)
    assert (reward, terminated, truncated) == (0.0, True, False)
    assert info["declared"] == outcome and info["collided"] is False
    assert info["success"] == 0.0 and info["spl"] == 0.0
    assert before["distance_to_goal"] <= 1.0  # where a STOP would have succeeded
    np.testing.assert_array_equal(u.robot_pose_world(), pose)  # it did not move
    assert info["steps"] == before["steps"] + 1  # one decision, standing still
    assert info["path_length"] == before["path_length"]
    assert info["distance_to_goal"] == pytest.approx(before["distance_to_goal"])
    assert info["episode_id"] == "room-0" and env.observation_space.contains(obs)
    np.testing.assert_array_equal(obs["pose"], u._last_obs["pose"])
    with pytest.raises(
        RuntimeError, match=r"step\(\) called before reset\(\) or after the episode"
    ):
        env.step(np.zeros(3, np.float32))
    with pytest.raises(RuntimeError, match=r"declare\(\) called before reset\(\) or after the"):
        u.declare(outcome)
    _, info = run_room(env, room, room_spec(4.0, 2.0, 0.0))  # a new episode: nothing declared
    assert info["declared"] is None
    _, _, terminated, _, info = env.step(np.array([0.0, 0.0, 1.0], np.float32))
    assert terminated and info["success"] == 1.0 and info["declared"] is None


@pytest.mark.parametrize("bad", ["not understood", "NOT_FOUND", "success", None, 3])
def test_an_unknown_outcome_is_refused_and_the_episode_goes_on(env, room, bad):
    run_room(env, room, room_spec(1.0, 1.0, 0.0))
    with pytest.raises(ValueError, match="valid: not_understood, not_found") as err:
        env.unwrapped.declare(bad)
    assert repr(bad) in str(err.value) and len(str(err.value).splitlines()) == 1
    _, _, terminated, truncated, info = env.step(np.array([0.5, 0.0, -1.0], np.float32))
    assert not (terminated or truncated) and info["steps"] == 1


def test_declare_before_reset_is_the_error_step_gives():
    env = gym.make(ENV_ID, image_size=32)
    with pytest.raises(RuntimeError, match="before reset") as stepped:
        env.unwrapped.step(np.zeros(3, np.float32))
    with pytest.raises(RuntimeError, match="before reset") as declared:
        env.unwrapped.declare("not_understood")
    assert str(declared.value) == str(stepped.value).replace("step()", "declare()")
    env.close()


# ----------------------------------------------------------------------------- instructions


def test_any_printable_unicode_instruction_reaches_the_observation_folded(env, room):
    said = {
        "I\u2019m looking for the sofa": "I'm looking for the sofa",
        "the caf\u00e9 chair, Zo\u00eb\u2019s": "the cafe chair, Zoe's",
        "the chair \u2014 the red one\u2026": "the chair - the red one...",
        "the \u201cred\u201d chair \U0001fa91\U0001f642": 'the "red" chair',
        "find\tthe\nred\x07 chair\x00": "find the red chair",
        "\t  ": "",
        "Find The RED chair": "Find The RED chair",  # case kept
    }
    for text, folded in said.items():
        obs, _ = run_room(env, room, room_spec(1.0, 1.0, 0.0, instruction=text))
        assert obs["instruction"] == folded and env.unwrapped.instruction == folded
        assert env.observation_space.contains(obs)
        assert env.unwrapped.episode_spec.instruction == text  # the spec stays as written
        obs, *_ = env.step(np.array([0.0, 0.0, -1.0], np.float32))
        assert obs["instruction"] == folded
    # the limit applies to the folded text: 300 emoji and a short request fit
    obs, _ = run_room(env, room, room_spec(1.0, 1.0, 0.0, instruction="\U0001f600" * 300 + "sofa"))
    assert obs["instruction"] == "sofa"


def test_an_instruction_too_long_after_folding_is_one_line_naming_the_limit(env, room):
    from vla_gr.envs.nav_env import INSTRUCTION_MAX_LENGTH

    fits = "x" * INSTRUCTION_MAX_LENGTH
    obs, _ = run_room(env, room, room_spec(1.0, 1.0, 0.0, instruction=f"  {fits}\t"))
    assert obs["instruction"] == fits
    long = "find the chair " * 20  # 299 characters once stripped
    with pytest.raises(ValueError) as err:
        run_room(env, room, room_spec(1.0, 1.0, 0.0, instruction=long))
    message = str(err.value)
    assert len(message.splitlines()) == 1 and "room-0" in message
    assert "299 characters" in message and f"limit of {INSTRUCTION_MAX_LENGTH}" in message
    with pytest.raises(RuntimeError, match="before reset"):  # the failed reset ended it
        env.step(np.zeros(3, np.float32))
    with pytest.raises(ValueError, match="instruction must be a str, got bytes"):
        run_room(env, room, room_spec(1.0, 1.0, 0.0, instruction=b"find the chair"))
    obs, _ = run_room(env, room, room_spec(1.0, 1.0, 0.0))  # and the env is still usable
    assert obs["instruction"] == "find the red chair"


def test_truncation_is_a_failure(room):
    env = gym.make(ENV_ID, max_episode_steps=3)
    run_room(env, room, room_spec(1.0, 1.0, 0.0))
    outs = [env.step(np.array([0.2, 0.0, -1.0], np.float32)) for _ in range(3)]
    assert [o[3] for o in outs] == [False, False, True]
    assert not any(o[2] for o in outs) and outs[-1][4]["success"] == 0.0
    env.close()


def test_invalid_spec_raises_with_reason(env, room):
    with pytest.raises(ValueError, match="inside an obstacle"):
        run_room(env, room, room_spec(5.0, 2.0, 0.0))
    with pytest.raises(ValueError, match="missing"):
        run_room(env, room, room_spec(1.0, 1.0, 0.0, goal=42))


# ----------------------------------------------------------------------------- replay, caching


def test_same_spec_gives_identical_observation_bytes():
    spec = house_specs(1)[0]
    rng = np.random.default_rng(3)
    actions = [np.array([rng.uniform(0, 1), rng.uniform(-1, 1), -1], np.float32) for _ in range(15)]
    runs = []
    for _ in range(2):
        env = gym.make(ENV_ID, semantic=True)
        obs, _ = env.reset(options={"episode": spec})
        frames = [obs]
        for a in actions:
            frames.append(env.step(a)[0])
        env.close()
        runs.append(frames)
    for a, b in zip(*runs):
        for key in ("rgb", "depth", "pose", "semantic"):
            assert a[key].tobytes() == b[key].tobytes(), key
    assert not np.array_equal(runs[0][0]["rgb"], runs[0][-1]["rgb"])  # it did move


def test_scene_cache_reuses_compiled_model(room):
    specs = house_specs(2)
    env = gym.make(ENV_ID, scene_cache_size=1)
    u = env.unwrapped
    env.reset(options={"episode": specs[0]})
    model = u._scene.model
    env.reset(options={"episode": specs[1]})  # same scene seed, another goal
    assert u._scene.model is model
    run_room(env, room, room_spec(1.0, 1.0, 0.0))  # another scene evicts the first
    env.reset(options={"episode": specs[0]})
    assert u._scene.model is not model and len(u._scenes) == 1
    env.close()


def test_cached_scenes_render_like_fresh_ones(room):
    """Several compiled scenes share one GL context; switching back gives the same frame."""
    spec = house_specs(1)[0]
    env = gym.make(ENV_ID, semantic=True)
    first, _ = env.reset(options={"episode": spec})
    model = env.unwrapped._scene.model
    run_room(env, room, room_spec(1.0, 1.0, 0.0))
    env.unwrapped.render_rgbd(96)
    again, _ = env.reset(options={"episode": spec})
    assert env.unwrapped._scene.model is model  # a cache hit, no recompile
    for key in ("rgb", "depth", "semantic"):
        assert first[key].tobytes() == again[key].tobytes(), key
    env.close()


def test_episodes_file_index_and_seed_selection(tmp_path):
    from vla_gr.envs.episode_order import episode_at

    specs = house_specs(3)
    path = save_episodes(tmp_path / "eps.jsonl", specs)
    env = gym.make(ENV_ID, episodes=str(path))
    assert env.reset(options={"episode": 1})[1]["episode_id"] == "gen-1"
    ids = [env.reset(seed=5)[1]["episode_id"]] + [env.reset()[1]["episode_id"] for _ in range(5)]
    assert ids == [f"gen-{episode_at(5, p, 3)}" for p in range(6)]  # no seed: the next one
    assert sorted(ids[:3]) == ["gen-0", "gen-1", "gen-2"]
    obs, _ = env.reset(options={"episode": dataclasses.asdict(specs[0])})  # dicts work too
    assert obs["instruction"] == specs[0].instruction
    with pytest.raises(ValueError, match=r"must be in \[0, 3\): the episodes file has 3"):
        env.reset(options={"episode": 3})
    env.close()


@pytest.mark.filterwarnings("ignore:.*infinity")  # pose is unbounded, like Habitat's GPS
def test_gymnasium_env_checker_passes():
    pytest.importorskip("vla_gr.envs.instructions")
    from gymnasium.utils.env_checker import check_env

    env = gym.make(ENV_ID)
    check_env(env.unwrapped, skip_render_check=True)  # incl. reset(seed) determinism
    env.close()


def test_module_qualified_id_imports_the_package():
    env = gym.make("vla_gr.envs:" + ENV_ID, image_size=32)
    assert env.observation_space["rgb"].shape == (32, 32, 3)
    assert env.unwrapped.max_linear_speed == 0.5 and env.unwrapped.max_angular_speed == 1.0
    assert env.unwrapped.control_hz == 10.0 and env.unwrapped.success_distance == 1.0
    env.close()


def test_split_episode_index_and_seed_are_deterministic():
    pytest.importorskip("vla_gr.envs.instructions")
    a, b = gym.make(ENV_ID), gym.make(ENV_ID)
    oa, ia = a.reset(options={"episode": 2})
    ob, ib = b.reset(options={"episode": 2})
    assert ia["episode_id"] == ib["episode_id"] == "val-000002"
    assert oa["rgb"].tobytes() == ob["rgb"].tobytes() and oa["instruction"] == ob["instruction"]
    assert a.unwrapped.episode_spec == b.unwrapped.episode_spec
    seeded = [[e.reset(seed=2)[1]["episode_id"], e.reset()[1]["episode_id"]] for e in (a, b)]
    assert seeded[0] == seeded[1] and "val-000002" not in seeded[0]  # a seed is no index
    a.close()
    b.close()


@pytest.mark.parametrize("bad", [-1, 1.5, "0", None])
def test_failed_reset_leaves_the_env_usable(bad):
    """After a bad first reset the next valid reset + step work; errors quote the input."""
    env = gym.make(ENV_ID, image_size=32)
    if bad is None:  # a failed reset of another kind: unknown options
        with pytest.raises(ValueError, match="unknown reset options"):
            env.reset(seed=0, options={"nope": 1})
    else:
        with pytest.raises((ValueError, TypeError), match=f"seed[ =].*{bad!r}"):
            env.reset(seed=bad)
    with pytest.raises(RuntimeError, match="before reset"):
        env.step(np.zeros(3, np.float32))
    obs, info = env.reset(options={"episode": 0})
    assert info["episode_id"] == "val-000000"
    obs, _, terminated, truncated, info = env.step(np.array([0.5, 0.0, -1.0], np.float32))
    assert obs["rgb"].shape == (32, 32, 3) and not terminated and info["steps"] == 1
    env.close()


def test_distance_to_goal_stays_finite_inside_the_inflated_margin(env, room):
    from vla_gr.envs import robot as rb
    from vla_gr.envs.geodesic import distance_at

    run_room(env, room, room_spec(1.0, 1.0, 0.0))
    u = env.unwrapped
    grid, field = room.grid, u.goal_distance  # (H, W)
    # a free cell (no obstacle) whose whole neighbourhood is in the margin: inf distance
    inf_free = [
        (r, c)
        for r, c in zip(*np.nonzero(~room.occupancy & ~u.traversable))
        if np.isinf(field[r - 1 : r + 2, c - 1 : c + 2]).all()
    ]
    assert inf_free
    x, y = grid.cell_to_world(np.array(inf_free[0]))
    assert np.isinf(sample_field(field, grid, x, y))
    s = u._scene
    rb.set_robot_pose(s.model, s.data, s.robot, np.array([x, y, 0.0]))
    _, _, _, _, info = env.step(np.array([0.0, 0.0, 1.0], np.float32))  # STOP there
    assert np.isfinite(info["distance_to_goal"])
    assert info["distance_to_goal"] == pytest.approx(distance_at(field, grid, x, y))
    assert np.isfinite(info["soft_spl"])


def test_noise_options_are_off_by_default_and_replay_per_seeded_episode():
    def run(**kw):
        e = gym.make(ENV_ID, split="val", image_size=16, **kw)
        try:
            obs, _ = e.reset(options={"episode": 0})
            depths = [obs["depth"]]
            for _ in range(5):
                obs, *_ = e.step(np.array([1.0, 0.5, -1.0], np.float32))
                depths.append(obs["depth"])
            return np.stack(depths), e.unwrapped.robot_pose_world()
        finally:
            e.close()

    clean_depth, clean_pose = run()
    again_depth, again_pose = run(depth_noise_std=0.0, actuation_noise=0.0)
    np.testing.assert_array_equal(clean_depth, again_depth)
    noisy_depth, noisy_pose = run(depth_noise_std=0.05, actuation_noise=0.3)
    replay_depth, replay_pose = run(depth_noise_std=0.05, actuation_noise=0.3)
    np.testing.assert_array_equal(noisy_depth, replay_depth)  # seeded by (k, seed)
    np.testing.assert_array_equal(noisy_pose, replay_pose)
    assert 0.02 < np.std(noisy_depth[0] - clean_depth[0]) < 0.08
    assert not np.allclose(noisy_pose, clean_pose)
    with pytest.raises(ValueError, match="depth_noise_std"):
        gym.make(ENV_ID, depth_noise_std=-1.0)
