"""The explorer's walking step compiled with numba (the optional ``fast`` extra): the compiled step.

:class:`~tactex.ergodic.explorer.HedacExplorer` runs one exploration step as about a hundred
small numpy calls (20 neighbours, a 5 × 5 and a 10 × 10 system, a ~200-row projection): their
dispatch, not their arithmetic, is most of its cost. This module does the same operations in
compiled functions, in the same order: the neighbourhood, the sphere/plane fit (eq. 23–26), the
projection (eq. 27) and tangent basis, the footprint φ (eq. 30–31) and coverage (eq. 3), the
source (eq. 1–2) and one step of spectral diffusion (eq. 19), the weighted cubic (eq. 32–33),
the slope of the raw source, the scan-edge rule (the agent brakes its outward motion there), the
agent (eq. 6, Table II limits), the landing on the fitted patch and the off-cloud and
step-length limits. The numpy step stays the reference: the tests check, state by state, that
both give the same step to round-off.

Rare cases are not compiled; the compiled step returns a status and leaves every piece of state as
it found it, and the explorer runs the numpy step instead:

* ``DEGENERATE``: the neighbourhood is a line, a point, a circle or an imaginary sphere (the
  numpy fit's special patches), a small sphere fits no better than the neighbourhood's plane
  (:data:`tactex.geometry.fit.CHECK_RADIUS_RATIO`), or the agent sits at the sphere's centre;
* ``EDGE_GAP``: the agent is at a scan edge whose points have a link across a scan hole (the hop
  planner of :mod:`.bridges` decides);
* ``FLAT``: the gradient vanishes or the cubic's system is singular (a random heading is drawn).

Compilation takes seconds, once: numba caches the machine code (its own ``__pycache__`` files,
like Python's bytecode cache: beside this file when its folder is writable, else in a per-user
folder) so later processes load it quickly. The compiled step agrees with the numpy one to
round-off with the default 20 neighbours; with far fewer (n_neighbors_fit ≲ 12) the 10-term cubic
is ill-conditioned and the two summation orders differ visibly. Without numba (:func:`available`
is False) the explorer uses numpy alone.
"""

from __future__ import annotations

import importlib.util

import numpy as np

from tactex.ergodic.gradient import PLANE_PIVOT_RTOL, RIDGE_RTOL
from tactex.ergodic.source import update_source
from tactex.geometry.fit import CHECK_RADIUS_RATIO, DEGENERACY_RTOL, MAX_RADIUS_RATIO

__all__ = ["DEGENERATE", "EDGE_GAP", "FLAT", "HELPERS", "OK", "OUT_SIZE", "available", "compiled_walk_step", "disable",
           "params"]

#: Statuses of the compiled step (:func:`_walk_step`).
OK, DEGENERATE, EDGE_GAP, FLAT = 0, 1, 2, 3
#: Length of the step's ``out``: x_new (3), velocity (3), normal (3), t_u (3), t_v (3),
#: agent velocity (3), step length, nearest point, coverage sum.
OUT_SIZE = 21


# Positions in the step's parameter array (module constants: numba folds them into the code).
_R_A2, _EPS2, _SOURCE_W, _A_DT, _V_MAX, _DT, _STEP_MAX, _OFF2, _OFF, _EDGE, _NORM_TARGET, _ORDER = range(12)
# The fits' tolerances travel in the array too: numba would bake imported constants into its cached
# machine code, and it renews that cache only when this file changes, not when fit.py or gradient.py do.
_DEGENERACY, _MAX_RADIUS, _RIDGE, _PIVOT = range(12, 16)
_BRAKE = 16
_CHECK_RADIUS = 17
_N_PRM = 18


def params(*, agent_radius_m: float, eps2: float, source_weight: float, max_acceleration: float,
           max_velocity: float, max_step_m: float, dt: float, max_off_m: float, edge_offset: float,
           normalize_by_target: bool, order: int, edge_braking: bool = True) -> np.ndarray:
    """The compiled step's parameter array, in SI units: footprint radius [m] and the footprint's ε² [1/m²], weight
    of the raw source's slope, the agent's limits [m/s², m/s], the longest step [m] and the step
    duration [s], farthest distance from the nearest cloud point [m], the scan-edge centroid
    threshold [neighbourhood radii], the coverage normalisation (True = over the target's support)
    the agent's order (1 or 2) and whether it brakes at scan edges (HedacConfig.edge_braking); the
    fits' tolerances are added from their modules."""
    prm = np.empty(_N_PRM)
    prm[_R_A2] = agent_radius_m**2
    prm[_EPS2] = eps2
    prm[_SOURCE_W] = source_weight
    prm[_A_DT] = max_acceleration * dt
    prm[_V_MAX] = max_velocity
    prm[_DT] = dt
    prm[_STEP_MAX] = max_step_m
    prm[_OFF2] = max_off_m**2
    prm[_OFF] = max_off_m
    prm[_EDGE] = edge_offset
    prm[_NORM_TARGET] = 1.0 if normalize_by_target else 0.0
    prm[_ORDER] = float(order)
    prm[_DEGENERACY] = DEGENERACY_RTOL
    prm[_MAX_RADIUS] = MAX_RADIUS_RATIO
    prm[_RIDGE] = RIDGE_RTOL
    prm[_PIVOT] = PLANE_PIVOT_RTOL
    prm[_BRAKE] = 1.0 if edge_braking else 0.0
    prm[_CHECK_RADIUS] = CHECK_RADIUS_RATIO
    return prm


