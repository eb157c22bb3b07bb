"""The HEDAC walking step of one agent (TEC eq. 1–6, 19–33), in numpy, and the choice of its compiled twin.

One step (see :mod:`tactex.ergodic.explorer` for the whole method): the neighbourhood from the
precomputed ball of the agent's nearest point, the sphere-or-plane fit and the projection (eq. 23–29,
:mod:`.surface_fit`), the footprint φ (eq. 30–31) added to the coverage (eq. 3), the source and one
step of spectral diffusion (eq. 1–2, 19), the gradient on the tangent plane (eq. 32–33), the scan-edge
rule (eq. 5's Neumann boundary), the agent's update (eq. 6) and the landing on the fitted patch.
Where the guidance (:mod:`.guidance`, :mod:`.hops`) steers, it replaces or follows the gradient.

:class:`HedacStep` is that part of :class:`~tactex.ergodic.explorer.HedacExplorer`. The explorer runs
the compiled step (:mod:`.compiled_step`) when numba is there and the case is a plain walking step of
one agent; otherwise, and whenever the compiled step declines a case, this numpy step runs.
"""

from __future__ import annotations

import logging
import warnings

import numpy as np
from scipy.linalg.lapack import dposv as _dposv

from tactex.ergodic import compiled_step
from tactex.ergodic.command import ExplorationCommand
from tactex.ergodic.compiled_step import tangent_floats
from tactex.ergodic.gradient import CUBIC_EXPONENTS, RIDGE_RTOL
from tactex.ergodic.setup_progress import in_chunks
from tactex.ergodic.source import update_source_numpy
from tactex.ergodic.surface_fit import plane_slope_checked, project_on_patch, tangent_matrix_0uv
from tactex.geometry.fit import SurfacePatch, fit_local_design

__all__ = ["EDGE_OFFSET", "FOOTPRINT", "MOVE", "WHOLE", "HedacStep"]

_log = logging.getLogger(__name__)
# ndarray.dot and the ufunc reductions dispatch in a fraction of @ / np.dot / ndarray.sum's time on
# these tiny arrays (the step is mostly numpy calls, their overhead is most of its cost), same results.
_sum = np.add.reduce
_min = np.minimum.reduce
if CUBIC_EXPONENTS != ((0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2), (3, 0), (2, 1), (1, 2), (0, 3)):
    raise RuntimeError("the explorer's in-place monomials assume gradient.CUBIC_EXPONENTS' order")
# Column picks of the in-place monomials: (u, v) → (u·u, u·v, v·v) → (u²·u, u²·v, v²·u, v²·v).
_QUAD_A, _QUAD_B = np.array([0, 0, 1]), np.array([0, 1, 1])
_CUBE_A, _CUBE_B = np.array([0, 0, 2, 2]), np.array([0, 1, 0, 1])
#: Tangential offset of the neighbours' centroid (in neighbourhood radii) that marks a scan edge:
#: ≈ 0 inside a uniformly sampled surface, ≈ 0.42 on a straight edge (half-disc centroid 4/(3π)).
EDGE_OFFSET = 0.25
#: Passes of a step (see HedacExplorer.step_all and :mod:`.multi_agent`): one agent does all of it;
#: several agents lay their footprints first, then (after one diffusion) move.
WHOLE, FOOTPRINT, MOVE = 0, 1, 2


