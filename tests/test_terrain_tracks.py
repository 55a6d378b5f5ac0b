"""Stump and hexagon height lines (pure numpy): geometry, units, randomness, bad input."""

import numpy as np
import pytest

from acl3d.terrain.tracks import (
    START_PAD,
    TERRAIN_STEP,
    TrackGenerator,
    check_buildable,
    track_task_space,
)


@pytest.fixture
def gen():
    return TrackGenerator()


def rising_edges(gen, heights):
    on = heights > 1e-6
    return int(np.sum(on[1:] & ~on[:-1]))


def test_stumps_follow_original_units(gen):
    heights = gen.heights({"stump_height": 2.0, "obstacle_spacing": 3.0}, np.random.default_rng(0))
    x = gen.x
    # start pad is flat, first stump starts where the pad ends
    assert np.all(heights[x < START_PAD * TERRAIN_STEP - 1e-6] == 0)
    # spacing 3 m after a 1-TS stump: 25 stumps over the 200-TS track (verified in the original)
    assert rising_edges(gen, heights) == 25
    tops = heights[heights > 0]
    assert abs(np.median(tops) - 2.0 * TERRAIN_STEP) < 0.1  # N(h, 0.1) in TS units


def test_negative_heights_give_the_minimum_stump(gen):
    heights = gen.heights({"stump_height": -3.0, "obstacle_spacing": 3.0}, np.random.default_rng(0))
    assert heights.max() == pytest.approx(0.05 * TERRAIN_STEP)


def test_same_generator_seed_same_terrain_other_seed_differs(gen):
    task = {"stump_height": 1.5, "obstacle_spacing": 2.0}
    a = gen.heights(task, np.random.default_rng(3))
    b = gen.heights(task, np.random.default_rng(3))
    c = gen.heights(task, np.random.default_rng(4))
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


def test_hexagons_grow_with_offsets(gen):
    small = gen.heights({"poly_shape": np.zeros(12)}, np.random.default_rng(0))
    big = gen.heights({"poly_shape": np.full(12, 3.0)}, np.random.default_rng(0))
    assert 0.15 < small.max() < 0.4  # the default hexagon is 0.5 TS tall
    assert big.max() > 3 * small.max()
    assert rising_edges(gen, small) >= 5


def test_task_space_describes_names_bounds_units():
    space = track_task_space(["stump_height", "obstacle_spacing"])
    assert space.names == ("stump_height", "obstacle_spacing")
    assert space.dim == 2
    assert np.allclose(space.low, [0, 0]) and np.allclose(space.high, [3, 6])
    assert "TS" in space.describe() and "m" in space.describe()
    vec = space.to_vector({"stump_height": 1.0})  # partial: default spacing
    assert space.to_dict(vec) == {"stump_height": 1.0, "obstacle_spacing": 8.0}


@pytest.mark.parametrize(
    "task, name",
    [
        ({"stump_height": 40.0}, "stump_height"),
        ({"obstacle_spacing": -1.0}, "obstacle_spacing"),
        ({"poly_shape": np.full(12, 50.0)}, "poly_shape"),
    ],
)
def test_unbuildable_values_name_parameter_and_range(task, name):
    with pytest.raises(ValueError, match=name) as err:
        check_buildable(task)
    assert "range" in str(err.value)


def test_boxes_stamped_together_equal_boxes_stamped_one_by_one(gen):
    from acl3d.terrain.tracks import _columns

    rng = np.random.default_rng(4)
    cell = gen.grid.cell
    x0 = np.concatenate([rng.uniform(-6.0, 60.0, 40), [10.0, 10.0 + cell / 3, 20.0]])
    x1 = np.concatenate([x0[:40] + rng.uniform(0.0, 3.0, 40), [10.0 + cell / 4, 12.0, 19.0]])
    h = rng.uniform(0.0, 2.0, len(x0))  # overlapping, narrower than a cell, empty, off the grid
    one_by_one = np.zeros_like(gen.x)
    for a, b, top in zip(x0, x1, h):
        cols = _columns(gen.grid, a, b)
        np.maximum(one_by_one[cols], top, out=one_by_one[cols])
    together = np.zeros_like(gen.x)
    gen._stamp_boxes(together, list(zip(x0, x1, h)))
    assert together.tobytes() == one_by_one.tobytes()
    assert together.max() > 0