# Float rules shared with the numpy step (explorer.py, agents.py call these Python forms; the
# compiled step calls their compiled forms): they live in this file because numba renews its cache
# only when the cached step's own file changes.
def project_floats(kind, c0, c1, c2, rad, pn0, pn1, pn2, x0, x1, x2, r0, r1, r2):
    """Closest point of a sphere (kind 0: centre c, radius rad) or plane (kind 1: point c, unit
    normal pn) to x and the normal there, oriented along r; ok = False at a sphere's centre."""
    if kind == 0:
        ux, uy, uz = x0 - c0, x1 - c1, x2 - c2
        nu = (ux * ux + uy * uy + uz * uz) ** 0.5
        if nu > 1e-12 * rad:
            sgn = 1.0 / nu if ux * r0 + uy * r1 + uz * r2 >= 0.0 else -1.0 / nu
            k = rad / nu
            return True, c0 + k * ux, c1 + k * uy, c2 + k * uz, ux * sgn, uy * sgn, uz * sgn
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    h = (x0 - c0) * pn0 + (x1 - c1) * pn1 + (x2 - c2) * pn2
    sgn = 1.0 if pn0 * r0 + pn1 * r1 + pn2 * r2 >= 0.0 else -1.0
    return True, x0 - h * pn0, x1 - h * pn1, x2 - h * pn2, sgn * pn0, sgn * pn1, sgn * pn2


def tangent_floats(n0, n1, n2):
    """Orthonormal tangent basis (t_u, t_v) of the unit normal n with (t_u, t_v, n) right-handed:
    t_u is e_x (e_y when n is near e_x) with its n component removed, t_v = n × t_u."""
    if abs(n0) < 0.9:
        t0, t1, t2 = 1.0 - n0 * n0, -n0 * n1, -n0 * n2
    else:
        t0, t1, t2 = -n1 * n0, 1.0 - n1 * n1, -n1 * n2
    it = 1.0 / (t0 * t0 + t1 * t1 + t2 * t2) ** 0.5
    t0, t1, t2 = t0 * it, t1 * it, t2 * it
    return t0, t1, t2, n1 * t2 - n2 * t1, n2 * t0 - n0 * t2, n0 * t1 - n1 * t0


def plane_slope(a00, a01, a02, a11, a12, a22, b0, b1, b2, pivot_rtol):
    """Slope (c_u, c_v) of the weighted plane c_0 + c_u u + c_v v with normal matrix a[:3, :3] and
    right-hand side (b0, b1, b2), as (ok, c_u, c_v); ok is False when the block is not positive
    definite (collinear points: a pivot below pivot_rtol of its diagonal entry). A 3×3 Cholesky in
    floats: a LAPACK call costs more than the arithmetic at this size."""
    if a00 <= 0.0:
        return False, 0.0, 0.0
    l00 = a00**0.5
    l10, l20 = a01 / l00, a02 / l00
    p11 = a11 - l10 * l10
    if p11 <= pivot_rtol * a11:
        return False, 0.0, 0.0
    l11 = p11**0.5
    l21 = (a12 - l20 * l10) / l11
    p22 = a22 - l20 * l20 - l21 * l21
    if p22 <= pivot_rtol * a22:
        return False, 0.0, 0.0
    l22 = p22**0.5
    y0 = b0 / l00
    y1 = (b1 - l10 * y0) / l11
    c_v = (b2 - l20 * y0 - l21 * y1) / l22 / l22
    c_u = (y1 - l21 * c_v) / l11
    return True, c_u, c_v


TRANSPORT_CONE = 1e-3
"""Sine of the angle between a velocity and the new normal below which transport shrinks it."""


