"""CGA sphere-or-plane fit (TEC eq. 23–29) against pygafro and known primitives."""

from __future__ import annotations

import numpy as np
import pygafro as g
import pytest

from tactex.errors import InputError
from tactex.geometry.fit import (
    SurfacePatch,
    cga_design_matrix,
    cga_fit_vector,
    fit_local,
    fit_local_design,
    fit_sphere_or_plane,
    gafro_normal_line,
    gafro_primitive,
    gafro_project,
    gafro_tangent_plane,
)

EXACT_TOL = 1e-6  # [m] / [-]: recovery from exact points (task acceptance)
GAFRO_TOL = 1e-9  # closed form vs pygafro expressions


def _rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def _sphere_cap(rng, center, radius, n=20, half_angle=0.3):
    """Points on a cap of the sphere (a neighbourhood sees a small cap, not the whole sphere)."""
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    t1 = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(axis, t1)
    th = rng.uniform(0, half_angle, n)
    ph = rng.uniform(0, 2 * np.pi, n)
    d = np.cos(th)[:, None] * axis + np.sin(th)[:, None] * (np.cos(ph)[:, None] * t1 + np.sin(ph)[:, None] * t2)
    return center + radius * d, axis


def _plane_patch(rng, n=20, half=0.006):
    rot = _rotation(rng)
    origin = rng.uniform(-0.5, 0.5, 3)
    uv = rng.uniform(-half, half, (n, 2))
    pts = origin + uv[:, :1] * rot[:, 0] + uv[:, 1:] * rot[:, 1]
    return pts, origin, rot[:, 2]


def test_design_matrix_rows_give_the_conformal_inner_product(rng):
    """w_i · (v, v∞, v0) = P_i · X* with pygafro's inner product (eq. 24–25)."""
    pts = rng.uniform(-0.3, 0.3, (6, 3))
    x_dual = g.Sphere(g.Point(0.1, -0.2, 0.05), 0.07).dual()
    dv = np.asarray(x_dual.vector())  # [e0, e1, e2, e3, e∞]
    w = cga_design_matrix(pts)
    ours = w @ np.array([dv[1], dv[2], dv[3], dv[4], dv[0]])
    theirs = [np.asarray((g.Point(*p) | x_dual).vector())[0] for p in pts]
    np.testing.assert_allclose(ours, theirs, atol=GAFRO_TOL)


def test_eigen_formulation_matches_pygafro_sphere(rng):
    center, radius = np.array([0.45, -0.1, 0.2]), 0.04
    pts, _ = _sphere_cap(rng, center, radius, half_angle=1.0)
    v = cga_fit_vector(pts)
    ref = np.asarray(g.Sphere(g.Point(*center), radius).dual().vector())
    np.testing.assert_allclose(v / v[0], ref / ref[0], atol=EXACT_TOL)
    for p in pts:  # every point lies on the fitted primitive: P · X* = 0 (eq. 23)
        assert abs(np.asarray((g.Point(*p) | g.Sphere(g.Point(*center), radius).dual()).vector())[0]) < 1e-12


def test_eigen_formulation_gives_a_plane_with_v0_zero(rng):
    pts, origin, normal = _plane_patch(rng, half=0.05)
    v = cga_fit_vector(pts)
    assert abs(v[0]) < EXACT_TOL * np.linalg.norm(v[1:4])
    prim = gafro_primitive(SurfacePatch("plane", origin, np.inf, normal))
    ref = np.asarray(prim.dual().vector())  # a plane's dual has no e0: [e1, e2, e3, e∞]
    np.testing.assert_allclose(v[1:] / v[1], ref / ref[0], atol=EXACT_TOL)


@pytest.mark.parametrize("seed", range(5))
def test_fit_recovers_a_known_sphere(seed):
    rng = np.random.default_rng(seed)
    center = rng.uniform(-0.5, 0.5, 3)
    radius = rng.uniform(0.01, 0.2)
    pts, _ = _sphere_cap(rng, center, radius, half_angle=0.006 / radius * 3)
    patch = fit_sphere_or_plane(pts)
    assert patch.kind == "sphere"
    np.testing.assert_allclose(patch.center, center, atol=EXACT_TOL)
    assert abs(patch.radius - radius) < EXACT_TOL


