"""Procedural houses: determinism, splits, placement rules, occupancy, MJCF and rendering."""

from functools import cache

import mujoco
import numpy as np
import pytest
from scipy import ndimage

from vla_gr.envs.floorplan import WALL_THICKNESS, door_clear_zones, wall_boxes
from vla_gr.envs.geodesic import traversable_cells
from vla_gr.envs.house import (
    build_house,
    generate_house,
    house_to_mjcf,
    split_seed,
    unreachable_problems,
)
from vla_gr.envs.placement import rects_overlap
from vla_gr.envs.scene import COLORS, GOAL_CATEGORIES, ROOM_TYPES, ObjectInstance, Room

ROBOT = (
    '<body name="robot" pos="{x} {y} 0.2"><joint name="rx" type="slide" axis="1 0 0"/>'
    '<joint name="ry" type="slide" axis="0 1 0"/>'
    '<geom name="robot_base" type="sphere" size="0.18" contype="1" conaffinity="1"/></body>'
)
SEEDS = range(12)


@cache
def house(seed: int, num_rooms: int | None = None, clutter: float = 1.0):
    return generate_house(seed, num_rooms=num_rooms, clutter=clutter)


def cell_centres(h):
    xs, ys = h.grid.cell_centres()  # (H, W) each
    return xs, ys


def test_split_seeds_are_disjoint_and_validated():
    ranges = {s: {split_seed(s, i) for i in (0, 1, 999_999)} for s in ("train", "val", "test")}
    assert split_seed("train", 5) == 5 and split_seed("val", 0) == 1_000_000
    assert max(ranges["train"]) < min(ranges["val"]) and max(ranges["val"]) < min(ranges["test"])
    with pytest.raises(ValueError, match="split"):
        split_seed("dev", 0)
    with pytest.raises(ValueError, match="index"):
        split_seed("val", 1_000_000)


def test_same_seed_gives_identical_house_and_model():
    a, b = generate_house(7), generate_house(7)
    assert house_to_mjcf(a) == house_to_mjcf(b)
    assert a.occupancy.tobytes() == b.occupancy.tobytes()
    assert a.object_ids.tobytes() == b.object_ids.tobytes()
    assert a.objects == b.objects and a.rooms == b.rooms and a.doors == b.doors


def test_different_seeds_differ():
    models = {house_to_mjcf(house(s)) for s in range(6)}
    assert len(models) == 6
    assert house(0).occupancy.shape != house(1).occupancy.shape or not np.array_equal(
        house(0).occupancy, house(1).occupancy
    )


def test_bad_arguments_raise():
    with pytest.raises(ValueError, match="num_rooms"):
        generate_house(0, num_rooms=7)
    with pytest.raises(ValueError, match="cell_size"):
        generate_house(0, cell_size=0.1)
    with pytest.raises(ValueError, match="clutter"):
        generate_house(0, clutter=-1.0)


@pytest.mark.parametrize("num_rooms", [1, 2, 3, 4, 5, 6])
def test_models_compile_for_every_room_count(num_rooms):
    for seed in (num_rooms, 100 + num_rooms):
        h = house(seed, num_rooms)
        assert len(h.rooms) == num_rooms
        assert h.grid.cell_size <= 0.05
        assert {r.room_type for r in h.rooms} <= set(ROOM_TYPES)
        x, y = _free_point(h)
        model = mujoco.MjModel.from_xml_string(house_to_mjcf(h, ROBOT.format(x=x, y=y)))
        names = {model.geom(i).name for i in range(model.ngeom)}
        assert "floor" in names and any(n.startswith("wall_") for n in names)
        for obj in h.objects:
            body = model.body(obj.body_name)
            geoms = [
                model.geom(i).name for i in range(model.ngeom) if model.geom_bodyid[i] == body.id
            ]
            assert geoms and all(g.startswith(f"obj{obj.instance_id}_") for g in geoms)


