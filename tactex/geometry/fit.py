"""Least-squares sphere-or-plane fit in conformal geometric algebra (TEC eq. 23–29).

A plane is a sphere of infinite radius, so one fit serves both: the dual primitive
X* = v0 e0 + v1 e1 + v2 e2 + v3 e3 + v∞ e∞ minimising Σ (P_i · X*)² over the conformal points P_i
is the eigenvector of the smallest eigenvalue of the 5×5 matrix B = Wᵀ W with the rows
w_i = (p_i, −1, −½|p_i|²) (eq. 24–25), because P · X* = p·v − v∞ − ½|p|² v0.

Two forms are given:

* :func:`cga_fit_vector` is eq. 24–26 literally, in the world frame, returning the dual
  primitive in pygafro's blade order [e0, e1, e2, e3, e∞]; tests check it against pygafro's
  ``Sphere``/``Plane``.
* :func:`fit_sphere_or_plane` is the one the explorer runs every step. It solves the same
  eigenproblem in a local frame (neighbourhood centred on its centroid and scaled to unit RMS
  radius) because the unit-norm eigenvector of eq. 24 is not translation invariant: in world
  coordinates a neighbourhood 0.5 m from the origin makes the e∞ column dominate and the fit
  ill-conditioned. It returns a :class:`SurfacePatch` with closed-form numpy projection
  (eq. 27), normal line (eq. 28) and tangent plane (eq. 29), verified in the tests against the
  pygafro expressions in :func:`gafro_project` and :func:`gafro_normal_line`.

Degenerate neighbourhoods never produce NaN: points on one line give a ``"line"`` patch
(projection onto the line, normal = the perpendicular from the line towards the query point, or
the perpendicular closest to a reference direction when the point lies on the line), a single
repeated point gives a ``"point"`` patch, and exactly coplanar points (including concyclic ones,
where every sphere through the circle fits equally well) give the PCA plane.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.linalg.lapack import dsyev as _dsyev

from tactex.errors import PYGAFRO_FIX, InputError, MissingDependencyError

__all__ = [
    "SurfacePatch",
    "cga_design_matrix",
    "cga_fit_vector",
    "fit_local",
    "fit_local_design",
    "fit_sphere_or_plane",
    "gafro_normal_line",
    "gafro_primitive",
    "gafro_project",
    "gafro_tangent_plane",
    "to_world",
]

#: Relative eigenvalue below which a neighbourhood counts as lower-dimensional (line/plane/circle).
DEGENERACY_RTOL = 1e-10
#: A fitted sphere larger than this many neighbourhood radii is treated as its limit, a plane.
MAX_RADIUS_RATIO = 1e6
#: Spheres smaller than this many neighbourhood radii must fit the neighbourhood better than its PCA
#: plane does (geometric residuals), or the plane is taken. On a sparse or ragged scan edge the
#: algebraic fit can return a small sphere that fits the points worse than a plane, with a normal at
#: the agent 60–120° off the surface (at a bowl's rim that tilts the tool onto the wall and the agent
#: sticks there); a genuine small sphere fits far better than any plane, however one-sided the
#: neighbourhood. Larger spheres are left alone: they are nearly planes over a neighbourhood.
CHECK_RADIUS_RATIO = 3.0

_Z = np.array([0.0, 0.0, 1.0])
_ZERO3 = np.zeros(3)


class SurfacePatch(NamedTuple):
    """A local primitive fitted to a neighbourhood.

    Attributes:
        kind: "sphere", "plane", "line" or "point".
        center: sphere centre, a point of the plane / line, or the point [m] (3,).
        radius: sphere radius [m]; ``inf`` for the other kinds.
        direction: plane unit normal, line unit direction, or zeros for a point (3,).
    """

    kind: str
    center: np.ndarray
    radius: float
    direction: np.ndarray

    def project(self, x: np.ndarray, reference_normal: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Closest point of the primitive to ``x`` and the unit surface normal there (eq. 27–28).

        The normal of a sphere points away from its centre and that of a plane along
        ``direction``; callers orient it. ``reference_normal`` breaks ties where the normal is
        undefined (a point on a line, a point at a sphere centre, a point patch).
        """
        ref = _Z if reference_normal is None else reference_normal
        if self.kind == "sphere":
            u = x - self.center
            nu = float(np.sqrt(u @ u))
            if nu < 1e-12 * max(self.radius, 1e-300):
                n = ref / np.linalg.norm(ref)
            else:
                n = u / nu
            return self.center + self.radius * n, n
        if self.kind == "plane":
            n = self.direction
            return x - ((x - self.center) @ n) * n, n
        if self.kind == "line":
            d = self.direction
            foot = self.center + ((x - self.center) @ d) * d
            return foot, _perpendicular(x - foot, d, ref)
        return self.center.copy(), _perpendicular(x - self.center, None, ref)