def transported_floats(v0, v1, v2, n0, n1, n2):
    """agents.transport on float triples: v carried to the plane ⊥ the unit normal n, its length kept.

    Where v lies within TRANSPORT_CONE (a sine) of n, its tangential remainder is mostly round-off
    and has no direction of its own: it is projected again (exactly, also for an n off unit length)
    and scaled up by at most 1 / TRANSPORT_CONE, not to full length. So the result is tangent, never
    longer than v, and continuous in v and n (it fades to 0 as v → ±n). Outside the cone the
    arithmetic is the plain projection and rescaling. A zero n leaves v as it is.
    """
    vn = v0 * n0 + v1 * n1 + v2 * n2
    t0, t1, t2 = v0 - vn * n0, v1 - vn * n1, v2 - vn * n2
    tt = t0 * t0 + t1 * t1 + t2 * t2
    vv = v0 * v0 + v1 * v1 + v2 * v2
    if tt > 1e-300 and tt >= TRANSPORT_CONE * TRANSPORT_CONE * vv:
        k = (vv / tt) ** 0.5
        return t0 * k, t1 * k, t2 * k
    nn = n0 * n0 + n1 * n1 + n2 * n2
    if not nn > 1e-300:
        return v0, v1, v2
    # v (almost) along n: remove the normal part exactly, twice (the first pass leaves round-off)
    vn = (v0 * n0 + v1 * n1 + v2 * n2) / nn
    t0, t1, t2 = v0 - vn * n0, v1 - vn * n1, v2 - vn * n2
    tn = (t0 * n0 + t1 * n1 + t2 * n2) / nn
    t0, t1, t2 = t0 - tn * n0, t1 - tn * n1, t2 - tn * n2
    tt = t0 * t0 + t1 * t1 + t2 * t2
    if not (tt > 1e-300 and vv > 1e-300):
        return 0.0 * t0, 0.0 * t1, 0.0 * t2
    k = (vv / tt) ** 0.5
    if k > 1.0 / TRANSPORT_CONE:
        k = 1.0 / TRANSPORT_CONE
    return t0 * k, t1 * k, t2 * k


def braked_direction(e0, e1, e2, i0, i1, i2, v_out, a_dt):
    """The unit acceleration direction e at a scan edge with the unit inward tangent i, for an
    outward speed v_out [m/s] and one step's change a_dt [m/s]: its inward share is at least
    b = min(1, v_out / a_dt) (e is kept if it already turns inward that much), the rest √(1 − b²)
    along the edge in e's sense (see SecondOrderAgent.edge_direction)."""
    if v_out <= 0.0:
        return e0, e1, e2
    b = min(1.0, v_out / a_dt)
    di = e0 * i0 + e1 * i1 + e2 * i2
    if di >= b:
        return e0, e1, e2
    p0, p1, p2 = e0 - di * i0, e1 - di * i1, e2 - di * i2
    pn = (p0 * p0 + p1 * p1 + p2 * p2) ** 0.5
    if pn <= 1e-12:  # no preference along the edge: brake (and come back in) with all of it
        return i0, i1, i2
    s = (1.0 - b * b) ** 0.5 / pn
    return b * i0 + s * p0, b * i1 + s * p1, b * i2 + s * p2


def _nearest(dd, k):
    """Indices of the k smallest values of dd, ascending (k ≪ len(dd): an insertion list)."""
    idx = np.empty(k, dtype=np.int64)
    val = np.empty(k)
    n = 0
    for j in range(dd.shape[0]):
        v = dd[j]
        if n == k and v >= val[k - 1]:
            continue
        pos = n if n < k else k - 1
        while pos > 0 and val[pos - 1] > v:
            if pos < k:
                val[pos] = val[pos - 1]
                idx[pos] = idx[pos - 1]
            pos -= 1
        val[pos] = v
        idx[pos] = j
        if n < k:
            n += 1
    return idx


def _sphere_beats_plane(d, part, n_n, inv, cx, cy, cz, r):
    """fit._sphere_beats_plane on the neighbours d[part[:n_n]] · inv: the sphere's squared geometric
    residuals sum below the scatter's smallest eigenvalue (the PCA plane's)."""
    m0 = m1 = m2 = 0.0
    for k in range(n_n):
        j = part[k]
        m0 += d[j, 0] * inv
        m1 += d[j, 1] * inv
        m2 += d[j, 2] * inv
    f = 1.0 / n_n
    m0, m1, m2 = m0 * f, m1 * f, m2 * f
    C = np.zeros((3, 3))
    res = 0.0
    for k in range(n_n):
        j = part[k]
        q0, q1, q2 = d[j, 0] * inv, d[j, 1] * inv, d[j, 2] * inv
        e = ((q0 - cx) ** 2 + (q1 - cy) ** 2 + (q2 - cz) ** 2) ** 0.5 - r
        res += e * e
        q0, q1, q2 = q0 - m0, q1 - m1, q2 - m2
        C[0, 0] += q0 * q0
        C[0, 1] += q0 * q1
        C[0, 2] += q0 * q2
        C[1, 1] += q1 * q1
        C[1, 2] += q1 * q2
        C[2, 2] += q2 * q2
    C[1, 0], C[2, 0], C[2, 1] = C[0, 1], C[0, 2], C[1, 2]
    return res < np.linalg.eigvalsh(C)[0]


def _restore(cov, fp, fp_old, coef, coef_old, s, s_old):
    """Undo the footprint (points fp had coverage fp_old), the diffusion and the source."""
    for r in range(fp.shape[0] - 1, -1, -1):  # backwards: right even if fp repeated a point
        cov[fp[r]] = fp_old[r]
    coef[:] = coef_old
    s[:] = s_old