@pytest.mark.parametrize("seed", range(5))
def test_fit_recovers_a_known_plane(seed):
    rng = np.random.default_rng(seed)
    pts, origin, normal = _plane_patch(rng)
    patch = fit_sphere_or_plane(pts)
    assert patch.kind == "plane"
    assert 1 - abs(patch.direction @ normal) < EXACT_TOL
    assert abs((patch.center - origin) @ normal) < EXACT_TOL


def test_fit_degrades_gracefully_with_noise():
    """Surface error of the projected agent grows with the noise, stays a few σ, never NaN."""
    rng = np.random.default_rng(7)
    center, radius = np.array([0.3, 0.2, 0.1]), 0.05
    errors = []
    for sigma in (0.0, 1e-5, 1e-4, 3e-4):
        worst = 0.0
        for _ in range(30):
            pts, axis = _sphere_cap(rng, center, radius, n=20, half_angle=0.12)
            pts = pts + rng.normal(scale=sigma, size=pts.shape)
            x = center + (radius + 0.001) * axis
            p, n = fit_sphere_or_plane(pts).project(x)
            assert np.all(np.isfinite(p)) and np.all(np.isfinite(n))
            surf_err = abs(np.linalg.norm(p - center) - radius)
            worst = max(worst, surf_err)
        errors.append(worst)
    assert errors[0] < 1e-9
    # a few σ off the surface at most (σ = 0.3 mm is a tenth of a voxel)
    for sigma, err in zip((1e-5, 1e-4, 3e-4), errors[1:], strict=True):
        assert err < 5 * sigma, (sigma, err)


@pytest.mark.parametrize("kind", ["sphere", "plane"])
def test_projection_normal_line_and_tangent_plane_match_pygafro(kind, rng):
    if kind == "sphere":
        center, radius = np.array([0.2, 0.1, 0.3]), 0.03
        pts, axis = _sphere_cap(rng, center, radius, half_angle=0.5)
        x = center + 0.035 * axis + 0.002 * rng.normal(size=3)
    else:
        pts, origin, normal = _plane_patch(rng)
        x = origin + 0.004 * normal + 0.002 * rng.normal(size=3)
    patch = fit_sphere_or_plane(pts)
    p, n = patch.project(x)
    np.testing.assert_allclose(p, gafro_project(patch, x), atol=GAFRO_TOL)  # eq. 27
    line = gafro_normal_line(patch, p)  # eq. 28: the line holds P' + t n
    for t in (0.01, -0.02):
        assert np.abs(np.asarray((g.Point(*(p + t * n)) ^ line).vector())).max() < GAFRO_TOL
    tu = np.cross(n, [1.0, 0.0, 0.0])
    tu /= np.linalg.norm(tu)
    plane = gafro_tangent_plane(patch, p)  # eq. 29: the plane holds P' + t u, not P' + t n
    assert np.abs(np.asarray((g.Point(*(p + 0.01 * tu)) ^ plane).vector())).max() < GAFRO_TOL
    assert np.abs(np.asarray((g.Point(*(p + 0.01 * n)) ^ plane).vector())).max() > 1e-4


@pytest.mark.parametrize("seed", range(3))
def test_projected_point_lies_on_the_surface_in_any_orientation(seed):
    """Orientation independence: the same cap rotated anywhere (incl. vertical) fits the same."""
    rng = np.random.default_rng(seed)
    center, radius = np.zeros(3), 0.04
    pts, axis = _sphere_cap(rng, center, radius, half_angle=0.2)
    x = 1.03 * radius * axis
    p0, n0 = fit_sphere_or_plane(pts).project(x)
    for rot in (_rotation(rng), np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])):
        off = rng.uniform(-0.4, 0.4, 3)
        p, n = fit_sphere_or_plane(pts @ rot.T + off).project(rot @ x + off)
        np.testing.assert_allclose(p, rot @ p0 + off, atol=EXACT_TOL)
        np.testing.assert_allclose(n, rot @ n0, atol=EXACT_TOL)
        assert abs(np.linalg.norm(p - off) - radius) < EXACT_TOL