def _perpendicular(v: np.ndarray, d: np.ndarray | None, ref: np.ndarray) -> np.ndarray:
    """Unit vector along v (minus its d component); falls back to ref, then to any unit vector ⊥ d."""
    for cand in (v, ref, np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])):
        w = cand if d is None else cand - (cand @ d) * d
        nw = float(np.sqrt(w @ w))
        if nw > 1e-12 * max(1.0, float(np.sqrt(cand @ cand))):
            return w / nw
    return _Z.copy()  # unreachable: one of x/y axes is always ⊥-able to a unit d


def cga_design_matrix(points: np.ndarray, squared_norms: np.ndarray | None = None) -> np.ndarray:
    """Rows w_i = (p_i1, p_i2, p_i3, −1, −½|p_i|²) of eq. 25, shape (n, 5); ``squared_norms`` are
    the |p_i|² when the caller already has them."""
    p = np.asarray(points, dtype=np.float64)
    w = np.empty((p.shape[0], 5))
    w[:, :3] = p
    w[:, 3] = -1.0
    w[:, 4] = -0.5 * (np.einsum("ij,ij->i", p, p) if squared_norms is None else squared_norms)
    return w


def cga_fit_vector(points: np.ndarray) -> np.ndarray:
    """Eq. 24–26 in the world frame: the unit dual primitive [v0, v1, v2, v3, v∞] (pygafro blade
    order e0, e1, e2, e3, e∞) minimising Σ (P_i · X*)². v0 = 0 for a plane."""
    p = _check_points(points)
    w = cga_design_matrix(p)
    _, vecs = np.linalg.eigh(w.T @ w)
    v = vecs[:, 0]
    return np.array([v[4], v[0], v[1], v[2], v[3]])


def _check_points(points: np.ndarray) -> np.ndarray:
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or p.shape[0] < 1:
        raise InputError(f"neighbourhood points must have shape (n >= 1, 3), got {p.shape}")
    if not np.isfinite(p).all():
        raise InputError("neighbourhood points hold NaN/inf coordinates")
    return p


def fit_sphere_or_plane(points: np.ndarray, *, validate: bool = True) -> SurfacePatch:
    """Fit the sphere or plane of eq. 23–26 to a neighbourhood (n, 3) [m]; see the module doc.

    ``validate=False`` skips the shape/finiteness check (for rows of an already validated cloud).
    """
    p = _check_points(points) if validate else points
    mu = p.sum(axis=0) * (1.0 / p.shape[0])
    q = p - mu
    scale = float(np.sqrt(np.einsum("ij,ij->", q, q) / p.shape[0]))
    if scale == 0.0:
        return SurfacePatch("point", mu, np.inf, np.zeros(3))
    local = fit_local(q * (1.0 / scale))
    return to_world(local, mu, scale)


def to_world(local: SurfacePatch, origin: np.ndarray, scale: float) -> SurfacePatch:
    """Map a patch fitted in coordinates q = (p − origin) / scale back to world coordinates."""
    return SurfacePatch(local.kind, origin + scale * local.center, scale * local.radius, local.direction)


