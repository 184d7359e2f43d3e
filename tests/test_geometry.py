import numpy as np

from radseek.dataset import Wall
from radseek.geometry import path_lengths, path_lengths_per_wall, segment_hits_walls

WALL = Wall(start=(0.0, 0.0), end=(4.0, 0.0), thickness=0.2, height=3.0)


def test_perpendicular_crossing_is_thickness():
    a = np.array([2.0, -1.0, 1.0])
    b = np.array([2.0, 1.0, 1.0])
    assert np.isclose(path_lengths(a, b, [WALL]), 0.2)


def test_oblique_crossing_scales_with_secant():
    # 45 degrees in the horizontal plane: thickness / cos(45)
    a = np.array([1.0, -1.0, 1.0])
    b = np.array([3.0, 1.0, 1.0])
    assert np.isclose(path_lengths(a, b, [WALL]), 0.2 * np.sqrt(2))
    # and with a vertical component, the 3-D length grows by |d| / |d_xy|
    b3 = np.array([3.0, 1.0, 0.0])
    d = b3 - a
    expected = 0.2 * np.sqrt(2) * np.linalg.norm(d) / np.linalg.norm(d[:2])
    assert np.isclose(path_lengths(a, b3, [WALL]), expected)


def test_misses_beside_above_and_short_of_the_wall():
    pts = np.array(
        [
            [[5.0, -1.0, 1.0], [5.0, 1.0, 1.0]],  # beside the end
            [[2.0, -1.0, 3.5], [2.0, 1.0, 3.5]],  # above
            [[2.0, -1.0, 1.0], [2.0, -0.5, 1.0]],  # stops short
        ]
    )
    assert np.allclose(path_lengths(pts[:, 0], pts[:, 1], [WALL]), 0.0)


def test_segment_ending_inside_wall_counts_partial_length():
    a = np.array([2.0, -1.0, 1.0])
    b = np.array([2.0, 0.0, 1.0])  # ends on the centre line
    assert np.isclose(path_lengths(a, b, [WALL]), 0.1)


def test_vectorised_over_points_and_walls():
    walls = [WALL, Wall((0.0, 2.0), (4.0, 2.0), 0.3, 3.0)]
    a = np.tile([2.0, -1.0, 1.0], (5, 1))
    b = np.tile([2.0, 3.0, 1.0], (5, 1))
    per = path_lengths_per_wall(a, b, walls)
    assert per.shape == (5, 2)
    assert np.allclose(per, [[0.2, 0.3]] * 5)


def test_hit_test_with_inflated_walls():
    a = np.array([4.05, -1.0, 1.0])
    b = np.array([4.05, 1.0, 1.0])
    assert not segment_hits_walls(a, b, [WALL])
    assert segment_hits_walls(a, b, [WALL], inflate=0.1)