def _offsets(pts, cand, x, d, dd):
    """Offsets d (m, 3) [m] of the candidates from the agent x and their squared lengths dd (m,); the index of
    the nearest candidate."""
    x0, x1, x2 = x[0], x[1], x[2]
    jmin = 0
    for j in range(cand.shape[0]):
        c = cand[j]
        a0, a1, a2 = pts[c, 0] - x0, pts[c, 1] - x1, pts[c, 2] - x2
        d[j, 0], d[j, 1], d[j, 2] = a0, a1, a2
        dd[j] = a0 * a0 + a1 * a1 + a2 * a2
        if dd[j] < dd[jmin]:
            jmin = j
    return jmin


def _fit_patch(d, dd, part, n_n, inv, prm):
    """Sphere/plane fit (eq. 23–26) of the neighbours d[part] · inv: the smallest eigenvector of WᵀW, rows
    (q, −1, −½|q|²). Returns (status, kind (0 sphere, 1 plane), centre or plane point c, radius, plane normal p)
    in the scaled coordinates; a status other than OK leaves the rest meaningless."""
    B = np.zeros((5, 5))
    w = np.empty(5)
    h2 = -0.5 * inv * inv
    for r in range(n_n):
        j = part[r]
        w[0], w[1], w[2], w[3], w[4] = d[j, 0] * inv, d[j, 1] * inv, d[j, 2] * inv, -1.0, dd[j] * h2
        for a in range(5):
            for b in range(a, 5):
                B[a, b] += w[a] * w[b]
    for a in range(5):
        for b in range(a):
            B[a, b] = B[b, a]
    ev, vecs = np.linalg.eigh(B)
    if ev[1] <= prm[_DEGENERACY] * ev[4]:
        return DEGENERATE, 0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    v0x, v1x, v2x, vinf, v0 = vecs[0, 0], vecs[1, 0], vecs[2, 0], vecs[3, 0], vecs[4, 0]
    nv = (v0x * v0x + v1x * v1x + v2x * v2x) ** 0.5
    if abs(v0) * prm[_MAX_RADIUS] > nv:
        cx, cy, cz = v0x / v0, v1x / v0, v2x / v0
        rr2 = cx * cx + cy * cy + cz * cz - 2.0 * vinf / v0
        if rr2 <= 0.0:
            return DEGENERATE, 0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
        if rr2 < prm[_CHECK_RADIUS] * prm[_CHECK_RADIUS] and not _sphere_beats_plane(d, part, n_n, inv, cx, cy, cz,
                                                                                      rr2**0.5):
            return DEGENERATE, 0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0  # no better than the plane: numpy takes the plane
        return OK, 0, cx, cy, cz, rr2**0.5, 0.0, 0.0, 0.0
    if nv == 0.0:
        return DEGENERATE, 0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    px, py, pz = v0x / nv, v1x / nv, v2x / nv
    o = vinf / nv
    return OK, 1, o * px, o * py, o * pz, np.inf, px, py, pz


def _on_tangent_plane(d, sf0, sf1, sf2, t0, t1, t2, s0, s1, s2, gu, gv, d2):
    """Every candidate on the tangent plane (t, s) at the projected agent sf: (u, v) [m] into gu, gv and the
    squared 3D distance [m²] into d2."""
    for j in range(d.shape[0]):
        e0, e1, e2 = d[j, 0] - sf0, d[j, 1] - sf1, d[j, 2] - sf2
        gu[j] = e0 * t0 + e1 * t1 + e2 * t2
        gv[j] = e0 * s0 + e1 * s1 + e2 * s2
        d2[j] = e0 * e0 + e1 * e1 + e2 * e2


def _add_footprint(cand, d2, gu, gv, cov, cov_sum, prm, fp, fp_old):
    """The footprint φ (eq. 30–31) added to the coverage (eq. 3); the points and their old coverage go to fp and
    fp_old for a fallback. Returns their number and the new coverage sum."""
    eps2 = prm[_EPS2]
    n_fp = 0
    for j in range(cand.shape[0]):
        if d2[j] <= prm[_R_A2]:
            k = np.exp(-eps2 * (gu[j] * gu[j] + gv[j] * gv[j]))
            c = cand[j]
            fp[n_fp] = c
            fp_old[n_fp] = cov[c]
            n_fp += 1
            cov[c] += k
            cov_sum += k
    return n_fp, cov_sum


def _diffuse(cov, cov_sum, tidx, p_t, s_ext, c_used, active, sums, phitm_t, dcoef, coef, decay, prm):
    """Source on the target rows (eq. 1–2) and one step of spectral diffusion (eq. 19)."""
    if prm[_NORM_TARGET] > 0.0:
        norm = 0.0
        for r in range(tidx.shape[0]):
            norm += cov[tidx[r]]
    else:
        norm = cov_sum
    update_source(cov, tidx, p_t, norm, s_ext, c_used, active, sums, phitm_t, dcoef)
    for k in range(coef.shape[0]):
        coef[k] = (coef[k] + dcoef[k]) * decay[k]