def fit_local(q: np.ndarray, q_sq: np.ndarray | None = None) -> SurfacePatch:
    """Eq. 24–26 on points q (n, 3) already centred near the data and scaled to about unit size.

    ``q_sq`` are the squared norms of the rows when the caller has them;
    :func:`fit_sphere_or_plane` wraps this for arbitrary world points.
    """
    return fit_local_design(cga_design_matrix(q, q_sq))


def fit_local_design(w: np.ndarray) -> SurfacePatch:
    """:func:`fit_local` from its design matrix w (n, 5), rows (q_i, −1, −½|q_i|²) of eq. 25.

    The per-step fast path: the explorer fills w in a preallocated buffer straight from its
    agent-centred offsets (scaled by the neighbourhood radius).
    """
    n = w.shape[0]
    evals, vecs, info = _dsyev(w.T.dot(w))  # the method skips np.dot's dispatch; same product
    if info != 0 or n < 5:
        return _degenerate_patch(np.ascontiguousarray(w[:, :3]))
    _, e1, _, _, e4 = evals.tolist()
    if e1 <= DEGENERACY_RTOL * e4:
        return _degenerate_patch(np.ascontiguousarray(w[:, :3]))
    v0x, v1x, v2x, vinf, v0 = vecs[:, 0].tolist()  # scalar algebra in Python floats: 5 numbers
    nv = (v0x * v0x + v1x * v1x + v2x * v2x) ** 0.5
    if abs(v0) * MAX_RADIUS_RATIO > nv:
        cx, cy, cz = v0x / v0, v1x / v0, v2x / v0
        r2 = cx * cx + cy * cy + cz * cz - 2.0 * vinf / v0
        if r2 > 0.0:
            if r2 < CHECK_RADIUS_RATIO * CHECK_RADIUS_RATIO:  # a small sphere must beat the PCA plane
                q = np.ascontiguousarray(w[:, :3])
                mu, evals, vecs = _pca(q)
                if not _sphere_residual(q, cx, cy, cz, r2**0.5) < float(evals[0]):
                    return SurfacePatch("plane", mu, np.inf, vecs[:, 0].copy())
            return SurfacePatch("sphere", np.array((cx, cy, cz)), r2**0.5, _ZERO3)
        # An imaginary sphere (r² < 0) fits only noise; the plane is the sane limit.
        return _pca_plane(np.ascontiguousarray(w[:, :3]))
    if nv == 0.0:
        return _pca_plane(np.ascontiguousarray(w[:, :3]))
    nx, ny, nz = v0x / nv, v1x / nv, v2x / nv
    off = vinf / nv
    return SurfacePatch("plane", np.array((off * nx, off * ny, off * nz)), np.inf, np.array((nx, ny, nz)))


def _sphere_residual(q: np.ndarray, cx: float, cy: float, cz: float, r: float) -> float:
    """Σ(|q_i − c| − r)²: the sphere's squared geometric residuals over the points q. The PCA plane's
    are the scatter's smallest eigenvalue, Σ((q_i − q̄)·n)² (see CHECK_RADIUS_RATIO)."""
    d = q - np.array((cx, cy, cz))
    res = np.sqrt(np.einsum("ij,ij->i", d, d)) - r
    return float(res.dot(res))


def _sphere_beats_plane(w: np.ndarray, cx: float, cy: float, cz: float, r: float) -> bool:
    """Whether the sphere (centre c, radius r) fits the neighbourhood q = w[:, :3] strictly better
    than its PCA plane (the verdict of :func:`fit_local_design`; the compiled step mirrors it)."""
    q = np.ascontiguousarray(w[:, :3])
    return _sphere_residual(q, cx, cy, cz, r) < float(_pca(q)[1][0])