def test_collinear_neighbourhood_falls_back_to_a_line():
    pts = np.c_[np.linspace(0, 0.01, 12), np.zeros(12), np.zeros(12)] + [0.3, 0.1, 0.0]
    patch = fit_sphere_or_plane(pts)
    assert patch.kind == "line"
    p, n = patch.project(np.array([0.305, 0.1, 0.002]))
    np.testing.assert_allclose(p, [0.305, 0.1, 0.0], atol=1e-12)
    np.testing.assert_allclose(n, [0.0, 0.0, 1.0], atol=1e-12)
    # on the line itself the normal is undefined: the reference direction (default +z) is used
    p, n = patch.project(np.array([0.304, 0.1, 0.0]))
    assert np.all(np.isfinite(p)) and abs(n @ [1, 0, 0]) < 1e-12 and abs(np.linalg.norm(n) - 1) < 1e-12
    p, n = patch.project(np.array([0.304, 0.1, 0.0]), reference_normal=np.array([1.0, 0.0, 0.0]))
    assert np.all(np.isfinite(n)) and abs(n @ [1, 0, 0]) < 1e-12  # a reference along the line is skipped


def test_concyclic_or_few_points_fall_back_to_the_plane():
    th = np.linspace(0, 2 * np.pi, 9)[:-1]
    circle = np.c_[0.01 * np.cos(th), 0.01 * np.sin(th), np.full(8, 0.2)]
    patch = fit_sphere_or_plane(circle)  # every sphere through the circle fits: the plane is chosen
    assert patch.kind == "plane" and abs(abs(patch.direction[2]) - 1) < 1e-12
    tri = np.array([[0.0, 0, 0], [0.01, 0, 0], [0, 0.01, 0]])
    assert fit_sphere_or_plane(tri).kind == "plane"
    point = fit_sphere_or_plane(np.tile([0.1, 0.2, 0.3], (5, 1)))
    assert point.kind == "point"
    p, n = point.project(np.array([0.1, 0.2, 0.4]))
    np.testing.assert_allclose(p, [0.1, 0.2, 0.3])
    np.testing.assert_allclose(n, [0, 0, 1.0])


def _same_patch(a: SurfacePatch, b: SurfacePatch) -> bool:
    return (
        a.kind == b.kind
        and np.array_equal(a.center, b.center)
        and a.radius == b.radius
        and np.array_equal(a.direction, b.direction)
    )


def test_fit_local_design_equals_fit_local_bit_for_bit(rng):
    """The explorer's entry (design rows in a strided buffer) gives exactly fit_local's patch,
    on spheres, planes and the degenerate neighbourhoods (line, concyclic, point)."""
    cap, _ = _sphere_cap(rng, np.array([0.1, -0.2, 0.3]), 0.05)
    plane, _, _ = _plane_patch(rng)
    line = np.c_[np.linspace(0, 0.01, 12), np.zeros(12), np.zeros(12)]
    th = np.linspace(0, 2 * np.pi, 9)[:-1]
    circle = np.c_[np.cos(th), np.sin(th), np.zeros(8)]
    kinds = []
    for pts in (cap, plane, line, circle, np.tile([0.1, 0.2, 0.3], (6, 1))):
        q = (pts - pts.mean(axis=0)) * 37.0
        q_sq = np.einsum("ij,ij->i", q, q)
        buf = np.full((q.shape[0], 7), np.nan)[:, 1:6]  # not contiguous, like a column slice
        buf[:, :3] = q
        buf[:, 3] = -1.0
        buf[:, 4] = -0.5 * q_sq
        ref = fit_local(q, q_sq)
        assert _same_patch(fit_local_design(buf), ref)
        assert _same_patch(fit_local(q), ref)
        kinds.append(ref.kind)
    assert kinds == ["sphere", "plane", "line", "plane", "point"]


@pytest.mark.parametrize(
    "bad, match",
    [
        (np.zeros((0, 3)), r"\(n >= 1, 3\)"),
        (np.zeros((5, 2)), r"\(5, 2\)"),
        (np.array([[0.0, 0.0, np.nan]] * 6), "NaN"),
    ],
)
def test_fit_rejects_bad_points(bad, match):
    with pytest.raises(InputError, match=match):
        fit_sphere_or_plane(bad)
    with pytest.raises(InputError, match=match):
        cga_fit_vector(bad)


def test_gafro_primitive_refuses_a_line_patch():
    with pytest.raises(InputError, match="line"):
        gafro_primitive(SurfacePatch("line", np.zeros(3), np.inf, np.array([1.0, 0, 0])))