def _cubic_slope(part, n_n, cand, phi, coef, gu, gv, inv, scale2, prm):
    """Gradient on the tangent plane (eq. 32–33): the weighted cubic through the potential at the neighbours, in
    (u, v) scaled by the neighbourhood radius; its linear terms are the slope. Returns (ok, s_u, s_v); ok is
    False when the normal matrix is singular."""
    A = np.zeros((10, 10))
    rhs = np.zeros(10)
    X = np.empty(10)
    ws = -prm[_EPS2] * scale2
    u0 = 0.0
    for r in range(n_n):
        j = part[r]
        c = cand[j]
        un = 0.0
        for k in range(coef.shape[0]):
            un += phi[c, k] * coef[k]
        if r == 0:
            u0 = un  # any constant: the cubic's own constant term absorbs it
        u, v = gu[j] * inv, gv[j] * inv
        uu, vv = u * u, v * v
        X[0], X[1], X[2], X[3], X[4] = 1.0, u, v, uu, u * v
        X[5], X[6], X[7], X[8], X[9] = vv, uu * u, uu * v, vv * u, vv * v
        wt = np.exp(ws * (uu + vv))
        y = (un - u0) * wt
        for a in range(10):
            xa = X[a] * wt
            rhs[a] += X[a] * y
            for b in range(a, 10):
                A[a, b] += xa * X[b]
    ridge = prm[_RIDGE] * A[0, 0] + 1e-300
    # Cholesky of the (upper) normal matrix with the ridge on its diagonal.
    L = np.zeros((10, 10))
    for a in range(10):
        acc = A[a, a] + ridge
        for k in range(a):
            acc -= L[a, k] * L[a, k]
        if acc <= 0.0:
            return False, 0.0, 0.0
        la = acc**0.5
        L[a, a] = la
        for b in range(a + 1, 10):
            acc2 = A[a, b]
            for k in range(a):
                acc2 -= L[b, k] * L[a, k]
            L[b, a] = acc2 / la
    y = np.empty(10)
    for a in range(10):
        acc = rhs[a]
        for k in range(a):
            acc -= L[a, k] * y[k]
        y[a] = acc / L[a, a]
    coefs = np.empty(10)
    for a in range(9, -1, -1):
        acc = y[a]
        for k in range(a + 1, 10):
            acc -= L[k, a] * coefs[k]
        coefs[a] = acc / L[a, a]
    return True, coefs[1], coefs[2]


def _source_slope(cand, tpos, s_ext, d2, gu, gv, prm):
    """The raw source's weighted plane over the whole ball (the explorer's _source_slope): (ok, c_u, c_v)
    [1/m]; ok is False without source there or on a degenerate plane."""
    eps2 = prm[_EPS2]
    any_src = False
    a00 = a01 = a02 = a11 = a12 = a22 = b0 = b1 = b2 = 0.0
    for j in range(cand.shape[0]):
        t = tpos[cand[j]]
        sj = s_ext[t] if t >= 0 else 0.0
        kk = np.exp(-eps2 * d2[j])
        u, v = gu[j], gv[j]
        if sj != 0.0:
            any_src = True
            b0 += sj * kk
            b1 += sj * kk * u
            b2 += sj * kk * v
        a00 += kk
        a01 += kk * u
        a02 += kk * v
        a11 += kk * u * u
        a12 += kk * u * v
        a22 += kk * v * v
    if any_src and b0 > 0.0:
        return plane_slope(a00, a01, a02, a11, a12, a22, b0, b1, b2, prm[_PIVOT])
    return False, 0.0, 0.0


def _agent_velocity(e0, e1, e2, vel, n0, n1, n2, at_edge, i0, i1, i2, prm):
    """The agent (eq. 6) along the unit direction e: first order = full speed along it; second order = its
    velocity carried to this tangent plane (length kept) plus a_max·dt along it, braking its outward motion first
    at a scan edge (unit inward tangent i); then ‖v‖ ≤ v_max. Returns v [m/s]."""
    v_max = prm[_V_MAX]
    if prm[_ORDER] == 1.0:
        q0, q1, q2 = v_max * e0, v_max * e1, v_max * e2
    else:
        q0, q1, q2 = transported_floats(vel[0], vel[1], vel[2], n0, n1, n2)
        a_dt = prm[_A_DT]
        if at_edge and prm[_BRAKE] > 0.0:
            e0, e1, e2 = braked_direction(e0, e1, e2, i0, i1, i2, -(q0 * i0 + q1 * i1 + q2 * i2), a_dt)
        q0, q1, q2 = q0 + a_dt * e0, q1 + a_dt * e1, q2 + a_dt * e2
    nw = (q0 * q0 + q1 * q1 + q2 * q2) ** 0.5
    if nw > v_max:
        kk = v_max / nw
        q0, q1, q2 = q0 * kk, q1 * kk, q2 * kk
    return q0, q1, q2


