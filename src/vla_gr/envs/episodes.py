"""ObjectNav episode specs: deterministic sampling, validation, JSONL files.

An :class:`EpisodeSpec` is everything needed to replay an episode exactly: the scene
(seed and generation knobs), the start pose, the goal instance and the instruction.
Episode ``index`` of a split lives in scene ``index // EPISODES_PER_SCENE`` (several
episodes per house, as Habitat's datasets do) and is drawn from an RNG seeded by
(split, index) only, so ``sample_episode`` is a pure function of its arguments.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vla_gr.envs.geodesic import (
    ROBOT_RADIUS,
    sample_field,
    traversable_cells,
)
from vla_gr.envs.geodesic import goal_distance_field as goal_field
from vla_gr.envs.scene import House
from vla_gr.errors import UserError
from vla_gr.text_fold import fold_to_ascii

logger = logging.getLogger(__name__)

SPLITS = ("train", "val", "test")
EPISODES_PER_SCENE = 4
MIN_START_DISTANCE = 2.0  # m, geodesic start -> goal footprint
MAX_START_DISTANCE = 15.0
START_CLEARANCE = 0.05  # m of free space around the base at the start, beyond its radius
INSTRUCTION_MAX_LENGTH = 256  # characters of an instruction, after folding to ASCII
_SPLIT_CODE = {"train": 11, "val": 23, "test": 37}


class EpisodeFileError(UserError, ValueError):
    """An episodes file that is missing, empty or holds a bad line (named by number)."""


class NoEpisodeError(ValueError):
    """A split index whose house cannot host an episode: no goal with a distractor and a
    unique description, or no start at a valid distance from any goal (rare)."""


#: The keys of an episode's ``description`` (the generator's fields of its goal).
DESCRIPTION_FIELDS: tuple[str, ...] = ("category", "color", "room", "near")
#: The fields of an episode record written only when set (so older files read unchanged).
OPTIONAL_FIELDS: tuple[str, ...] = ("description", "absent")
#: The text fields of an episode record.
TEXT_FIELDS: tuple[str, ...] = ("episode_id", "split", "goal_category", "instruction")


@dataclass(frozen=True)
class EpisodeSpec:
    """One ObjectNav episode. Poses are in world metres / radians.

    ``description`` (optional) holds the generator's fields of the goal
    (``DESCRIPTION_FIELDS``, None where not named) for an episode whose ``instruction`` is a
    hand-written request. ``absent`` (optional) marks a request for an object the house does
    not have (:mod:`~vla_gr.envs.absent`): no goal object (``goal_instance_id`` -1, start
    distance 0), ``goal_category`` the category asked for. Each is written to files and dicts
    only when set, so specs without them read and write exactly as before.
    """

    episode_id: str
    split: str
    scene_seed: int
    num_rooms: int | None
    clutter: float
    start_x: float
    start_y: float
    start_yaw: float
    goal_instance_id: int
    goal_category: str
    instruction: str
    geodesic_start_distance: float
    description: dict | None = dataclasses.field(default=None, hash=False)
    absent: bool = False

    def __post_init__(self) -> None:
        check_description(self.description, self.episode_id)
        if not isinstance(self.absent, bool):
            raise ValueError(
                f"episode {self.episode_id}: absent must be true or false, got {self.absent!r}"
            )

    @property
    def scene_key(self) -> tuple[int, int | None, float]:
        """What determines the house: (scene_seed, num_rooms, clutter)."""
        return (self.scene_seed, self.num_rooms, self.clutter)

    @property
    def start_pose(self) -> np.ndarray:
        """World start pose (3,) = (x, y, yaw)."""
        return np.array([self.start_x, self.start_y, self.start_yaw], dtype=np.float64)

    def to_dict(self) -> dict:
        """The fields as a dict; ``description`` and ``absent`` only when set."""
        out = dataclasses.asdict(self)
        for key in OPTIONAL_FIELDS:
            if not out[key]:
                del out[key]
        return out

    @classmethod
    def from_dict(cls, record: dict) -> EpisodeSpec:
        """Build from a dict with exactly the dataclass fields, ``description`` and ``absent``
        optional (ValueError otherwise)."""
        names = {f.name for f in dataclasses.fields(cls)}
        missing, extra = names - set(record) - set(OPTIONAL_FIELDS), set(record) - names
        if missing or extra:
            raise ValueError(
                f"episode record has missing fields {sorted(missing)} / "
                f"unknown fields {sorted(extra)}"
            )
        rec = dict(record)
        texts = {k: type(rec[k]).__name__ for k in TEXT_FIELDS if not isinstance(rec[k], str)}
        if texts:
            raise ValueError(f"episode record fields must be text: {texts} are not")
        rec["num_rooms"] = None if rec["num_rooms"] is None else int(rec["num_rooms"])
        for key in ("clutter", "start_x", "start_y", "start_yaw", "geodesic_start_distance"):
            rec[key] = float(rec[key])
        for key in ("scene_seed", "goal_instance_id"):
            rec[key] = int(rec[key])
        return cls(**rec)


def check_description(description, episode_id: str = "?") -> None:
    """ValueError naming the problem unless ``description`` is None or a dict with exactly
    the keys ``DESCRIPTION_FIELDS``, each a str or None."""
    if description is None:
        return
    if not isinstance(description, dict) or set(description) != set(DESCRIPTION_FIELDS):
        got = sorted(description) if isinstance(description, dict) else type(description).__name__
        raise ValueError(
            f"episode {episode_id}: description must be a dict with the keys "
            f"{list(DESCRIPTION_FIELDS)}, got {got}"
        )
    bad = {k: v for k, v in description.items() if v is not None and not isinstance(v, str)}
    if bad:
        raise ValueError(f"episode {episode_id}: description values must be str or None: {bad}")


def folded_instruction(spec: EpisodeSpec) -> str:
    """The spec's instruction folded to printable ASCII (:func:`fold_to_ascii`), as the world
    shows it; ValueError in one line when it is not a str or folds to more than
    ``INSTRUCTION_MAX_LENGTH`` characters."""
    if not isinstance(spec.instruction, str):
        raise ValueError(
            f"episode {spec.episode_id}: instruction must be a str, "
            f"got {type(spec.instruction).__name__}"
        )
    folded = fold_to_ascii(spec.instruction)
    if len(folded) > INSTRUCTION_MAX_LENGTH:
        raise ValueError(
            f"episode {spec.episode_id}: instruction of {len(folded)} characters is longer "
            f"than the limit of {INSTRUCTION_MAX_LENGTH}; say it in fewer words"
        )
    return folded


def episode_rng(split: str, index: int) -> np.random.Generator:
    """The RNG of episode ``index`` of ``split`` (independent of every other episode)."""
    if split not in _SPLIT_CODE:
        raise ValueError(f"split={split!r} is not valid; choose one of {list(SPLITS)}")
    if index < 0:
        raise ValueError(f"index={index} must be >= 0")
    return np.random.default_rng(np.random.SeedSequence([_SPLIT_CODE[split], int(index), 2]))


def scene_seed_for(split: str, index: int, episodes_per_scene: int = EPISODES_PER_SCENE) -> int:
    """Seed of the house that episode ``index`` of ``split`` takes place in."""
    from vla_gr.envs.house import split_seed

    if episodes_per_scene < 1:
        raise ValueError(f"episodes_per_scene={episodes_per_scene} must be >= 1")
    return int(split_seed(split, index // episodes_per_scene))


def sample_start(
    house: House,
    distance_field: np.ndarray,
    rng: np.random.Generator,
    min_distance: float = MIN_START_DISTANCE,
    max_distance: float = MAX_START_DISTANCE,
) -> tuple[float, float, float, float] | None:
    """A random start (x, y, yaw, geodesic distance) for a goal, or None if none fits.

    ``distance_field`` (H, W) is the goal's geodesic distance field. Candidates are cell
    centres with ``START_CLEARANCE`` of free space around the base whose geodesic
    distance lies in [min_distance, max_distance] (finite, hence reachable).
    """
    if not 0 <= min_distance <= max_distance:
        raise ValueError(
            f"need 0 <= min_distance <= max_distance, got {min_distance}, {max_distance}"
        )
    roomy = traversable_cells(house, ROBOT_RADIUS + START_CLEARANCE)  # (H, W)
    ok = roomy & np.isfinite(distance_field) & (distance_field >= min_distance)
    ok &= distance_field <= max_distance  # (H, W)
    cells = np.argwhere(ok)  # (N, 2) row, col
    if len(cells) == 0:
        return None
    row, col = cells[rng.integers(len(cells))]
    x, y = house.grid.cell_to_world(np.array([row, col]))
    yaw = float(rng.uniform(-math.pi, math.pi))
    return float(x), float(y), yaw, float(distance_field[row, col])


def sample_episode_in_house(
    house: House,
    split: str,
    index: int,
    num_rooms: int | None = None,
    clutter: float = 1.0,
    max_goal_tries: int = 16,
) -> EpisodeSpec:
    """Episode ``index`` of ``split`` in an already generated ``house`` (deterministic)."""
    from vla_gr.envs.instructions import describe_goal, goal_candidates

    rng = episode_rng(split, index)
    candidates = list(goal_candidates(house))
    if not candidates:
        raise NoEpisodeError(f"house {house.seed} has no goal candidates")
    order = rng.permutation(len(candidates))
    for k in order[:max_goal_tries]:
        goal_id = int(candidates[k])
        field = goal_field(house, goal_id)  # (H, W)
        start = sample_start(house, field, rng)
        if start is None:
            continue
        x, y, yaw, dist = start
        instruction = describe_goal(house, goal_id, rng)
        return EpisodeSpec(
            episode_id=f"{split}-{index:06d}",
            split=split,
            scene_seed=int(house.seed),
            num_rooms=num_rooms,
            clutter=float(clutter),
            start_x=x,
            start_y=y,
            start_yaw=yaw,
            goal_instance_id=goal_id,
            goal_category=house.object(goal_id).category,
            instruction=instruction,
            geodesic_start_distance=dist,
        )
    raise NoEpisodeError(
        f"no start {MIN_START_DISTANCE}-{MAX_START_DISTANCE} m from any goal in house {house.seed}"
    )


def sample_episode(
    split: str,
    index: int,
    num_rooms: int | None = None,
    clutter: float = 1.0,
    episodes_per_scene: int = EPISODES_PER_SCENE,
    house: House | None = None,
) -> EpisodeSpec:
    """Episode ``index`` of ``split``: same arguments, same spec, on any machine.

    ``house`` may be passed when the caller already generated the episode's house.
    """
    from vla_gr.envs.house import generate_house

    seed = scene_seed_for(split, index, episodes_per_scene)
    if house is None:
        house = generate_house(seed, num_rooms=num_rooms, clutter=clutter)
    elif house.seed != seed:
        raise ValueError(f"house seed {house.seed} is not episode {index}'s scene seed {seed}")
    return sample_episode_in_house(house, split, index, num_rooms, clutter)


def sample_episodes_rooms_cycling(
    split: str, first: int, count: int, max_rooms: int = 6
) -> list[EpisodeSpec]:
    """``count`` episodes of ``split`` from index ``first`` on in houses of 1..``max_rooms``
    rooms drawn evenly: the k-th kept episode has ``1 + k % max_rooms`` rooms; an index whose
    house hosts no episode is skipped (the next index takes its place)."""
    if count < 0 or not 1 <= max_rooms <= 6:
        raise ValueError(f"count={count} must be >= 0 and max_rooms={max_rooms} in [1, 6]")
    out: list[EpisodeSpec] = []
    index = first
    while len(out) < count:
        with contextlib.suppress(NoEpisodeError):  # a house with no episode: the next index
            out.append(sample_episode(split, index, num_rooms=1 + len(out) % max_rooms))
        index += 1
    return out


def validate_spec(
    spec: EpisodeSpec,
    house: House,
    traversable: np.ndarray | None = None,
    distance_field: np.ndarray | None = None,
) -> float:
    """Raise ValueError with the reason if ``spec`` cannot run in ``house``.

    Checks the goal exists (with the spec's category), the start lies in the map, outside
    every obstacle inflated by the robot radius, and is reachable from the goal; for an
    ``absent`` spec, that its request fits no object instead
    (:func:`~vla_gr.envs.absent.check_absent`).
    ``traversable`` (H, W) and ``distance_field`` (H, W) may be passed when already computed.
    Returns the geodesic start distance (m; 0 for an absent spec).
    """
    if spec.split not in SPLITS:
        raise ValueError(f"episode {spec.episode_id}: split={spec.split!r} not in {SPLITS}")
    if spec.scene_seed != house.seed:
        raise ValueError(
            f"episode {spec.episode_id}: scene_seed={spec.scene_seed} but house seed={house.seed}"
        )
    if spec.absent:
        from vla_gr.envs.absent import check_absent

        check_absent(spec, house)
    else:
        _check_goal(spec, house)
    pose = spec.start_pose
    if not np.all(np.isfinite(pose)):
        raise ValueError(f"episode {spec.episode_id}: start pose {pose.tolist()} is not finite")
    cell = house.grid.world_to_cell(pose[:2])  # (2,) row, col
    if not house.grid.in_bounds(cell):
        raise ValueError(
            f"episode {spec.episode_id}: start ({pose[0]:.2f}, {pose[1]:.2f}) is outside the map"
        )
    row, col = int(cell[0]), int(cell[1])
    if traversable is None:
        traversable = traversable_cells(house)
    if not traversable[row, col]:
        raise ValueError(
            f"episode {spec.episode_id}: start ({pose[0]:.2f}, {pose[1]:.2f}) is inside an "
            f"obstacle (or closer than the robot radius {ROBOT_RADIUS} m to one)"
        )
    if spec.absent:
        return 0.0
    if distance_field is None:
        distance_field = goal_field(house, spec.goal_instance_id)
    if not np.isfinite(distance_field[row, col]):
        raise ValueError(
            f"episode {spec.episode_id}: start ({pose[0]:.2f}, {pose[1]:.2f}) is unreachable "
            f"from goal object {spec.goal_instance_id}"
        )
    return sample_field(distance_field, house.grid, pose[0], pose[1])


def _check_goal(spec: EpisodeSpec, house: House) -> None:
    """ValueError unless ``spec``'s goal object is in ``house`` with the spec's category."""
    try:
        goal = house.object(spec.goal_instance_id)
    except KeyError:
        raise ValueError(
            f"episode {spec.episode_id}: goal object {spec.goal_instance_id} is missing from "
            f"house {house.seed}"
        ) from None
    if goal.category != spec.goal_category:
        raise ValueError(
            f"episode {spec.episode_id}: goal object {goal.instance_id} is a {goal.category}, "
            f"not a {spec.goal_category}"
        )


def save_episodes(path: str | Path, specs) -> Path:
    """Write ``specs`` as JSONL (one episode per line); returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    with tmp.open("w", encoding="utf-8") as f:
        for spec in specs:
            if not isinstance(spec, EpisodeSpec):
                raise ValueError(f"specs must hold EpisodeSpec, got {type(spec).__name__}")
            f.write(json.dumps(spec.to_dict(), sort_keys=True) + "\n")
    tmp.replace(path)
    return path


def load_episodes(path: str | Path, check: bool = True) -> list[EpisodeSpec]:
    """Read a JSONL file written by :func:`save_episodes` (blank lines skipped).

    A line that is not UTF-8 text holding an episode record is an :class:`EpisodeFileError`
    naming it; so is, with ``check`` (the default; off only for tools that rewrite records), a
    line that cannot run in its house or whose instruction does not describe its goal
    (:func:`check_episodes`).
    """
    path = Path(path)
    if not path.is_file():
        raise EpisodeFileError(f"episodes file {str(path)!r} does not exist")
    lines, specs = [], []
    with path.open("rb") as f:
        for lineno, raw in enumerate(f, start=1):
            try:
                line = raw.decode("utf-8")
                if not line.strip():
                    continue
                specs.append(EpisodeSpec.from_dict(json.loads(line)))
            except (json.JSONDecodeError, ValueError, TypeError) as err:  # Unicode errors too
                raise EpisodeFileError(f"{path}:{lineno}: bad episode record: {err}") from err
            lines.append(lineno)
    if not specs:
        raise EpisodeFileError(f"episodes file {str(path)!r} holds no episodes")
    if check:
        check_episodes(specs, [f"{path}:{n}" for n in lines])
    return specs


def check_episodes(specs, where) -> None:
    """EpisodeFileError naming ``where[i]`` (its file and line) for the first spec that the
    world would refuse at reset (its instruction too long once folded, :func:`folded_instruction`;
    its goal or start not valid in its house, :func:`validate_spec`) or whose instruction does
    not describe its goal: the one object of its house that the instruction describes
    (:func:`~vla_gr.envs.grounding.ground`) must be the goal.

    A spec with a ``description`` declares its goal itself (a hand-written request, the
    not-understood ones among them) and is not read; an ``absent`` spec's request must fit no
    object (:func:`validate_spec`).
    """
    from vla_gr.envs.grounding import ground, object_phrase
    from vla_gr.envs.house import generate_house

    key = house = traversable = None  # one house at a time: a file's episodes come by house
    for spec, place in zip(specs, where):
        if spec.scene_key != key:
            try:
                house = generate_house(spec.scene_seed, spec.num_rooms, clutter=spec.clutter)
            except ValueError as err:
                raise EpisodeFileError(
                    f"{place}: no house has scene_seed={spec.scene_seed}, "
                    f"num_rooms={spec.num_rooms}, clutter={spec.clutter}: {err}"
                ) from None
            key, traversable = spec.scene_key, traversable_cells(house)
        try:
            folded_instruction(spec)
            validate_spec(spec, house, traversable)
        except ValueError as err:
            raise EpisodeFileError(f"{place}: {err}") from None
        if spec.description is not None or spec.absent:
            continue
        goal = house.object(spec.goal_instance_id)
        try:
            found = ground(house, spec.instruction).instance
        except ValueError as err:
            raise EpisodeFileError(
                f"{place}: instruction {spec.instruction!r} does not pick goal object "
                f"{spec.goal_instance_id}: {str(err).strip(chr(34))}"
            ) from None
        if found is not goal:
            raise EpisodeFileError(
                f"{place}: instruction {spec.instruction!r} describes the "
                f"{object_phrase(house, found)} (object {found.instance_id}), not the goal, the "
                f"{object_phrase(house, goal)} (object {goal.instance_id}); correct it or give the "
                "line a 'description' of its goal"
            )