def _free_point(h):
    """A traversable point in the largest free region."""
    free = traversable_cells(h)
    labels, _ = ndimage.label(free, structure=np.ones((3, 3), int))
    main = labels == np.argmax(np.bincount(labels.ravel())[1:]) + 1
    rows, cols = np.nonzero(main)
    x, y = h.grid.cell_to_world(np.array([rows[len(rows) // 2], cols[len(cols) // 2]]))
    return float(x), float(y)


def test_rooms_doors_and_sizes():
    for seed in SEEDS:
        h = house(seed)
        assert 2 <= len(h.rooms) <= 5  # drawn from the seed when num_rooms is None
        for room in h.rooms:
            width, depth = room.x1 - room.x0, room.y1 - room.y0
            assert min(width, depth) >= 2.0 and max(width, depth) <= 5.0 + 1e-9
        for door in h.doors:
            assert door.width >= 0.9
            # The door centre is free and the robot fits through it.
            r, c = h.grid.world_to_cell(np.array([door.x, door.y]))
            assert not h.occupancy[r, c] and traversable_cells(h)[r, c]
        # Doors connect all rooms (graph search over the door list).
        reached, frontier = {0}, [0]
        while frontier:
            k = frontier.pop()
            for d in h.doors:
                for a, b in ((d.room_a, d.room_b), (d.room_b, d.room_a)):
                    if a == k and b not in reached:
                        reached.add(b)
                        frontier.append(b)
        assert reached == set(range(len(h.rooms)))


def test_furniture_is_placed_where_it_belongs():
    allowed = {
        "toilet": {"bathroom"},
        "bed": {"bedroom"},
        "sofa": {"living_room", "office"},
        "tv_monitor": {"living_room", "bedroom", "office"},
    }
    seen_colors = set()
    for seed in SEEDS:
        h = house(seed)
        for obj in h.objects:
            room = h.rooms[obj.room_index]
            if obj.category in allowed:
                assert room.room_type in allowed[obj.category], (seed, obj)
            corners = obj.footprint()
            assert (corners[:, 0] >= room.x0 - 1e-6).all() and (
                corners[:, 0] <= room.x1 + 1e-6
            ).all()
            assert (corners[:, 1] >= room.y0 - 1e-6).all() and (
                corners[:, 1] <= room.y1 + 1e-6
            ).all()
            assert obj.color in COLORS
            seen_colors.add(obj.color)
        for room in h.rooms:
            cats = [o.category for o in h.objects if o.room_index == room.index]
            if room.room_type == "bathroom":
                assert "toilet" in cats
            if room.room_type == "bedroom":
                assert "bed" in cats
        # Ids are 1..N, in order.
        assert [o.instance_id for o in h.objects] == list(range(1, len(h.objects) + 1))
    assert len(seen_colors) >= 6


def test_objects_do_not_overlap_or_block_doors():
    for seed in SEEDS:
        h = house(seed)
        fps = [o.footprint() for o in h.objects]
        for i in range(len(fps)):
            for j in range(i + 1, len(fps)):
                assert not rects_overlap(fps[i], fps[j]), (seed, i, j)
        for room in h.rooms:
            for x0, y0, x1, y1 in door_clear_zones(room, h.doors):
                zone = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
                for obj in h.objects:
                    assert not rects_overlap(obj.footprint(), zone), (seed, obj)


def test_distractors_exist_in_every_house():
    for seed in SEEDS:
        h = house(seed)
        multi = [
            c
            for c in GOAL_CATEGORIES
            if len({(o.color, o.room_index) for o in h.objects if o.category == c}) >= 2
        ]
        assert multi, seed


def test_free_space_connected_and_every_object_reachable():
    for seed in SEEDS:
        h = house(seed)
        free = traversable_cells(h)
        _, count = ndimage.label(free, structure=np.ones((3, 3), int))
        assert count == 1, seed
        # Independent check: a free cell lies within robot radius + 2 cells of each footprint.
        dist = ndimage.distance_transform_edt(~free) * h.grid.cell_size  # (H, W)
        for obj in h.objects:
            assert dist[h.object_ids == obj.instance_id].min() <= 0.18 + 2 * h.grid.cell_size
        assert unreachable_problems(h) == ([], [])
        # Outside the house is occupied.
        assert h.occupancy[0, :].all() and h.occupancy[:, -1].all()


def test_footprints_in_grid_match_object_rectangles():
    for seed in (0, 1, 2):
        h = house(seed)
        xs, ys = cell_centres(h)
        for obj in h.objects:
            hx, hy = obj.half_extents
            c, s = np.cos(obj.yaw), np.sin(obj.yaw)
            lx = c * (xs - obj.x) + s * (ys - obj.y)
            ly = -s * (xs - obj.x) + c * (ys - obj.y)
            inside = (np.abs(lx) <= hx) & (np.abs(ly) <= hy)  # (H, W)
            assert np.array_equal(h.object_ids == obj.instance_id, inside)
            area = inside.sum() * h.grid.cell_size**2
            assert area == pytest.approx(4 * hx * hy, rel=0.25)
        assert h.occupancy[h.object_ids > 0].all()
        # Walls at robot height are occupied: the centre of every blocking wall box.
        for box in wall_boxes(h.rooms, h.doors):
            r, c = h.grid.world_to_cell(np.array([(box.x0 + box.x1) / 2, (box.y0 + box.y1) / 2]))
            assert h.occupancy[r, c] == box.blocks_robot


def _one_room(objects):
    room = Room(0, "living_room", 0.0, 0.0, 4.0, 4.0)
    return build_house(seed=0, rooms=[room], doors=[], objects=objects)


def test_hand_built_room_has_full_thickness_walls():
    h = _one_room([])
    xs, ys = cell_centres(h)
    inside = (xs > 0) & (xs < 4) & (ys > 0) & (ys < 4)
    assert not h.occupancy[inside].any()
    wall = (xs > -WALL_THICKNESS) & (xs < 0) & (ys > 0) & (ys < 4)
    assert h.occupancy[wall].all() and wall.sum() == 2 * round(4 / h.grid.cell_size)


def test_collision_shapes_match_footprints_and_robot_collides():
    h = house(3)
    x, y = _free_point(h)
    model = mujoco.MjModel.from_xml_string(house_to_mjcf(h, ROBOT.format(x=x, y=y)))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    for obj in h.objects:
        col = model.geom(f"{obj.body_name}_collision")
        assert col.contype[0] == 1 and col.conaffinity[0] == 0
        pos = data.geom_xpos[col.id]
        half = np.abs(data.geom_xmat[col.id].reshape(3, 3)) @ col.size  # world AABB half sizes
        corners = obj.footprint()
        np.testing.assert_allclose(pos[:2], corners.mean(0), atol=1e-6)
        np.testing.assert_allclose(half[:2], (corners.max(0) - corners.min(0)) / 2, atol=1e-4)
        assert pos[2] - half[2] == pytest.approx(0.0) and pos[2] + half[2] >= 0.4 - 1e-9
    for i in range(model.ngeom):
        name = model.geom(i).name
        if name.startswith("obj") and not name.endswith("_collision"):
            assert model.geom_contype[i] == 0 and model.geom_conaffinity[i] == 0
    assert data.ncon == 0  # robot in free space touches nothing
    # Move the robot onto the first wall at robot height: contacts appear with wall geoms.
    box = next(b for b in wall_boxes(h.rooms, h.doors) if b.blocks_robot)
    data.qpos[:] = [(box.x0 + box.x1) / 2 - x, (box.y0 + box.y1) / 2 - y]
    mujoco.mj_forward(model, data)
    hit = {model.geom(int(c.geom[k])).name for c in data.contact[: data.ncon] for k in range(2)}
    assert any(n.startswith("wall_") for n in hit)


def test_render_is_not_blank_and_segmentation_names_map_to_instances():
    chair = ObjectInstance(1, "sofa", "red", 0, 2.0, 0.5, 0.0, (0.9, 0.42), 0.8)
    plant = ObjectInstance(2, "plant", "green", 0, 3.5, 3.5, 0.0, (0.2, 0.2), 1.0)
    h = _one_room([chair, plant])
    model = mujoco.MjModel.from_xml_string(house_to_mjcf(h))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.lookat[:] = [2.0, 0.5, 0.4]
    cam.distance, cam.azimuth, cam.elevation = 2.0, -90.0, -15.0  # in front of the sofa
    with mujoco.Renderer(model, 64, 64) as renderer:
        renderer.update_scene(data, cam)
        rgb = renderer.render()  # (64, 64, 3)
        renderer.enable_segmentation_rendering()
        renderer.update_scene(data, cam)
        seg = renderer.render()  # (64, 64, 2): geom id, object type
    assert rgb.std() > 5.0
    centre = rgb[28:36, 28:36].reshape(-1, 3).mean(0)
    assert centre[0] > 1.5 * centre[1] and centre[0] > 1.5 * centre[2]  # the red sofa
    ids = np.zeros((64, 64), np.int32)
    for geom_id in np.unique(seg[..., 0]):
        if geom_id < 0:
            continue
        name = model.geom(int(geom_id)).name
        body = model.body(int(model.geom_bodyid[geom_id])).name
        if name.startswith("obj"):
            assert name.startswith(body + "_")
            ids[seg[..., 0] == geom_id] = int(body[3:])
    assert ids[32, 32] == 1 and (ids == 1).sum() > 200


def test_clutter_scales_the_number_of_objects():
    essential = {"sofa", "tv_monitor", "bed", "table", "toilet"}
    for seed in range(4):
        bare = generate_house(seed, clutter=0.0)
        assert {o.category for o in bare.objects} <= essential
        assert len(bare.objects) <= 2 * len(bare.rooms)
    totals = [
        sum(len(generate_house(s, num_rooms=3, clutter=c).objects) for s in range(5))
        for c in (0.5, 1.0, 2.0)
    ]
    assert totals[0] < totals[1] < totals[2]


@pytest.mark.slow
def test_many_houses_are_valid():
    for seed in range(150):
        h = generate_house(
            split_seed("train", seed), num_rooms=1 + seed % 6, clutter=0.5 + seed % 4
        )
        mujoco.MjModel.from_xml_string(house_to_mjcf(h))
        assert unreachable_problems(h) == ([], [])
        _, count = ndimage.label(traversable_cells(h), structure=np.ones((3, 3), int))
        assert count == 1, seed


def test_door_opening_in_grid_has_the_door_width():
    from vla_gr.envs.scene import Door

    rooms = [Room(0, "kitchen", 0.0, 0.0, 4.0, 3.0), Room(1, "office", 4.1, 0.0, 8.0, 3.0)]
    door = Door(0, 1, 4.05, 1.5, 1.0, "y")
    h = build_house(seed=0, rooms=rooms, doors=[door], objects=[])
    xs, ys = cell_centres(h)
    column = h.occupancy[:, h.grid.world_to_cell(np.array([4.05, 0.0]))[1]]  # (H,)
    inside_wall = (ys[:, 0] > 0) & (ys[:, 0] < 3)
    assert (~column[inside_wall]).sum() == round(1.0 / h.grid.cell_size)
    free = traversable_cells(h)
    _, count = ndimage.label(free, structure=np.ones((3, 3), int))
    assert count == 1  # the two rooms are joined through the door
    closed = build_house(seed=0, rooms=rooms, doors=[], objects=[])
    _, count = ndimage.label(traversable_cells(closed), structure=np.ones((3, 3), int))
    assert count == 2