def _land_on_cloud(kind, cx, cy, cz, rad, px, py, pz, sf0, sf1, sf2, q0, q1, q2, n0, n1, n2, scale, d, dd, prm):
    """Landing on the fitted patch; past the cloud's edge the outward part of the velocity q goes, and a landing
    still out is pulled within max_off_cloud_voxels of the nearest point. Returns (ok, step [m], normal there,
    |step|²)."""
    dt, off2 = prm[_DT], prm[_OFF2]
    dq2 = np.empty(d.shape[0])
    ok, st0, st1, st2, m0, m1, m2, ss, kmin = _land(kind, cx, cy, cz, rad, px, py, pz, sf0, sf1, sf2,
                                                    q0, q1, q2, n0, n1, n2, scale, dt, d, dd, dq2)
    if not ok:
        return False, st0, st1, st2, m0, m1, m2, ss
    if dq2[kmin] > off2:
        o0, o1, o2 = st0 - d[kmin, 0], st1 - d[kmin, 1], st2 - d[kmin, 2]
        on = o0 * n0 + o1 * n1 + o2 * n2
        o0, o1, o2 = o0 - on * n0, o1 - on * n1, o2 - on * n2
        no = (o0 * o0 + o1 * o1 + o2 * o2) ** 0.5
        if no > 0.0:
            o0, o1, o2 = o0 / no, o1 / no, o2 / no
            vo = max(q0 * o0 + q1 * o1 + q2 * o2, 0.0)
            q0, q1, q2 = q0 - vo * o0, q1 - vo * o1, q2 - vo * o2
            ok, st0, st1, st2, m0, m1, m2, ss, kmin = _land(kind, cx, cy, cz, rad, px, py, pz, sf0, sf1, sf2,
                                                            q0, q1, q2, n0, n1, n2, scale, dt, d, dd, dq2)
            if not ok:
                return False, st0, st1, st2, m0, m1, m2, ss
        if dq2[kmin] > off2:  # still out: within max_off_cloud_voxels of the nearest point
            f = prm[_OFF] / dq2[kmin] ** 0.5
            st0 = d[kmin, 0] + (st0 - d[kmin, 0]) * f
            st1 = d[kmin, 1] + (st1 - d[kmin, 1]) * f
            st2 = d[kmin, 2] + (st2 - d[kmin, 2]) * f
            ss = st0 * st0 + st1 * st1 + st2 * st2
    return True, st0, st1, st2, m0, m1, m2, ss


def _clamp_step(st0, st1, st2, ss, d, dd, jmin, prm):
    """The step ≤ v_max·dt: shortening may cut a corner past the edge, so it is halved until back within
    max_off_cloud_voxels, else it goes halfway to the nearest cloud point (see the explorer). Returns (step, length)."""
    sl = ss**0.5
    step_max, off2 = prm[_STEP_MAX], prm[_OFF2]
    if sl <= step_max:
        return st0, st1, st2, sl
    f = step_max / sl
    st0, st1, st2 = st0 * f, st1 * f, st2 * f
    sl = step_max
    for _ in range(5):
        ss2 = st0 * st0 + st1 * st1 + st2 * st2
        lo = np.inf
        for j in range(dd.shape[0]):
            z = dd[j] - 2.0 * (d[j, 0] * st0 + d[j, 1] * st1 + d[j, 2] * st2) + ss2
            lo = min(lo, z)
        if lo <= off2:
            return st0, st1, st2, sl
        st0, st1, st2 = st0 * 0.5, st1 * 0.5, st2 * 0.5
        sl *= 0.5
    dj = dd[jmin] ** 0.5
    st0 = st1 = st2 = 0.0
    if dj > 0.0:
        f = 0.5 * min(1.0, step_max / dj)
        st0, st1, st2 = d[jmin, 0] * f, d[jmin, 1] * f, d[jmin, 2] * f
    return st0, st1, st2, (st0 * st0 + st1 * st1 + st2 * st2) ** 0.5