#: 20 neighbours [mm] around the agent (at the origin) near the ragged top edge of a simulated bowl
#: capture: sparse (3.3 mm) points on a steep wall. Three steps of such fits turned the agent's normal
#: over; it got stuck at the rim and the tool, tilted onto the wall, pressed 45 N.
RAGGED_EDGE_MM = np.array([
    [-1.07, -1.11, 0.64], [2.01, -0.94, -0.72], [1.87, 1.73, 1.84], [-0.91, 2.32, -2.59], [-0.94, -3.82, -1.84],
    [-4.14, -1.3, 2.09], [2.15, -3.65, -3.2], [4.95, 1.9, 0.57], [5.11, -0.78, -2.0], [-4.03, -4.0, -0.39],
    [5.26, -3.49, -4.5], [-0.82, -6.55, -4.25], [-3.92, -6.73, -2.77], [8.03, 2.05, -0.54], [8.2, -0.63, -3.13],
    [2.28, -6.39, -5.62], [-6.83, -3.35, -5.65], [-7.01, -6.92, -1.16], [8.36, -3.35, -5.63], [5.4, -6.24, -6.93],
])


def _pca_normal(q: np.ndarray) -> np.ndarray:
    qc = q - q.mean(axis=0)
    return np.linalg.eigh(qc.T @ qc)[1][:, 0]


def test_a_small_sphere_no_better_than_a_plane_gives_way_to_the_plane(monkeypatch):
    """On a ragged scan edge the algebraic fit returns a sphere smaller than the neighbourhood that
    fits the points worse than a plane, with a normal at the agent far off the surface; the fit then
    takes the PCA plane."""
    import tactex.geometry.fit as fit_mod

    q = RAGGED_EDGE_MM / np.sqrt((RAGGED_EDGE_MM**2).sum(axis=1).max())  # scaled as the explorer does
    n_pca = _pca_normal(q)
    with monkeypatch.context() as m:
        m.setattr(fit_mod, "CHECK_RADIUS_RATIO", 0.0)  # the check off: the raw algebraic fit
        raw = fit_local(q)
    assert raw.kind == "sphere" and raw.radius < 1.0
    n_raw = -raw.center / np.linalg.norm(raw.center)  # the sphere's normal at the agent
    assert abs(n_raw @ n_pca) < 0.5  # over 60° off the surface
    sphere_ss = float(np.sum((np.linalg.norm(q - raw.center, axis=1) - raw.radius) ** 2))
    qc = q - q.mean(axis=0)
    assert sphere_ss > float(np.sum((qc @ n_pca) ** 2))  # and a worse fit than the plane
    patch = fit_local(q)
    assert patch.kind == "plane" and abs(patch.direction @ n_pca) == pytest.approx(1.0)


@pytest.mark.parametrize("side", ["full", "half", "quarter"])
@pytest.mark.parametrize("radius", [0.6, 0.8, 1.2])
def test_a_genuinely_small_sphere_is_kept_however_one_sided(rng, side, radius):
    """Caps of spheres of 0.6–1.2 neighbourhood radii (a bunny's ear at 3 mm voxels), with the agent
    at the pole and its neighbours all around it, on one side, or in one quadrant (a scan edge): the
    sphere fits far better than any plane and is kept, recovered exactly."""
    import tactex.geometry.fit as fit_mod

    centre = np.array([0.0, 0.0, -radius])
    d = rng.normal(size=(20000, 3))
    pts = centre + radius * d / np.linalg.norm(d, axis=1, keepdims=True)
    keep = np.linalg.norm(pts, axis=1) <= 1.0  # within one neighbourhood radius of the agent at the pole
    if side in ("half", "quarter"):
        keep &= pts[:, 0] >= 0.0
    if side == "quarter":
        keep &= pts[:, 1] >= 0.0
    pts = pts[keep][rng.choice(int(keep.sum()), 20, replace=False)]
    scale = np.linalg.norm(pts, axis=1).max()  # the explorer's scaling: the farthest neighbour at 1
    assert radius / scale < fit_mod.CHECK_RADIUS_RATIO  # the check applies
    patch = fit_local(pts / scale)
    assert patch.kind == "sphere"
    np.testing.assert_allclose(patch.center * scale, centre, atol=EXACT_TOL)
    assert patch.radius * scale == pytest.approx(radius, abs=EXACT_TOL)