class HedacStep:
    """The numpy walking step and the compiled one's driver (mixed into
    :class:`~tactex.ergodic.explorer.HedacExplorer`, whose ``__init__`` sets the arrays and buffers read here)."""

    def _update_decay(self) -> None:
        alpha = self.config.alpha_at(self.step_count)
        if alpha != self._decay_alpha:
            # e^{−(λ δt + β)}: eq. 19's diffusion and the cooling β of u̇ = αh²Δu − βu + s per step (eq. 4's −u)
            self._decay = np.exp(-(self._evals * (alpha * self.spacing**2) + self.config.cooling))
            self._decay_alpha = alpha

    def _build_neighbourhoods(self) -> None:
        """Per cloud point j, the indices within R_j = max(r_a, d_j,n_N) + (2 + v_max)·h.

        The agent is at most (1 + v_max)·h from the point nearest to it one step earlier, so the
        ball of that point holds every cloud point within max(r_a, kNN radius) + h of the agent:
        the footprint and the n_N nearest neighbours come from one small distance computation
        instead of two K-D tree queries per step.
        """
        cfg = self.config
        h = self.spacing
        dk = self._tree.query(self._points, k=cfg.n_neighbors_fit)[0][:, -1]
        radius = np.maximum(self._r_a, dk) + (2.0 + cfg.max_velocity) * h
        balls: list[np.ndarray] = []

        def chunk(lo: int, hi: int) -> None:
            found = self._tree.query_ball_point(self._points[lo:hi], radius[lo:hi], return_sorted=True)
            balls.extend(np.asarray(b, dtype=np.intp) for b in found)
        in_chunks(len(self._points), chunk, getattr(self, "_progress", None), "explorer: neighbourhoods")
        self._ball = balls

    def _candidates(self, i: int, x: np.ndarray, exact: bool) -> np.ndarray:
        if not exact:
            return self._ball[self._near[i]]
        d, j = self._tree.query(x)
        self._near[i] = int(j)
        if d <= self.spacing:
            return self._ball[int(j)]
        # Off the surface (a measured position): gather the footprint and the kNN directly.
        knn = self._tree.query(x, k=self.config.n_neighbors_fit)[1]
        ball = self._tree.query_ball_point(x, self._r_a + float(d))
        return np.union1d(knn, np.asarray(ball, dtype=np.intp))

    def _step_agent(self, i: int, exact: bool) -> ExplorationCommand:
        # The per-step hot path: every line pays numpy's call overhead, so vector algebra reuses the squared
        # distances dd instead of recomputing them (|d − s|² = dd − 2 d·s + |s|²).
        if self._bridges[i] is not None:
            return self._bridge_step(i)
        x = self._x[i]
        cand = self._candidates(i, x, True) if exact else self._ball[self._near[i]]
        self._nrm_t[i] = self._outward_side(self._nrm_t[i], self._near.item(i))
        if self._walk_compiled is not None and self._pass == WHOLE:
            cmd = self._compiled_step(i, x, cand)
            if cmd is not None:
                return cmd
        pts = self._points
        n_n = self._n_n
        d = pts.take(cand, 0)  # take, not fancy indexing: same values, a fraction of the dispatch
        d -= x
        sx, sy, sz = (d * d).T
        dd = sx + sz  # the order of np.einsum("ij,ij->i", d, d), bit for bit
        dd += sy
        self._near[i] = cand.item(dd.argmin())
        part = dd.argpartition(self._n_n1)[:n_n]
        nbr = cand.take(part)
        dd_n = dd.take(part)
        scale2 = max(dd_n.tolist())  # exact: no rounding in a max
        scale = scale2**0.5 if scale2 > 0.0 else self.spacing
        inv = 1.0 / scale

        # Sphere/plane fit around the agent (eq. 23–26) in agent-centred, scaled coordinates.
        dk = d.take(part, 0)
        # The fit's design rows (q, −1, −½|q|²), q = dk·inv, in the preallocated buffer
        # (−½·(dd·inv²) = dd·(−½·inv²) exactly: a factor ½ only shifts the exponent).
        np.multiply(dk, inv, self._w_q)
        np.multiply(dd_n, -0.5 * (inv * inv), self._w_sq)
        patch = fit_local_design(self._w)
        (p0, p1, p2), nt = project_on_patch(patch, (0.0, 0.0, 0.0), self._nrm_t[i])
        sf = (p0 * scale, p1 * scale, p2 * scale)  # the projected agent, agent-centred [m]
        shift, nrm = np.array(sf), np.array(nt)

        # Every candidate on the tangent plane at the projected agent (eq. 31), and the footprint
        # φ(r) = exp(−ε² r²) of eq. 30 there: the footprint is φ inside r_a (3D distance, so the
        # far side of a thin wall stays out), the raw source's plane fit weighs the whole ball by it.
        tb0 = tangent_matrix_0uv(nt)
        tb = tb0[:, 1:]
        rel = d - shift
        g1uv = rel.dot(tb0)  # rows (0, u, v) [m]; column 0 becomes 1 below
        rel *= rel
        d2 = _sum(rel, 1)
        foot = g1uv * g1uv
        foot = _sum(foot, 1)
        foot *= -self._eps2
        np.exp(foot, foot)
        g1uv[:, 0] = 1.0
        tuv = g1uv[:, 1:]
        inside = (d2 <= self._r_a2).nonzero()[0]
        fp = cand.take(inside)
        phi = foot.take(inside)
        if self._pass != MOVE:
            self._add_coverage(fp, phi)
            if self._pass == FOOTPRINT:
                return None
            self._update_potential()
        u = self._phi.take(nbr, 0).dot(self._coef)

        # Gradient on the tangent plane (eq. 32–33) in scaled (u, v); u becomes u − u0.
        uv = tuv.take(part, 0)
        uv *= inv
        g, u0 = self._cubic_gradient(uv, u, cand, g1uv, d2, tb, scale, scale2)
        guide = None
        if self._passes is not None and self._pass == WHOLE and self.n_agents == 1:
            guide, hop = self._guide(i, x, sf, nrm)
            if hop is not None:
                return hop
            if guide is not None:
                g = guide
        # At a scan edge (neighbours' centroid well inside) the Neumann boundary of eq. 5 allows no
        # outward flux: drop the outward part of the gradient so the agent follows the edge.
        cu, cv = _sum(uv, 0).tolist()  # n_n × the neighbours' centroid in (u, v) [radii]
        cn = (cu * cu + cv * cv) ** 0.5
        inward = None
        if cn > EDGE_OFFSET * n_n:
            # A hop follows the potential; an agent on a planned pass follows its waypoints and does not hop.
            if guide is None and self._gaps.n_links and self._gaps.has.take(nbr).any():
                here = np.array((x.item(0) + sf[0], x.item(1) + sf[1], x.item(2) + sf[2]))
                bridge = self._plan_bridge(nbr, u, u0, here, nrm)
                if bridge is not None:
                    self._bridges[i] = bridge
                    return self._bridge_move(i, x, bridge)
            inward = tb.dot(np.array((cu / cn, cv / cn)))
            go = float(g.dot(inward))
            if go < 0.0:
                g = g - go * inward
                if guide is not None:
                    self._check_blocked(g, guide)
        return self._move_agent(i, x, patch, sf, nt, nrm, g, inward, tb, scale, cand, d, dd)

    def _cubic_gradient(self, uv: np.ndarray, u: np.ndarray, cand: np.ndarray, g1uv: np.ndarray, d2: np.ndarray,
                        tb: np.ndarray, scale: float, scale2: float) -> tuple[np.ndarray, float]:
        """The potential's gradient (3,) on the tangent plane (basis ``tb``) at the projected agent: the weighted
        cubic (eq. 32–33) through u at the neighbours (scaled coordinates ``uv``, neighbourhood radius ``scale``
        [m], its square ``scale2``) plus the raw source's plane slope over the candidates ``cand`` (rows
        ``g1uv``, squared distances ``d2``); zero when the cubic's system is singular. Returns it and u0, the
        value subtracted from u in place (the cubic's constant term absorbs it)."""
        self._xf_lin[...] = uv  # uv stays contiguous: the reductions and products below are cheaper on it
        # Monomials of CUBIC_EXPONENTS in place, a block of columns per call (the same products:
        # u·u, u·v, v·v, then u²·u, u²·v, v²·u, v²·v).
        xf = self._xf
        xq = self._xf_quad
        np.multiply(uv.take(_QUAD_A, 1), uv.take(_QUAD_B, 1), xq)
        np.multiply(xq.take(_CUBE_A, 1), uv.take(_CUBE_B, 1), self._xf_cube)
        w = self._wt
        np.add(self._xf_uu, self._xf_vv, w)
        w *= -self._eps2 * scale2
        np.exp(w, w)  # eq. 33: φ(r) on the tangent plane
        np.multiply(xf, self._wt_col, self._xw)
        xwt = self._xwt
        a = xwt.dot(xf, self._a)
        self._a_diag += RIDGE_RTOL * a.item(0) + 1e-300
        u0 = u.item(0)
        u -= u0
        _, c, info = _dposv(a, xwt.dot(u), 0, 0, 1)  # overwrite_b
        if info == 0:
            slope_uv = c[1:3]  # the cubic's linear coefficients: its slope at the agent
            if self._source_w > 0.0:
                slope = self._source_slope(cand, g1uv, d2)
                if slope is not None:  # [1/m] → per scaled unit: × scale
                    c1, c2 = slope_uv.tolist()
                    k = self._source_w * scale
                    slope_uv = np.array((c1 + k * slope[0], c2 + k * slope[1]))
            g = tb.dot(slope_uv)
        else:
            g = np.zeros(3)
        return g, u0

    def _move_agent(self, i: int, x: np.ndarray, patch: SurfacePatch, sf: tuple, nt: tuple, nrm: np.ndarray,
                    g: np.ndarray, inward: np.ndarray | None, tb: np.ndarray, scale: float, cand: np.ndarray,
                    d: np.ndarray, dd: np.ndarray) -> ExplorationCommand:
        """Agent i at x [m] one step along the gradient g (3,) (a random heading when g vanishes): the agent's
        update (braking first at a scan edge, unit ``inward``), back onto the fitted patch (projected agent ``sf``,
        normal ``nt`` as float triples and ``nrm``; tangent basis ``tb``; the fit's ``scale`` [m]), within
        max_off_cloud_voxels of the candidates (cloud indices ``cand``, offsets ``d``, squared norms ``dd``), the
        step ≤ v_max·dt, its normal on the cloud's outward side."""
        g0, g1, g2 = g.tolist()
        gn = (g0 * g0 + g1 * g1 + g2 * g2) ** 0.5  # np.dot's order for three numbers
        if gn > 0.0 and gn < np.inf:
            k = 1.0 / gn
            direction = (g0 * k, g1 * k, g2 * k)
        else:
            r = self._rng.normal(size=2)
            direction = tuple(tb.dot(r / float(np.hypot(r[0], r[1]))).tolist())

        # Agent update, back onto the surface, within one voxel of the cloud, step ≤ v_max·dt.
        agent = self._agents[i]
        if inward is not None and self._edge_braking:  # at a scan edge: brake the outward motion first
            direction = agent.edge_direction(direction, tuple(inward.tolist()), nt)
        v = agent.command_velocity_floats(direction, nt)
        step, n_new, ss, dq2, k = self._land(patch, sf, v, nt, scale, d, dd)
        if dq2.item(k) > self._off2:
            # Past the edge of the cloud (eq. 5's boundary): drop the outward part of the velocity so
            # the agent slides along the edge, and stay within one voxel of the nearest point.
            out = np.array(step) - d[k]
            out -= float(out.dot(nrm)) * nrm
            no = float(out.dot(out)) ** 0.5
            if no > 0.0:
                out *= 1.0 / no
                va = np.array(v)
                v = tuple((va - max(float(va.dot(out)), 0.0) * out).tolist())
                step, n_new, ss, dq2, k = self._land(patch, sf, v, nt, scale, d, dd)
            if dq2[k] > self._off2:
                step = d[k] + (np.array(step) - d[k]) * (self._off / float(dq2[k]) ** 0.5)
                ss = float(step.dot(step))
        sl = ss**0.5
        if sl > self._step_max:
            step = np.array(step)
            step *= self._step_max / sl
            sl = self._step_max
            # Shortening may cut a corner past the edge: halve until back within max_off_cloud_voxels.
            # An agent right at the limit and pushed outward never gets back by halving (it would
            # stand still for good): it steps halfway to its nearest cloud point instead.
            for _ in range(5):
                if float(_min(dd - 2.0 * d.dot(step) + float(step.dot(step)))) <= self._off2:
                    break
                step *= 0.5
                sl *= 0.5
            else:
                j = int(dd.argmin())
                dj = float(dd[j]) ** 0.5
                step = d[j] * (0.5 * min(1.0, self._step_max / dj)) if dj > 0.0 else np.zeros(3)
                sl = float(step.dot(step)) ** 0.5
        # x + step, step / dt and the velocity's tangential part, in Python floats (the same operations).
        s0, s1, s2 = step if isinstance(step, tuple) else step.tolist()
        x0, x1, x2 = x.tolist()
        m0, m1, m2 = n_new
        idt = 1.0 / self._dt
        v0, v1, v2 = s0 * idt, s1 * idt, s2 * idt
        vn = v0 * m0 + v1 * m1 + v2 * m2
        v_t = (v0 - vn * m0, v1 - vn * m1, v2 - vn * m2)
        agent.velocity = np.array(v_t)
        self.path_lengths[i] = self.path_lengths.item(i) + sl
        n_new = self._outward_side(n_new, cand.item(k))
        self._nrm_t[i] = n_new
        # the command's frame at the landing point: the tangent basis of its normal, the velocity's
        # tangential part (the step is a chord)
        u0, u1, u2, w0, w1, w2 = tangent_floats(*n_new)
        x_new, n_new = np.array((x0 + s0, x1 + s1, x2 + s2)), np.array(n_new)
        self._x[i] = x_new
        return ExplorationCommand(x_new, np.array(v_t), n_new, np.array((u0, u1, u2)), np.array((w0, w1, w2)),
                                  self.step_count, i)

    def _source_slope(self, cand: np.ndarray, g1uv: np.ndarray, d2: np.ndarray) -> tuple[float, float] | None:
        """Slope (c_u, c_v) [1/m] of the plane through the raw source over the candidate ball
        (rows (1, u, v) of the candidates ``cand`` with tangent-plane coordinates u, v [m], squared
        3D distances ``d2`` [m²] from the projected agent), or None when there is no source there
        or the plane is degenerate.

        The weights are the footprint φ of the 3D distance, not of the tangent-plane distance: the
        back of a thin wall lies close on the tangent plane, and its spikes (which the footprint
        can never clear from this side) would pull the agent.

        The raw source is a set of isolated spikes at uncovered target points, typically just
        outside the footprint (which has cleared its inside) and so beyond the n_N neighbours of
        the cubic: the ball (every cloud point within max(r_a, kNN radius) + h of the agent) sees
        them. A cubic through a rim spike would overshoot and its slope at the agent point *away*
        from it; the weighted plane (eq. 33's weights) has the spike's slope sign. Both fits are
        linear in the values, so the slope of (smooth part + spikes) is the sum of the two.
        """
        src = self._source_at(cand)
        if not src.any():
            return None
        wt = d2 * -self._eps2
        np.exp(wt, wt)
        wg = g1uv * wt[:, None]
        b0, b1, b2 = src.dot(wg).tolist()
        if not b0 > 0.0:
            return None
        (a00, a01, a02), (_, a11, a12), (_, _, a22) = wg.T.dot(g1uv).tolist()
        return plane_slope_checked(a00, a01, a02, a11, a12, a22, b0, b1, b2)

    def _source_at(self, idx: np.ndarray) -> np.ndarray:
        """The source s of the last step at cloud points idx (zero off the target)."""
        sweep = self._sweep
        if sweep is not None and sweep.incremental:
            return sweep.at(self._tpos.take(idx))
        return self._s_ext.take(self._tpos.take(idx))

    def _add_coverage(self, fp: np.ndarray, phi: np.ndarray) -> None:
        """Footprint values phi at cloud points fp (no repeats) added to c̃ and its running sum (eq. 3)."""
        cov = self._cov
        cov.put(fp, cov.take(fp) + phi)  # fp holds no repeats: the same as cov[fp] += phi
        self._cov_sum += float(_sum(phi))

    def _update_potential(self) -> None:
        """Source on the target rows (eq. 1–2) and one step of spectral diffusion (eq. 19)."""
        cov = self._cov
        if self._sweep is not None:
            dcoef = self._sweep.image(self._s_t)
        else:
            norm = float(_sum(cov.take(self._tidx))) if self._norm_target else self._cov_sum
            dcoef = update_source_numpy(cov, self._tidx, self._p_t, norm, self._s_t, self._src, self._phitm_t)
        # Diffuse after adding the source: the truncated projection of a sharp source rings
        # (Gibbs), its heat-kernel image does not; the raw source is added back at full resolution.
        coef = self._coef
        coef += dcoef
        coef *= self._decay

    def _outward_side(self, n: tuple, near: int) -> tuple:
        """The unit normal ``n`` (3 floats) on the cloud's outward side at its point ``near`` (its own normal
        there, TEC eq. 28's agent side): ``n`` itself when it agrees or the cloud has no normals, else −n.

        The fit orients each step's normal along the last one; where a local fit is poor (a bowl's rim, a
        noisy patch) the normal can turn by most of a right angle in a step, and the next step's orientation
        then follows it round to the inside of the part: a pressing line from beneath the surface."""
        out = self._outward
        if out is None:
            return n
        n0, n1, n2 = n
        if n0 * out.item(near, 0) + n1 * out.item(near, 1) + n2 * out.item(near, 2) >= 0.0:
            return n
        return (-n0, -n1, -n2)

    def _land(self, patch: SurfacePatch, shift: tuple, v: tuple, nrm: tuple, scale: float,
              d: np.ndarray, dd: np.ndarray) -> tuple[tuple, tuple, float, np.ndarray, int]:
        """Where velocity v [m/s] takes the agent in one step, projected onto the fitted patch
        (agent-centred coordinates, scaled by ``scale`` in the fit; ``shift`` and ``nrm`` are the
        projected agent [m], its normal and v as float triples): the step [m], the normal there (triples),
        |step|², the squared distances from the landing point to the candidates d (offsets from
        the agent, squared norms dd) and the index of the nearest one."""
        v0, v1, v2 = v
        dt, k = self._dt, 1.0 / scale
        s0, s1, s2 = shift
        (x0, x1, x2), n_new = project_on_patch(patch, ((s0 + v0 * dt) * k, (s1 + v1 * dt) * k, (s2 + v2 * dt) * k), nrm)
        x0, x1, x2 = x0 * scale, x1 * scale, x2 * scale
        ss = x0 * x0 + x1 * x1 + x2 * x2  # np.dot's order for three numbers
        dq2 = d.dot(np.array((2.0 * x0, 2.0 * x1, 2.0 * x2)))  # = 2 d·step exactly (×2 is exact)
        np.subtract(dd, dq2, dq2)
        dq2 += ss
        return (x0, x1, x2), n_new, ss, dq2, int(dq2.argmin())

    def _compile_step(self):
        """The compiled walking step (:mod:`.compiled_step`), or None (numpy) without numba or when it fails.

        It is called once here on a dummy state of this explorer's array types: numba makes (or loads
        from its cache) the machine code now, not in the middle of the first step of a control loop.
        """
        if not compiled_step.available():
            return None
        n, k = len(self._points), self._phi.shape[1]
        try:
            fn = compiled_step.compiled_walk_step()
            if fn is None:  # numba's JIT switched off (NUMBA_DISABLE_JIT)
                return None
            if not fn.signatures:  # the first explorer of this process: numba compiles or loads its cache
                _log.info("preparing the compiled exploration step (numba compiles it once per machine, in seconds)")
            fn(self._points, self._ball[0], self._points[0].copy(), np.array((0.0, 0.0, 1.0)), np.zeros(3),
               np.zeros(n), 0.0, self._tidx, self._tpos, self._p_t, self._phitm_t, np.zeros(k),
               np.zeros_like(self._s_ext), self._decay, self._phi, self._gaps.has, self._n_n, self._compiled_prm,
               np.empty(compiled_step.OUT_SIZE), np.zeros_like(self._src.c_used), np.zeros_like(self._src.active),
               np.zeros_like(self._src.sums), np.zeros(k))
        except Exception as exc:  # numba's import, typing or compilation: numpy still works
            reason = f"{type(exc).__name__}: {exc}"
            compiled_step.disable(reason)
            warnings.warn(f"the compiled exploration step is unavailable, running numpy ({reason})",
                          RuntimeWarning, stacklevel=3)
            return None
        return fn

    def _compiled_step(self, i: int, x: np.ndarray, cand: np.ndarray) -> ExplorationCommand | None:
        """The walking step of agent i compiled (:mod:`.compiled_step`), or None (nothing changed) for a
        case the compiled step leaves to the numpy step: a degenerate fit, a scan edge with a hop across a
        hole in reach, or a vanishing gradient."""
        agent = self._agents[i]
        out = self._compiled_out
        try:
            status = self._walk_compiled(
                self._points, cand, x, np.array(self._nrm_t[i]), agent.velocity, self._cov, self._cov_sum,
                self._tidx, self._tpos, self._p_t, self._phitm_t, self._coef, self._s_ext, self._decay, self._phi,
                self._gaps.has, self._n_n, self._compiled_prm, out, self._src.c_used, self._src.active,
                self._src.sums, self._dcoef,
            )
        except Exception as exc:  # e.g. numba failing to type arguments it has not seen: numpy goes on
            self._walk_compiled = None
            warnings.warn(f"the compiled exploration step failed, this explorer runs numpy from now on "
                          f"({type(exc).__name__}: {exc})", RuntimeWarning, stacklevel=4)
            return None
        if status != compiled_step.OK:
            return None
        self.compiled_steps += 1
        o = out.copy()  # the command, the agent and the explorer keep views of this one copy
        n_out = tuple(o[6:9].tolist())
        n_side = self._outward_side(n_out, int(o.item(19)))
        if n_side is not n_out:
            o[6:9] = n_side
            o[9:15] = tangent_floats(*n_side)
        agent.velocity = o[15:18]
        self.path_lengths[i] = self.path_lengths.item(i) + o.item(18)
        self._near[i] = int(o.item(19))
        self._cov_sum = o.item(20)
        self._nrm_t[i] = tuple(o[6:9].tolist())
        self._x[i] = o[:3]
        return ExplorationCommand(o[:3], o[3:6], o[6:9], o[9:12], o[12:15], self.step_count, i)
