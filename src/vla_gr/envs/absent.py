"""Absent-object episodes: a request for an object the house does not have.

Episode ``index`` of a split has an absent-object twin in the same house
(:func:`sample_absent_episode`, a pure function of its arguments like
:func:`~vla_gr.envs.episodes.sample_episode`). Its request, in the generator's words, names
either a colour that no object of a goal category has ("find the purple sofa" where every sofa
is red or blue: kind ``colour``) or a goal category the house lacks ("find the bed" in a house
without one: kind ``category``). The spec says so with ``absent=True`` and has no goal object
(``goal_instance_id == ABSENT_GOAL_ID``, ``geodesic_start_distance == 0``): a STOP is a false
STOP, declaring ``not_found`` is the right outcome, SPL is undefined. The start is a roomy cell
of the house's reachable free space.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from vla_gr.envs.episodes import (
    _SPLIT_CODE,
    EPISODES_PER_SCENE,
    SPLITS,
    START_CLEARANCE,
    EpisodeSpec,
    NoEpisodeError,
    scene_seed_for,
)
from vla_gr.envs.geodesic import ROBOT_RADIUS, traversable_cells
from vla_gr.envs.instructions import Description, render_instruction
from vla_gr.envs.scene import COLORS, GOAL_CATEGORIES, House

__all__ = [
    "ABSENT_GOAL_ID",
    "ABSENT_KINDS",
    "absent_descriptions",
    "absent_rng",
    "check_absent",
    "fitting_objects",
    "requested_object",
    "sample_absent_episode",
]

#: ``goal_instance_id`` of an absent-object episode (no object has it: ids start at 1).
ABSENT_GOAL_ID = -1
#: What an absent request gets wrong: a colour of a category the house has, or the category.
ABSENT_KINDS: tuple[str, ...] = ("colour", "category")


def absent_rng(split: str, index: int) -> np.random.Generator:
    """The RNG of absent-object episode ``index`` of ``split`` (independent of the normal
    episode ``index``'s and of every other episode's)."""
    if split not in _SPLIT_CODE:
        raise ValueError(f"split={split!r} is not valid; choose one of {list(SPLITS)}")
    if index < 0:
        raise ValueError(f"index={index} must be >= 0")
    return np.random.default_rng(np.random.SeedSequence([_SPLIT_CODE[split], int(index), 3]))


def absent_descriptions(house: House) -> dict[str, list[Description]]:
    """{kind: descriptions no object of ``house`` fits}: each goal category it has with each
    colour none of its objects of that category has (``colour``), each goal category it lacks
    (``category``)."""
    colours: dict[str, set[str]] = {}
    for obj in house.objects:
        colours.setdefault(obj.category, set()).add(obj.color)
    return {
        "colour": [
            Description(category, color=colour)
            for category in GOAL_CATEGORIES
            if category in colours
            for colour in COLORS
            if colour not in colours[category]
        ],
        "category": [Description(c) for c in GOAL_CATEGORIES if c not in colours],
    }


def _roomy_reachable_cells(house: House) -> np.ndarray:
    """Cells (N, 2) (row, col) with ``START_CLEARANCE`` around the base, in the largest
    connected part of the free space (the reachable house)."""
    free = traversable_cells(house)  # (H, W)
    labels, count = ndimage.label(free, structure=np.ones((3, 3), int))
    if count == 0:
        return np.zeros((0, 2), np.int64)
    main = labels == int(np.argmax(np.bincount(labels.ravel())[1:])) + 1  # (H, W)
    return np.argwhere(main & traversable_cells(house, ROBOT_RADIUS + START_CLEARANCE))


def sample_absent_episode(
    split: str,
    index: int,
    num_rooms: int | None = None,
    clutter: float = 1.0,
    episodes_per_scene: int = EPISODES_PER_SCENE,
    house: House | None = None,
) -> EpisodeSpec:
    """Absent-object episode ``index`` of ``split``, in the house of episode ``index``: same
    arguments, same spec. The kind is drawn among those the house allows, then one of its
    descriptions; NoEpisodeError when the house allows none or has no roomy start."""
    from vla_gr.envs.house import generate_house

    seed = scene_seed_for(split, index, episodes_per_scene)
    if house is None:
        house = generate_house(seed, num_rooms=num_rooms, clutter=clutter)
    elif house.seed != seed:
        raise ValueError(f"house seed {house.seed} is not episode {index}'s scene seed {seed}")
    rng = absent_rng(split, index)
    options = {kind: d for kind, d in absent_descriptions(house).items() if d}
    cells = _roomy_reachable_cells(house)  # (N, 2)
    if not options or len(cells) == 0:
        raise NoEpisodeError(f"house {house.seed} hosts no absent-object episode")
    kinds = sorted(options)
    pool = options[kinds[int(rng.integers(len(kinds)))]]
    description = pool[int(rng.integers(len(pool)))]
    row, col = cells[rng.integers(len(cells))]
    x, y = house.grid.cell_to_world(np.array([row, col]))
    return EpisodeSpec(
        episode_id=f"{split}-{index:06d}-absent",
        split=split,
        scene_seed=int(house.seed),
        num_rooms=num_rooms,
        clutter=float(clutter),
        start_x=float(x),
        start_y=float(y),
        start_yaw=float(rng.uniform(-np.pi, np.pi)),
        goal_instance_id=ABSENT_GOAL_ID,
        goal_category=description.category,
        instruction=render_instruction(description, rng),
        geodesic_start_distance=0.0,
        absent=True,
    )


def fitting_objects(house: House, spec: EpisodeSpec) -> list:
    """The objects of ``house`` that ``spec``'s request fits: its ``description`` when it has
    one, else what the world reads in its instruction (:func:`~vla_gr.envs.grounding.fits`)."""
    from vla_gr.envs.grounding import Request, fits, read_request

    if spec.description is not None:
        request = Request(**spec.description)
    else:
        request = read_request(spec.instruction)
    if request.category is None:
        return []
    return [o for o in house.objects if fits(house, o, request)]


def check_absent(spec: EpisodeSpec, house: House) -> None:
    """ValueError naming the problem unless absent-object ``spec`` has no goal object
    (``ABSENT_GOAL_ID``, start distance 0) and its request fits no object of ``house``."""
    from vla_gr.envs.grounding import object_phrase

    if spec.goal_instance_id != ABSENT_GOAL_ID or spec.geodesic_start_distance != 0.0:
        raise ValueError(
            f"episode {spec.episode_id}: an absent-object episode has goal_instance_id="
            f"{ABSENT_GOAL_ID} and geodesic_start_distance=0, got {spec.goal_instance_id} and "
            f"{spec.geodesic_start_distance}"
        )
    try:
        found = fitting_objects(house, spec)
    except ValueError as err:
        raise ValueError(f"episode {spec.episode_id}: {err}") from None
    if found:
        raise ValueError(
            f"episode {spec.episode_id}: the absent-object request {spec.instruction!r} fits the "
            f"{object_phrase(house, found[0])} (object {found[0].instance_id}) of house "
            f"{house.seed}"
        )


def requested_object(spec: EpisodeSpec) -> dict:
    """What an absent-object ``spec`` asks for, in the shape of an object's summary:
    ``instance_id`` (``ABSENT_GOAL_ID``), ``category``, ``color`` and ``room`` (None where not
    said)."""
    from vla_gr.envs.grounding import Request, read_request

    request = Request(**spec.description) if spec.description else read_request(spec.instruction)
    return {
        "instance_id": ABSENT_GOAL_ID,
        "category": spec.goal_category,
        "color": request.color,
        "room": request.room,
    }