def _walk_step(pts, cand, x, nrm, vel, cov, cov_sum, tidx, tpos, p_t, phitm_t, coef, s_ext, decay, phi,
               gap_has, n_n, prm, out, c_used, active, sums, dcoef):
    """One walking step of one agent; see the module doc. Changes cov, coef, s_ext and out on OK only.

    Args:
        pts: (N, 3) cloud [m]. cand: candidate point indices around the agent (its ball).
        x, nrm, vel: the agent's position [m], last unit normal and velocity [m/s] (3,) each.
        cov, cov_sum: accumulated footprint c̃ (N,) and its sum. tidx, tpos, p_t: target rows, the
            row of each cloud point (−1 off the target), normalised target on them.
        phitm_t: (T, K) rows of Φᵀ M on the target; coef: (K,) spectral coefficients of the
            potential; s_ext: (T + 1,) source with a trailing 0; decay: (K,) exp(−λ δt); phi: (N, K) Φ.
        gap_has: (N,) bool, point has a link across a scan hole. n_n: neighbours of the fits.
        prm: parameters, see :func:`params`. out: (OUT_SIZE,) results on OK.
        c_used, active, sums: the running source sums (:class:`~tactex.ergodic.source.SourceSums`);
            a failed step leaves them describing its coverage, which the next update corrects.
        dcoef: (K,) scratch for Φᵀ M s.
    """
    m = cand.shape[0]
    if m < n_n:  # never from the explorer's balls; compiled code has no bounds checks, so refuse
        return DEGENERATE
    d = np.empty((m, 3))
    dd = np.empty(m)
    jmin = _offsets(pts, cand, x, d, dd)
    part = _nearest(dd, n_n)
    scale2 = dd[part[n_n - 1]]
    scale = scale2**0.5 if scale2 > 0.0 else 1.0  # all n_n points coincide: the fit is degenerate below
    inv = 1.0 / scale

    status, kind, cx, cy, cz, rad, px, py, pz = _fit_patch(d, dd, part, n_n, inv, prm)
    if status != OK:
        return status
    ok, p0, p1, p2, n0, n1, n2 = project_floats(kind, cx, cy, cz, rad, px, py, pz, 0.0, 0.0, 0.0,
                                                nrm[0], nrm[1], nrm[2])
    if not ok:
        return DEGENERATE
    sf0, sf1, sf2 = p0 * scale, p1 * scale, p2 * scale  # the projected agent, agent-centred [m]
    t0, t1, t2, s0, s1, s2 = tangent_floats(n0, n1, n2)  # (t_u, t_v, n) right-handed
    gu = np.empty(m)
    gv = np.empty(m)
    d2 = np.empty(m)
    _on_tangent_plane(d, sf0, sf1, sf2, t0, t1, t2, s0, s1, s2, gu, gv, d2)
    # Scan edge: the neighbours' centroid (in neighbourhood radii) is well inside.
    cu = cv = 0.0
    for r in range(n_n):
        cu += gu[part[r]] * inv
        cv += gv[part[r]] * inv
    cn = (cu * cu + cv * cv) ** 0.5
    at_edge = cn > prm[_EDGE] * n_n
    if at_edge:
        for r in range(n_n):
            if gap_has[cand[part[r]]]:
                return EDGE_GAP  # before any state changes: the hop planner runs in numpy

    # Footprint, coverage, source and diffusion; the old values are kept for a fallback.
    fp = np.empty(m, dtype=np.int64)
    fp_old = np.empty(m)
    n_fp, cov_sum = _add_footprint(cand, d2, gu, gv, cov, cov_sum, prm, fp, fp_old)
    fp = fp[:n_fp]
    fp_old = fp_old[:n_fp]
    coef_old = coef.copy()
    s_old = s_ext.copy()
    _diffuse(cov, cov_sum, tidx, p_t, s_ext, c_used, active, sums, phitm_t, dcoef, coef, decay, prm)

    ok, su, sv = _cubic_slope(part, n_n, cand, phi, coef, gu, gv, inv, scale2, prm)
    if not ok:
        _restore(cov, fp, fp_old, coef, coef_old, s_ext, s_old)
        return FLAT
    if prm[_SOURCE_W] > 0.0:
        ok, c_u, c_v = _source_slope(cand, tpos, s_ext, d2, gu, gv, prm)
        if ok:
            kw = prm[_SOURCE_W] * scale
            su += kw * c_u
            sv += kw * c_v
    g0, g1, g2 = t0 * su + s0 * sv, t1 * su + s1 * sv, t2 * su + s2 * sv
    i0 = i1 = i2 = 0.0  # the unit inward tangent at a scan edge
    if at_edge:  # Neumann boundary: no outward flux, drop the gradient's outward part
        i0, i1, i2 = (t0 * cu + s0 * cv) / cn, (t1 * cu + s1 * cv) / cn, (t2 * cu + s2 * cv) / cn
        go = g0 * i0 + g1 * i1 + g2 * i2
        if go < 0.0:
            g0, g1, g2 = g0 - go * i0, g1 - go * i1, g2 - go * i2
    gn = (g0 * g0 + g1 * g1 + g2 * g2) ** 0.5
    if not (gn > 0.0 and gn < np.inf):
        _restore(cov, fp, fp_old, coef, coef_old, s_ext, s_old)
        return FLAT
    k = 1.0 / gn
    q0, q1, q2 = _agent_velocity(g0 * k, g1 * k, g2 * k, vel, n0, n1, n2, at_edge, i0, i1, i2, prm)
    ok, st0, st1, st2, m0, m1, m2, ss = _land_on_cloud(kind, cx, cy, cz, rad, px, py, pz, sf0, sf1, sf2,
                                                       q0, q1, q2, n0, n1, n2, scale, d, dd, prm)
    if not ok:
        _restore(cov, fp, fp_old, coef, coef_old, s_ext, s_old)
        return DEGENERATE
    st0, st1, st2, sl = _clamp_step(st0, st1, st2, ss, d, dd, jmin, prm)
    idt = 1.0 / prm[_DT]
    e0, e1, e2 = st0 * idt, st1 * idt, st2 * idt
    vn = e0 * m0 + e1 * m1 + e2 * m2
    # the command's frame at the landing point: the tangent basis of its normal, the velocity's
    # tangential part (the step is a chord)
    u0, u1, u2, w0, w1, w2 = tangent_floats(m0, m1, m2)
    out[0], out[1], out[2] = x[0] + st0, x[1] + st1, x[2] + st2
    out[3], out[4], out[5] = e0 - vn * m0, e1 - vn * m1, e2 - vn * m2
    out[6], out[7], out[8] = m0, m1, m2
    out[9], out[10], out[11] = u0, u1, u2
    out[12], out[13], out[14] = w0, w1, w2
    out[15], out[16], out[17] = e0 - vn * m0, e1 - vn * m1, e2 - vn * m2
    out[18] = sl
    out[19] = cand[jmin]
    out[20] = cov_sum
    return OK


