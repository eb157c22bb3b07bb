"""Built-in analytic surfaces and markings: geometry is exact, masks land where drawn."""

from __future__ import annotations

import numpy as np
import pytest

from tactex.errors import ConfigError, InputError
from tactex.pointcloud.markings import marked_cloud, marking_mask, marking_names, mask_from_image
from tactex.pointcloud.shapes import SURFACES, get_surface, sine_panel_height

TOL_NORMAL = 1e-6


@pytest.mark.parametrize("name", sorted(SURFACES))
def test_samples_lie_on_surface_with_unit_normals(name: str) -> None:
    surf = get_surface(name)
    cloud = surf.sample(0.005)
    proj, normals = surf.project(cloud.points)
    np.testing.assert_allclose(proj, cloud.points, atol=1e-12)
    np.testing.assert_allclose(np.abs(np.sum(normals * cloud.normals, axis=1)), 1.0, atol=TOL_NORMAL)
    uv = surf.uv(cloud.points)
    assert uv.min() >= 0.0 and uv.max() <= 1.0


def test_sine_panel_matches_va_ufic_formula_and_normal() -> None:
    surf = get_surface("sine_panel")
    y = np.linspace(-0.255, 0.255, 11)
    z = sine_panel_height(np.zeros_like(y), y)
    np.testing.assert_allclose(z, 0.02 * np.sin(np.pi / 0.19 * (y + 0.255) + 0.44) + 0.02)
    dzdy = 0.02 * np.pi / 0.19 * np.cos(np.pi / 0.19 * (y + 0.255) + 0.44)
    expected = np.stack([np.zeros_like(y), -dzdy, np.ones_like(y)], axis=1)
    expected /= np.linalg.norm(expected, axis=1, keepdims=True)
    np.testing.assert_allclose(surf.normal(np.zeros_like(y), y), expected, atol=1e-8)


def test_cup_wall_normals_are_horizontal() -> None:
    cloud = get_surface("cup").sample(0.004)
    np.testing.assert_allclose(cloud.normals[:, 2], 0.0, atol=1e-12)
    np.testing.assert_allclose(np.hypot(cloud.points[:, 0], cloud.points[:, 1]), 0.04, atol=1e-12)


def test_marking_x_covers_both_diagonals_only() -> None:
    # The letter is drawn in the middle 70 % of its cell: u ∈ [0.29, 0.71], v ∈ [0.2, 0.8].
    on = np.array([[0.5, 0.5], [0.29, 0.2], [0.71, 0.2], [0.29, 0.8]])
    off = np.array([[0.5, 0.2], [0.2, 0.5], [0.05, 0.95], [0.9, 0.5]])
    assert marking_mask("X", on).all()
    assert not marking_mask("X", off).any()


def test_spots_are_three_one_centimetre_spots_on_the_plate() -> None:
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    cloud = marked_cloud(get_surface("plate"), "spots", 0.001)
    pts = cloud.points[cloud.target > 0]
    n, labels = connected_components(cKDTree(pts).sparse_distance_matrix(cKDTree(pts), 0.0015), directed=False)
    assert n == 3
    for k in range(n):
        spot = pts[labels == k, :2]
        assert 0.008 <= np.ptp(spot, axis=0).max() <= 0.011  # 1 cm across (to the 1 mm sampling)


def test_marked_cloud_target_is_the_mark_and_red() -> None:
    cloud = marked_cloud(get_surface("plate"), "RLI", 0.004)
    marked = cloud.target > 0
    assert 0 < marked.sum() < len(cloud)
    np.testing.assert_array_equal(cloud.colors[marked], np.tile([1.0, 0.0, 0.0], (marked.sum(), 1)))
    assert not np.any(cloud.colors[~marked][:, 0] >= 1.0)


def test_mask_from_image_orientation() -> None:
    img = np.ones((10, 10))
    img[:5, :] = 0.0  # top half dark → v > 0.5 marked
    uv = np.array([[0.5, 0.9], [0.5, 0.1]])
    np.testing.assert_array_equal(mask_from_image(img, uv), [True, False])


def test_unknown_names_list_the_valid_ones() -> None:
    with pytest.raises(ConfigError, match="plate"):
        get_surface("teapot")
    with pytest.raises(ConfigError, match=", ".join(marking_names())):
        marking_mask("smiley", np.zeros((1, 2)))
    with pytest.raises(InputError, match=r"\(N, 2\)"):
        marking_mask("X", np.zeros((3, 3)))
    with pytest.raises(ConfigError, match="spacing"):
        get_surface("plate").sample(-1.0)
