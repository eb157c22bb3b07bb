"""The normal under the tool (tactex.perception.axis_normal) against PCA's, on rendered geometry.

The wrist camera sits beside the tool, so on a cylinder the segment it sees around the tool axis is
lopsided and PCA's plane tilts towards it; the expected normals below come from the geometry (the
cylinder's normal where the tool axis meets it), not from the code under test.
"""

from __future__ import annotations

import numpy as np
import pytest

from tactex.perception import CameraMount, D435I_DEPTH_640x480, SurfaceEstimator, SurfaceEstimatorConfig, segment_pca
from tactex.perception.axis_normal import MIN_POINTS, normal_at_axis
from tactex.perception.synthetic import Cylinder, Plane, render_frame

K = D435I_DEPTH_640x480
RADIUS_M = 0.04  # the cup's wall


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1.0, 1.0))))


def tool_facing_cylinder(yaw_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """world_T_tool 1 cm off a vertical cylinder of RADIUS_M at the origin, the tool axis through the
    cylinder's axis from the −y side turned by ``yaw_deg`` about z; and the outward normal where it hits."""
    y = np.radians(yaw_deg)
    z_tool = np.array([np.sin(y), np.cos(y), 0.0])
    x_tool = np.array([np.cos(y), -np.sin(y), 0.0])
    world_T_tool = np.eye(4)
    world_T_tool[:3, :3] = np.column_stack([x_tool, np.cross(z_tool, x_tool), z_tool])
    world_T_tool[:3, 3] = -(RADIUS_M + 0.01) * z_tool
    return world_T_tool, -z_tool


@pytest.mark.parametrize("yaw_deg", [0.0, 25.0])
@pytest.mark.parametrize("offset_m", [(0.06, 0.0, -0.10), (0.0, 0.06, -0.10)])
def test_the_normal_under_the_tool_on_a_cylinder_seen_from_the_side(yaw_deg, offset_m) -> None:
    world_T_tool, n_true = tool_facing_cylinder(yaw_deg)
    frame, _ = render_frame(K, CameraMount.parallel(offset_m=offset_m).world_T_camera(world_T_tool),
                            [Cylinder((0.0, 0.0, 0.0), (0.0, 0.0, 1.0), RADIUS_M)])
    pca = SurfaceEstimator(SurfaceEstimatorConfig(normal_at_axis=False)).estimate(frame, world_T_tool)
    axis = SurfaceEstimator(SurfaceEstimatorConfig(normal_at_axis=True)).estimate(frame, world_T_tool)
    assert pca.valid and axis.valid, (pca.reason, axis.reason)
    assert angle_deg(pca.normal_world, n_true) > 3.0  # the bias this module removes
    assert angle_deg(axis.normal_world, n_true) < 1.0
    assert np.degrees(axis.theta_rad) < 1.0  # the tool presses straight into the wall
    assert axis.curvature == pytest.approx(pca.curvature)  # eq. 16 stays PCA's


def test_a_plane_keeps_its_normal() -> None:
    tilt = np.radians(30.0)
    n_true = np.array([0.0, -np.sin(tilt), np.cos(tilt)])
    world_T_tool = np.eye(4)
    world_T_tool[:3, :3] = np.diag([1.0, -1.0, -1.0])
    world_T_tool[:3, 3] = [0.0, 0.0, 0.05]
    frame, _ = render_frame(K, CameraMount.parallel(offset_m=(0.06, 0.0, -0.10)).world_T_camera(world_T_tool),
                            [Plane((0.0, 0.0, 0.0), tuple(n_true))])
    est = SurfaceEstimator(SurfaceEstimatorConfig(normal_at_axis=True)).estimate(frame, world_T_tool)
    assert est.valid, est.reason
    assert angle_deg(est.normal_world, n_true) < 0.5


def _sphere_cap(n: int, radius_m: float = 0.05) -> np.ndarray:
    """Points of a sphere's cap around +z (outward normal +z at the top), off to the +x side."""
    rng = np.random.default_rng(0)
    phi, az = rng.uniform(0.1, 0.4, n), rng.uniform(-0.6, 0.6, n)
    return radius_m * np.column_stack([np.sin(phi) * np.cos(az), np.sin(phi) * np.sin(az), np.cos(phi)])


def test_the_fit_finds_the_sphere_normal_where_the_axis_enters() -> None:
    pts = _sphere_cap(400)
    pca = segment_pca(pts, viewpoint=np.array([0.0, 0.0, 1.0]))
    origin, direction = np.array([0.0, 0.0, 0.2]), np.array([0.0, 0.0, -1.0])  # down the sphere's top
    # the axis meets the sphere outside the seen cap: the fit is clamped to the cap's edge, not extrapolated
    fitted = normal_at_axis(pts, pca, origin, direction)
    assert angle_deg(fitted, np.array([0.0, 0.0, 1.0])) < angle_deg(pca.normal, np.array([0.0, 0.0, 1.0]))
    # an axis through the cap's middle: the sphere's normal there
    mid = pts[np.argmin(np.linalg.norm(pts - pts.mean(axis=0), axis=1))]
    fitted = normal_at_axis(pts, pca, mid + 0.1 * mid / np.linalg.norm(mid), -mid / np.linalg.norm(mid))
    assert angle_deg(fitted, mid) < 1.0


def test_what_the_fit_cannot_use_keeps_pca_s_normal() -> None:
    pts = _sphere_cap(400)
    pca = segment_pca(pts, viewpoint=np.array([0.0, 0.0, 1.0]))
    down = np.array([0.0, 0.0, -1.0])
    few = pts[:MIN_POINTS - 1]
    pca_few = segment_pca(few, viewpoint=np.array([0.0, 0.0, 1.0]))
    assert normal_at_axis(few, pca_few, np.array([0.0, 0.0, 0.2]), down) is pca_few.normal
    along = pca.e1  # an axis in the surface's plane never crosses it
    assert normal_at_axis(pts, pca, pca.centroid + 0.1 * pca.normal, along) is pca.normal