def _land(kind, cx, cy, cz, rad, px, py, pz, sf0, sf1, sf2, q0, q1, q2, n0, n1, n2, scale, dt, d, dd, dq2):
    """Where velocity q [m/s] takes the projected agent sf in one step, on the patch (fitted in
    coordinates scaled by 1/scale): ok, the step [m], the normal there, |step|², and in dq2 the
    squared distances from the landing point to the candidates, with the index of the nearest."""
    k = 1.0 / scale
    y0, y1, y2 = (sf0 + q0 * dt) * k, (sf1 + q1 * dt) * k, (sf2 + q2 * dt) * k
    ok, a0, a1, a2, m0, m1, m2 = project_floats(kind, cx, cy, cz, rad, px, py, pz, y0, y1, y2, n0, n1, n2)
    a0, a1, a2 = a0 * scale, a1 * scale, a2 * scale
    ss = a0 * a0 + a1 * a1 + a2 * a2
    kmin = 0
    for j in range(dd.shape[0]):
        z = dd[j] - (d[j, 0] * (2.0 * a0) + d[j, 1] * (2.0 * a1) + d[j, 2] * (2.0 * a2)) + ss
        dq2[j] = z
        if z < dq2[kmin]:
            kmin = j
    return ok, a0, a1, a2, m0, m1, m2, ss, kmin


_compiled = None  # _walk_step compiled, made on first use
_failure: str | None = None  # why it could not be made or run, once it failed in this process


def available() -> bool:
    """Whether numba is installed (the ``fast`` extra); does not import it."""
    return importlib.util.find_spec("numba") is not None


def compile_pending() -> bool:
    """Whether the next explorer will make (or load from numba's cache) the compiled step: numba is
    installed and enabled, nothing failed, and this process holds no machine code for it yet."""
    if _failure is not None or not available():
        return False
    if _compiled is not None:
        return not _compiled.signatures
    from numba import config

    return not config.DISABLE_JIT


#: The compiled step's helpers, compiled before it and put in place of their Python forms in this module's
#: namespace (numba resolves the step's calls there when it compiles it).
HELPERS = ("_nearest", "_restore", "_land", "_sphere_beats_plane", "project_floats", "tangent_floats", "plane_slope",
           "transported_floats", "braked_direction", "update_source", "_offsets", "_fit_patch", "_on_tangent_plane",
           "_add_footprint", "_diffuse", "_cubic_slope", "_source_slope", "_agent_velocity", "_land_on_cloud",
           "_clamp_step")


def compiled_walk_step():
    """The walking step compiled by numba (see :func:`_walk_step` for its arguments), or None when
    numba is not installed.

    numba is imported here, not with this module (importing it is slow). The :data:`HELPERS` are
    compiled first and replace their Python forms in this module's namespace. Machine code for each
    set of argument types is made on the first call (seconds) and kept in numba's cache: beside this
    file when its folder is writable, else in a per-user folder, else nowhere (then each process
    compiles). Import errors other than a missing numba (e.g. a numba too old for the installed
    numpy) propagate: the explorer reports them and runs numpy. After :func:`disable` it raises at once.
    """
    global _compiled
    if _failure is not None:
        raise RuntimeError(_failure)
    if _compiled is None:
        if not available():
            return None
        from numba import config, njit

        if config.DISABLE_JIT:  # NUMBA_DISABLE_JIT=1 would run the step as plain Python, far slower than numpy
            return None

        def jit(fn):
            try:
                return njit(cache=True, nogil=True)(fn)
            except RuntimeError:  # no writable cache location anywhere: compile in every process
                return njit(nogil=True)(fn)

        namespace = globals()
        for name in HELPERS:
            namespace[name] = jit(namespace[name])
        _compiled = jit(_walk_step)
    return _compiled


def disable(reason: str) -> None:
    """Stop offering the compiled step in this process (it failed to build or run: ``reason``), so
    that later explorers go straight to numpy instead of paying for the failure again."""
    global _failure
    _failure = reason