def _pca(q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    mu = q.sum(axis=0) * (1.0 / q.shape[0])
    qc = q - mu
    evals, vecs = np.linalg.eigh(qc.T @ qc)
    return mu, evals, vecs


def _degenerate_patch(q: np.ndarray) -> SurfacePatch:
    """Collinear → line; a single point → point; otherwise (coplanar, concyclic, < 5 points) → PCA plane."""
    mu, evals, vecs = _pca(q)
    if evals[2] <= 1e-300:
        return SurfacePatch("point", mu, np.inf, np.zeros(3))
    if evals[1] <= DEGENERACY_RTOL * evals[2]:
        return SurfacePatch("line", mu, np.inf, vecs[:, 2].copy())
    return SurfacePatch("plane", mu, np.inf, vecs[:, 0].copy())


def _pca_plane(q: np.ndarray) -> SurfacePatch:
    mu, _, vecs = _pca(q)
    return SurfacePatch("plane", mu, np.inf, vecs[:, 0].copy())


# ---------------------------------------------------------------------------------------------
# pygafro forms (reference implementations of eq. 26–29; used by tests and by callers who want
# the CGA objects, never in the per-step loop)


def _gafro():
    try:
        import pygafro
    except ImportError as exc:  # pragma: no cover - pygafro is a core dependency
        raise MissingDependencyError("pygafro", "", "The CGA fit", fix=PYGAFRO_FIX) from exc
    return pygafro


def _gpoint(x: np.ndarray):
    g = _gafro()
    return g.Point(float(x[0]), float(x[1]), float(x[2]))


def gafro_primitive(patch: SurfacePatch):
    """The patch as a pygafro ``Sphere`` or ``Plane`` (eq. 26)."""
    g = _gafro()
    if patch.kind == "sphere":
        return g.Sphere(_gpoint(patch.center), float(patch.radius))
    if patch.kind == "plane":
        n = patch.direction
        t1 = _perpendicular(np.array([1.0, 0.0, 0.0]), n, np.array([0.0, 1.0, 0.0]))
        t2 = np.cross(n, t1)
        c = patch.center
        return g.Plane(_gpoint(c), _gpoint(c + t1), _gpoint(c + t2))
    raise InputError(f"a {patch.kind!r} patch has no sphere/plane form")


def gafro_project(patch: SurfacePatch, x: np.ndarray) -> np.ndarray:
    """Eq. 27 with pygafro: split[((P_a ∧ e∞) · X) · X], the point of the pair nearest to x."""
    g = _gafro()
    prim = gafro_primitive(patch)
    pair = ((_gpoint(x) ^ g.Ei(1.0)) | prim) | prim
    if patch.kind == "sphere":
        pp = g.PointPair(pair)
        vecs = [np.asarray(pt.vector()) for pt in (pp.getPoint1(), pp.getPoint2())]
        cands = [vec[1:4] / vec[0] for vec in vecs]
        return min(cands, key=lambda c: float(np.linalg.norm(c - x)))
    # A plane gives a flat point (e0∞, e1∞, e2∞, e3∞): x_k = coefficient of e_k∞ / coefficient of e0∞.
    fv = np.asarray(pair.vector())
    return fv[1:4] / fv[0]


def gafro_normal_line(patch: SurfacePatch, projected: np.ndarray):
    """Eq. 28: L = X* ∧ P'_a ∧ e∞, the line through P'_a normal to the primitive (pygafro)."""
    g = _gafro()
    prim = gafro_primitive(patch)
    return prim.dual() ^ _gpoint(projected) ^ g.Ei(1.0)


def gafro_tangent_plane(patch: SurfacePatch, projected: np.ndarray):
    """Eq. 29: E = L* ∧ P'_a ∧ e∞, the plane tangent to the primitive at P'_a (pygafro)."""
    g = _gafro()
    line = gafro_normal_line(patch, projected)
    return line.dual() ^ _gpoint(projected) ^ g.Ei(1.0)
