"""Surface estimation on analytically rendered depth images of known geometry (VA-UFIC eq. 14–16).

Depth images come from exact ray–plane / ray–sphere / ray–cylinder / ray–height-field
intersections through the D435i intrinsics (tactex.perception.synthetic), so every expected
number below is derived from the geometry, not from the code under test.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.integrate import quad

from tactex.perception import (
    CameraMount,
    D435I_DEPTH_640x480,
    SurfaceEstimator,
    SurfaceEstimatorConfig,
    frame_to_cloud,
    grid_normals,
    knn_normals,
    segment_pca,
    smallest_eigpairs,
)
from tactex.perception.synthetic import Cylinder, HeightField, Plane, Sphere, VaUficSinusoid, look_at, render_frame

K = D435I_DEPTH_640x480
PLANE_NORMAL_TOL_DEG = 1.0
PLANE_THETA_TOL_DEG = 1.0
SINUSOID_NORMAL_TOL_DEG = 2.0


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b) / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


def down_camera(x: float, y: float, height: float) -> np.ndarray:
    """Camera at (x, y, height) looking straight down (−z world); image 'up' is world +y."""
    return look_at([x, y, height], [x, y, 0.0], up=(0.0, 1.0, 0.0))


# ----------------------------------------------------------------------------- planes
@pytest.mark.parametrize(("tilt_deg", "azimuth_deg"), [(0.0, 0.0), (20.0, 0.0), (35.0, 120.0), (50.0, 250.0)])
def test_tilted_plane_normal_and_theta(tilt_deg: float, azimuth_deg: float) -> None:
    t, a = np.radians(tilt_deg), np.radians(azimuth_deg)
    n_true = np.array([np.sin(t) * np.cos(a), np.sin(t) * np.sin(a), np.cos(t)])
    frame, _ = render_frame(K, down_camera(0.0, 0.0, 0.3), [Plane((0.0, 0.0, 0.0), tuple(n_true))])
    est = SurfaceEstimator().estimate(frame)  # tool axis = optical axis (the paper's mount)
    assert est.valid, est.reason
    assert angle_deg(est.normal_world, n_true) < PLANE_NORMAL_TOL_DEG
    # θ between the tool axis (−z world) and the inward normal −n is the tilt.
    assert abs(np.degrees(est.theta_rad) - tilt_deg) < PLANE_THETA_TOL_DEG
    assert est.curvature < 1e-6  # eq. 16 vanishes on a plane
    # Camera-frame normal faces the camera and maps to the world one (eq. 22).
    assert est.normal_camera @ est.centroid_camera < 0
    np.testing.assert_allclose(frame.world_T_camera[:3, :3] @ est.normal_camera, est.normal_world, atol=1e-12)
    # The centroid lies on the plane; (e1, e2, n) is a right-handed orthonormal frame.
    assert abs(est.centroid_world @ n_true) < 1e-6  # float32 depth: ~1e-7 relative
    frame_mat = np.stack([est.e1_world, est.e2_world, est.normal_world], axis=1)
    np.testing.assert_allclose(frame_mat.T @ frame_mat, np.eye(3), atol=1e-9)
    assert np.linalg.det(frame_mat) == pytest.approx(1.0, abs=1e-9)


def test_theta_uses_the_tool_axis_with_an_offset_camera() -> None:
    # Camera 6 cm beside the tool, parallel to it (VA-UFIC mount); the tool is pitched 15° about
    # world x and the plane is tilted 25° about world x: θ is the 10° between tool and normal.
    tilt = np.radians(25.0)
    n_true = np.array([0.0, -np.sin(tilt), np.cos(tilt)])
    pitch = np.radians(15.0)
    rot = np.array([[1, 0, 0], [0, np.cos(pitch), -np.sin(pitch)], [0, np.sin(pitch), np.cos(pitch)]])
    world_T_tool = np.eye(4)
    world_T_tool[:3, :3] = rot @ np.diag([1.0, -1.0, -1.0])  # tool z points down, pitched
    world_T_tool[:3, 3] = [0.0, 0.0, 0.12]
    mount = CameraMount.parallel(offset_m=(0.06, 0.0, -0.10))
    frame, _ = render_frame(K, mount.world_T_camera(world_T_tool), [Plane((0.0, 0.0, 0.0), tuple(n_true))])
    est = SurfaceEstimator().estimate(frame, world_T_tool)
    assert est.valid, est.reason
    assert angle_deg(est.normal_world, n_true) < PLANE_NORMAL_TOL_DEG
    expected = angle_deg(world_T_tool[:3, 2], -n_true)
    assert expected == pytest.approx(10.0, abs=1e-9)
    assert abs(np.degrees(est.theta_rad) - expected) < PLANE_THETA_TOL_DEG
    # The segment is the one under the tool: its centroid is near the tool axis, not the camera axis.
    rel = est.centroid_world - world_T_tool[:3, 3]
    axis = world_T_tool[:3, 2]
    assert np.linalg.norm(rel - (rel @ axis) * axis) < 0.01


# ----------------------------------------------------------------------------- curvature, eq. 16
def cap_variances(R: float, a: float, kind: str) -> tuple[float, float, float]:
    """Exact variances (σx², σy², σz²) of points z = R − sqrt(R² − ρ²) over a uniform disc of radius a.

    kind "sphere": ρ² = x² + y²; with u = ρ² ~ U[0, a²]:
        E[√(R² − u)] = 2 (R³ − (R² − a²)^{3/2}) / (3a²),  E[R² − u] = R² − a²/2.
    kind "cylinder" (axis along x): ρ = y, whose marginal density on the disc is
        p(y) = 2√(a² − y²) / (π a²);  E[R² − y²] = R² − a²/4, E[√(R² − y²)] by quadrature.
    In both cases σx² = σy² = a²/4 (uniform disc) and the cross-covariances vanish by symmetry, so
    the eigenvalues of Σ are {a²/4, a²/4, σz²} and eq. 16 gives l_s = σz² / (a²/2 + σz²).
    """
    if kind == "sphere":
        e_root = 2.0 * (R**3 - (R**2 - a**2) ** 1.5) / (3.0 * a**2)
        e_sq = R**2 - a**2 / 2.0
    else:
        e_root = quad(lambda y: np.sqrt(R**2 - y**2) * 2.0 * np.sqrt(a**2 - y**2) / (np.pi * a**2), -a, a)[0]
        e_sq = R**2 - a**2 / 4.0
    return a**2 / 4.0, a**2 / 4.0, e_sq - e_root**2


def expected_ls(R: float, a: float, kind: str) -> float:
    vx, vy, vz = cap_variances(R, a, kind)
    return vz / (vx + vy + vz)


@pytest.mark.parametrize("kind", ["sphere", "cylinder"])
def test_segment_pca_matches_the_analytic_cap_covariance(kind: str) -> None:
    # Exact points on a fine uniform grid over the disc: PCA (eq. 16) vs the closed form.
    R, a = 0.08, 0.03
    g = np.linspace(-a, a, 801)
    x, y = np.meshgrid(g, g)
    inside = x**2 + y**2 <= a**2
    x, y = x[inside], y[inside]
    rho2 = x**2 + y**2 if kind == "sphere" else y**2
    pts = np.stack([x, y, R - np.sqrt(R**2 - rho2)], axis=1)
    pca = segment_pca(pts, viewpoint=np.array([0.0, 0.0, -1.0]))
    vx, vy, vz = cap_variances(R, a, kind)
    np.testing.assert_allclose(pca.eigenvalues, [vx, vy, vz], rtol=0.01)
    assert pca.curvature == pytest.approx(expected_ls(R, a, kind), rel=0.01)
    np.testing.assert_allclose(abs(pca.normal[2]), 1.0, atol=1e-9)


CURVATURE_REL_TOL = 0.10  # perspective sampling is not uniform over the disc (density ∝ 1/z²)


def _cap_frame(kind: str, R: float):
    # Top of the surface at z = 0, camera 0.25 m above it looking down the symmetry axis.
    if kind == "sphere":
        surf = Sphere((0.0, 0.0, -R), R)
    elif kind == "cylinder":
        surf = Cylinder((0.0, 0.0, -R), (1.0, 0.0, 0.0), R)
    else:
        surf = Plane((0.0, 0.0, 0.0), (0.0, 0.0, 1.0))
    frame, _ = render_frame(K, down_camera(0.0, 0.0, 0.25), [surf])
    return frame


@pytest.mark.parametrize(("kind", "R"), [("sphere", 0.05), ("sphere", 0.1), ("cylinder", 0.05), ("cylinder", 0.1)])
def test_estimated_curvature_matches_eq16_expectation(kind: str, R: float) -> None:
    cfg = SurfaceEstimatorConfig()
    est = SurfaceEstimator(cfg).estimate(_cap_frame(kind, R))
    assert est.valid, est.reason
    assert est.curvature == pytest.approx(expected_ls(R, cfg.roi_radius_m, kind), rel=CURVATURE_REL_TOL)
    assert angle_deg(est.normal_world, np.array([0.0, 0.0, 1.0])) < PLANE_NORMAL_TOL_DEG


def test_curvature_ordering() -> None:
    est = SurfaceEstimator()
    ls = {
        (kind, R): est.estimate(_cap_frame(kind, R)).curvature
        for kind, R in [("plane", 0.0), ("cylinder", 0.1), ("cylinder", 0.05), ("sphere", 0.1), ("sphere", 0.05)]
    }
    assert ls[("plane", 0.0)] < 1e-6
    # Smaller radius → larger l_s; a sphere bends in two directions → larger l_s than a cylinder.
    assert ls[("plane", 0.0)] < ls[("cylinder", 0.1)] < ls[("cylinder", 0.05)]
    assert ls[("cylinder", 0.1)] < ls[("sphere", 0.1)] < ls[("sphere", 0.05)]
    assert ls[("cylinder", 0.05)] < ls[("sphere", 0.05)]
    assert all(v <= 1.0 / 3.0 for v in ls.values())


# ----------------------------------------------------------------------------- region growing
def roof(slope: float = 1.0, top: float = 0.05) -> HeightField:
    """Two planes z = top − slope·|x| meeting at a ridge; slope 1 → the planes meet at 90°."""
    return HeightField(
        lambda x, y: top - slope * np.abs(x),
        lambda x, y: (-slope * np.sign(x), np.zeros_like(y)),
        z_guess=top,
    )


def test_region_growing_separates_two_planes_at_90_degrees() -> None:
    frame, _ = render_frame(K, down_camera(0.0, 0.0, 0.3), [roof()])
    est_obj = SurfaceEstimator()
    patch = est_obj.prepare(frame)
    pts_c, _, labels = est_obj.segment(patch)
    pts_w = pts_c @ frame.world_T_camera[:3, :3].T + frame.world_T_camera[:3, 3]
    far = np.abs(pts_w[:, 0]) > 0.01  # away from the ridge (normal windows straddle it there)
    left, right = far & (pts_w[:, 0] < 0), far & (pts_w[:, 0] > 0)
    lab_left, lab_right = labels[left], labels[right]
    assert (lab_left >= 0).mean() > 0.95 and (lab_right >= 0).mean() > 0.95
    # Each side is one segment, and the two sides never share one.
    assert np.unique(lab_left[lab_left >= 0]).size == 1
    assert np.unique(lab_right[lab_right >= 0]).size == 1
    assert lab_left[lab_left >= 0][0] != lab_right[lab_right >= 0][0]
    # Each segment's PCA normal is its plane's normal (45° either side of z).
    # z = top + x on the left (normal (−1, 0, 1)/√2), z = top − x on the right (normal (1, 0, 1)/√2).
    for side, n_true in ((left, np.array([-1.0, 0, 1.0])), (right, np.array([1.0, 0, 1.0]))):
        seg = labels == labels[side][labels[side] >= 0][0]
        pca = segment_pca(pts_w[seg], viewpoint=frame.world_T_camera[:3, 3])
        assert angle_deg(pca.normal, n_true) < PLANE_NORMAL_TOL_DEG
        assert pca.curvature < 1e-3


def test_segment_under_an_offset_tool_is_its_plane() -> None:
    frame, _ = render_frame(K, down_camera(0.0, 0.0, 0.3), [roof()])
    world_T_tool = np.eye(4)
    world_T_tool[:3, :3] = np.diag([1.0, -1.0, -1.0])
    world_T_tool[:3, 3] = [0.02, 0.0, 0.1]  # above the right-hand plane (x > 0)
    est = SurfaceEstimator().estimate(frame, world_T_tool)
    assert est.valid, est.reason
    assert angle_deg(est.normal_world, np.array([1.0, 0.0, 1.0])) < PLANE_NORMAL_TOL_DEG
    assert np.degrees(est.theta_rad) == pytest.approx(45.0, abs=PLANE_THETA_TOL_DEG)


# ----------------------------------------------------------------------------- VA-UFIC sinusoid
@pytest.mark.parametrize("y0", [-0.12, -0.05, 0.0, 0.04, 0.1, 0.17])
def test_va_ufic_sinusoid_normal(y0: float) -> None:
    surf = VaUficSinusoid()
    p0 = np.array([[0.05, y0, 0.0]])
    p0[0, 2] = surf.h(p0[:, 0], p0[:, 1])[0]
    n_true = surf.normal(p0)[0]
    frame, _ = render_frame(K, down_camera(0.05, y0, p0[0, 2] + 0.25), [surf])
    est = SurfaceEstimator().estimate(frame)
    assert est.valid, est.reason
    assert angle_deg(est.normal_world, n_true) < SINUSOID_NORMAL_TOL_DEG
    assert abs(np.degrees(est.theta_rad) - angle_deg(n_true, np.array([0.0, 0.0, 1.0]))) < SINUSOID_NORMAL_TOL_DEG


def test_va_ufic_sinusoid_with_aligned_tool_has_small_theta() -> None:
    surf = VaUficSinusoid()
    p0 = np.array([[0.0, 0.05, 0.0]])
    p0[0, 2] = surf.h(p0[:, 0], p0[:, 1])[0]
    n = surf.normal(p0)[0]
    world_T_camera = look_at(p0[0] + 0.25 * n, p0[0], up=(0.0, 1.0, 0.0))
    frame, _ = render_frame(K, world_T_camera, [surf])
    est = SurfaceEstimator().estimate(frame)
    assert est.valid, est.reason
    assert np.degrees(est.theta_rad) < SINUSOID_NORMAL_TOL_DEG


# ----------------------------------------------------------------------------- building blocks
def test_smallest_eigpairs_match_eigh(rng: np.random.Generator) -> None:
    a = rng.normal(size=(500, 3, 3))
    cov = a @ a.transpose(0, 2, 1)
    cov[:50] = np.diag([1.0, 0.5, 1e-7])  # plane-like, λ0 ≪ λ1
    lam0, vec, trace = smallest_eigpairs(cov)
    w, v = np.linalg.eigh(cov)
    np.testing.assert_allclose(lam0, w[:, 0], atol=1e-10 * w[:, 2].max())
    np.testing.assert_allclose(np.abs(np.einsum("ij,ij->i", vec, v[:, :, 0])), 1.0, atol=1e-8)
    np.testing.assert_allclose(trace, w.sum(axis=1), rtol=1e-12)
    # A repeated smallest eigenvalue has no defined direction: NaN, not a made-up normal.
    _, iso, _ = smallest_eigpairs(np.stack([np.eye(3), np.diag([1.0, 0.0, 0.0])]))
    assert np.isnan(iso).all()


def test_grid_and_knn_normals_agree_on_a_plane(rng: np.random.Generator) -> None:
    n_true = np.array([0.2, -0.3, 1.0]) / np.linalg.norm([0.2, -0.3, 1.0])
    frame, _ = render_frame(K, down_camera(0.0, 0.0, 0.4), [Plane((0.0, 0.0, 0.0), tuple(n_true))])
    from tactex.perception import deproject, depth_in_meters

    depth = depth_in_meters(frame.depth_m, K)
    h, w = 60, 80
    sub = depth[200:260, 280:360]
    dp = deproject(depth, K, bbox=(200, 260, 280, 360))
    grid = np.zeros((h, w, 3))
    grid[dp.rows - 200, dp.cols - 280] = dp.points
    g = grid_normals(grid, sub > 0, 2)
    k = knn_normals(dp.points, 12)
    n_cam = frame.world_T_camera[:3, :3].T @ n_true
    for field in (g, k):
        assert field.ok.all()
        np.testing.assert_allclose(field.normals @ n_cam, 1.0, atol=1e-6)  # and facing the camera
        assert np.nanmax(field.curvature) < 1e-8


def test_knn_neighbourhood_estimator_matches_grid_on_a_plane() -> None:
    n_true = np.array([0.0, np.sin(0.4), np.cos(0.4)])
    frame, _ = render_frame(K, down_camera(0.0, 0.0, 0.3), [Plane((0.0, 0.0, 0.0), tuple(n_true))])
    est = SurfaceEstimator(SurfaceEstimatorConfig(neighbourhood="knn")).estimate(frame)
    assert est.valid, est.reason
    assert angle_deg(est.normal_world, n_true) < PLANE_NORMAL_TOL_DEG


def test_synchronous_estimate_is_deterministic() -> None:
    frame, _ = render_frame(K, down_camera(0.0, 0.02, 0.27), [VaUficSinusoid()])
    est = SurfaceEstimator()
    a, b = est.estimate(frame), est.estimate(frame)
    np.testing.assert_array_equal(a.normal_world, b.normal_world)
    assert a.curvature == b.curvature and a.segment_size == b.segment_size


def test_region_growing_follows_pcl_rules() -> None:
    from tactex.perception import RegionGrowingParams, region_growing

    # A chain 0-1-2-3-4-5-6 (edges i, i+1). Points 0-2 and 4-6 are seeds (low curvature); point 3
    # has high curvature: it joins a region but does not let it grow, so the two sides stay apart.
    up = np.array([0.0, 0.0, 1.0])
    normals = np.tile(up, (7, 1))
    curvature = np.array([0.01, 0.01, 0.01, 0.2, 0.005, 0.005, 0.005])
    edges = (np.arange(6), np.arange(1, 7))
    labels = region_growing(normals, curvature, edges, RegionGrowingParams(10.0, 0.05, 1))
    assert labels[0] == labels[1] == labels[2] != labels[4] == labels[5] == labels[6]
    # Point 3 goes to the region PCL grows first: the one whose lowest seed curvature is smaller.
    assert labels[3] == labels[4]
    # With the curvature test off (threshold 1) everything is one region.
    assert np.unique(region_growing(normals, curvature, edges, RegionGrowingParams(10.0, 1.0, 1))).size == 1
    # A normal 30° off breaks the smoothness test (10°) but not a 40° one.
    tilted = normals.copy()
    tilted[4:] = [np.sin(np.radians(30)), 0.0, np.cos(np.radians(30))]
    flat_curv = np.full(7, 0.01)
    lab = region_growing(tilted, flat_curv, edges, RegionGrowingParams(10.0, 0.05, 1))
    assert lab[3] != lab[4]
    assert np.unique(region_growing(tilted, flat_curv, edges, RegionGrowingParams(40.0, 0.05, 1))).size == 1
    # Opposite normals are the same plane (|n_i·n_j|, as in PCL).
    flipped = normals.copy()
    flipped[::2] *= -1
    assert np.unique(region_growing(flipped, flat_curv, edges, RegionGrowingParams(10.0, 0.05, 1))).size == 1
    # Segments below min_cluster_size become noise; NaN normals never belong to a region.
    small = region_growing(tilted, flat_curv, edges, RegionGrowingParams(10.0, 0.05, 4))
    assert (small[:4] == 0).all() and (small[4:] == -1).all()
    nan_normals = normals.copy()
    nan_normals[2] = np.nan
    lab = region_growing(nan_normals, flat_curv, edges, RegionGrowingParams(10.0, 0.05, 1))
    assert lab[2] == -1 and lab[1] != lab[3]


NOISY_NORMAL_TOL_DEG = 1.0


def test_noisy_depth_still_gives_the_normal(rng: np.random.Generator) -> None:
    # 1 mm Gaussian depth noise (D435i-class at 0.3 m) and 10 % missing pixels on a 30° plane.
    n_true = np.array([np.sin(np.radians(30.0)), 0.0, np.cos(np.radians(30.0))])
    frame, _ = render_frame(K, down_camera(0.0, 0.0, 0.3), [Plane((0.0, 0.0, 0.0), tuple(n_true))])
    depth = frame.depth_m + rng.normal(0.0, 0.001, frame.depth_m.shape).astype(np.float32)
    depth[rng.random(depth.shape) < 0.1] = 0.0
    est = SurfaceEstimator().estimate(dataclasses.replace(frame, depth_m=depth))
    assert est.valid, est.reason
    assert angle_deg(est.normal_world, n_true) < NOISY_NORMAL_TOL_DEG
    assert abs(np.degrees(est.theta_rad) - 30.0) < NOISY_NORMAL_TOL_DEG


def test_cloud_in_camera_and_world_frames() -> None:
    frame, _ = render_frame(K, look_at([0.1, -0.05, 0.35], [0.0, 0.0, 0.0]), [Sphere((0.0, 0.0, 0.0), 0.1)])
    cam = frame_to_cloud(frame, in_world=False, stride=4)
    world = frame_to_cloud(frame, in_world=True, stride=4)
    rot, t = frame.world_T_camera[:3, :3], frame.world_T_camera[:3, 3]
    np.testing.assert_allclose(cam.points @ rot.T + t, world.points, atol=1e-12)
    # Every world point lies on the sphere (float32 depth → ~1e-7 relative).
    np.testing.assert_allclose(np.linalg.norm(world.points, axis=1), 0.1, atol=1e-6)
    # Camera-frame depth is the optical z of the point, i.e. the image value.
    assert np.all(cam.points[:, 2] > 0)
    assert cam.spacing == pytest.approx(4 * np.median(cam.points[:, 2]) / K.fx)
