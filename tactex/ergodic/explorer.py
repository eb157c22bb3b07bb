"""HEDAC spectral ergodic exploration on a point cloud (TEC eq. 1–6, §IV-A).

One step for each agent:

1. the n_N nearest cloud points of the agent and those within the footprint radius, from the
   precomputed ball of the cloud point nearest to the agent one step earlier (exact: the agent
   moves at most one voxel per step; measured positions go through the K-D tree);
2. the sphere-or-plane fit of eq. 23–26 and the agent's projection onto it (eq. 27), with the
   normal line (eq. 28) and tangent plane (eq. 29);
3. coverage: the Gaussian footprint φ(r) = exp(−ε² r²) (eq. 30) of the footprint points,
   with r measured on the tangent plane (eq. 31), added to the coverage sum c̃ (eq. 3);
4. source s = max(p̂ − c, 0)² with p̂ and c normalised (eq. 1–2, s scaled to unit sum; c over
   the target's support by default, see ``HedacConfig.coverage_normalization``),
   injected into the spectral coefficients of the potential, which then diffuse by e^{−λ δt},
   δt = α h² (eq. 19–21): a ← e^{−λδt} ⊙ (a + Φᵀ M s), u = Φ a + w_s·s. The potential carries
   the heat of past sources, as in eq. 19 and the authors' released code; u(x, 0) = p̂ (eq. 5).
   With ``HedacConfig.cooling`` β > 0 the decay is e^{−(λδt + β)}: per step u̇ = αh²Δu − βu + s,
   whose steady state, δt Δu − βu + s = 0, has eq. 4's screened form (β is a rate per step, tuned;
   eq. 4 written in these units would be β = 1 with α h² in place of α).
   Diffusing *after* injecting matters: the truncated projection of a sharp source rings
   (Gibbs) and spurious maxima trap the agent, its heat-kernel image does not; the raw source
   (weight ``source_weight``) restores the full resolution at the target points;
5. the gradient of u on the tangent plane: the weighted cubic fit (eq. 32–33) of the diffused
   part Φ a, plus the weighted plane fit of the raw source term w_s·s (a cubic through the
   isolated source spikes at the rim of the neighbourhood overshoots and points away from them);
6. the agent's velocity update (first or second order, limits kept, see :mod:`.agents`), the
   new point projected back onto the fitted surface, the step clamped to v_max·dt.

Scan edges (eq. 5's Neumann boundary): where the neighbours' centroid lies well inside the
tangent plane the outward part of the gradient is dropped, so the agent follows the edge; a step
that would leave the cloud loses its outward velocity, and the agent never strays farther than
``max_off_cloud`` voxels from the nearest cloud point (it still lies on the fitted surface).

Cost per step is independent of N and of the target's size where it matters: Φᵀ M s is kept as
running sums over the target rows (:mod:`.source`) that change only where the footprint did, so a
step costs O(footprint · K) plus an O(n_target) scalar pass; u is only needed at the n_N
neighbours (Φ[nbrs] @ a). The coverage sum and its total are kept incrementally.

With the whole surface as the target (or ``HedacConfig.source_mode = "sweep"``) the source of step 4
is the sweep source of :mod:`.sweep` instead of eq. 1–2: every target point not yet passed over,
weighted up next to covered ground, so that every point is passed over once in passes (numpy step).
With one agent and ``HedacConfig.sweep_pass_spacing`` > 0 the sweep also plans its passes
(:mod:`.passes`): the agent steers along rings of surface distance from where it starts, laid side by
side, instead of up the potential's slope, stepping aside to what they miss and touching the specks they
pass (small parts across a hop), and the sweep source's potential leads it over whatever the passes missed
once its part has no pass left.

When walking makes no progress (the agent's Laplacian part holds no untouched target, it stalls,
or it touches nothing new for long) the step is a relocation instead (:mod:`.relocation`): the agent
lifts off, flies and touches down at untouched target elsewhere. Keep-out zones (``keep_out``) hold
no target, and the agent's point stays a footprint radius plus half a voxel away from them.

Starting and measured positions farther than ``max_snap_distance`` voxels from the cloud are
rejected with :class:`~tactex.errors.ExplorationError` (a robot that far from the surface is not
in contact, and a silent snap would hide it); nearer ones are projected onto the surface.
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import replace

import numpy as np
from scipy.linalg.lapack import dposv as _dposv
from scipy.sparse import coo_matrix
from scipy.spatial import cKDTree

from tactex.ergodic import kernel as _kernel
from tactex.ergodic.agents import Agent, make_agent
from tactex.ergodic.bridges import Bridge, gap_links
from tactex.ergodic.command import ExplorationCommand
from tactex.ergodic.config import HedacConfig
from tactex.ergodic.gradient import CUBIC_EXPONENTS, PLANE_PIVOT_RTOL, RIDGE_RTOL
from tactex.ergodic.kernel import plane_slope, project_floats, tangent_floats
from tactex.ergodic.metrics import coverage_residual, normalized_ergodicity
from tactex.ergodic.passes import RingPasses
from tactex.ergodic.relocation import ProgressMonitor, RelocationCommand, air_length, choose_touch_down
from tactex.ergodic.source import REBUILD_STEPS, SourceSums, update_source_numpy
from tactex.ergodic.sweep import SweepSource, sweeps
from tactex.errors import ConfigError, ExplorationError, InputError
from tactex.geometry.fit import SurfacePatch, fit_local_design, fit_sphere_or_plane
from tactex.pointcloud import SurfaceCloud

__all__ = ["HedacExplorer"]

_log = logging.getLogger(__name__)
#: The patch kinds :func:`~tactex.ergodic.kernel.project_floats` takes, by its code.
_PATCH_KINDS = {"sphere": 0, "plane": 1}
_Z = np.array([0.0, 0.0, 1.0])
# ndarray.dot and the ufunc reductions dispatch in a fraction of @ / np.dot / ndarray.sum's time on
# these tiny arrays (the step is ~130 numpy calls, their overhead is most of its cost), same results.
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
#: Steps between the samples of the agent's position for the stall rule (a multiple of them is a
#: stall: an agent sampled inside the stall circle every time), and between the checks of the untouched
#: target (part done, no progress) of the relocation rules: a few µs each, not paid every step.
STALL_SAMPLE_EVERY = 5
RELOCATION_CHECK_EVERY = 10
#: On a pass, untouched target points within this many footprint radii of the agent that the passes walked past
#: and none to come covers are touched at once (see HedacExplorer._missed) [-]: nearly all the points the passes
#: leave lie within 1.0–1.5 r_a of the agent's path (TEC bunny), their neighbouring passes being 1.8 r_a apart.
REPAIR_RADIUS = 2.0
#: A part of at most this many footprint discs of points is a speck, touched in passing (see _speck) [-].
SPECK_POINTS = 1.0
#: Steps an agent steers at one such point before it leaves it to the hunt [-].
REPAIR_STEPS = 6
#: A keep-out zone's clearance beyond the footprint radius [voxels]: the footprint is laid around the
#: agent projected on its fitted patch, a fraction of a voxel from the agent point the guard checks.
KEEP_OUT_MARGIN = 0.5
#: A planned pass's waypoint is given up when the scan edge leaves less than this share of the way to it [-].
EDGE_BLOCKED = 0.2
#: A planned pass's waypoint is done once the agent came this close [voxels] (see :mod:`.passes`): the agent goes on
#: along its pass instead of working its way onto each waypoint (at the scan's rim, where it dithers at the off-cloud
#: limit, it cannot); what the footprint then leaves beside the pass it steps aside to.
PASS_REACH = 2.5
#: Passes of a step (see step_all): one agent does all of it; several agents lay their footprints
#: first, then (after one diffusion) move.
_WHOLE, _FOOTPRINT, _MOVE = 0, 1, 2


def _read_only(a: np.ndarray) -> np.ndarray:
    view = a.view()
    view.setflags(write=False)
    return view


def _tangent_matrix(n: np.ndarray | tuple) -> np.ndarray:
    """(3, 2) orthonormal tangent basis [t_u, t_v] with (t_u, t_v, n) right-handed (n an array or 3 floats)."""
    return _tangent_matrix_0uv(n)[:, 1:]


def _tangent_matrix_0uv(n: np.ndarray | tuple) -> np.ndarray:
    """(3, 3) [0, t_u, t_v]: :func:`_tangent_matrix` after a zero column (offsets · it = rows (0, u, v))."""
    a0, a1, a2, b0, b1, b2 = tangent_floats(*(n if isinstance(n, tuple) else n.tolist()))
    return np.array([[0.0, a0, b0], [0.0, a1, b1], [0.0, a2, b2]])


def _tangent_basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    t = _tangent_matrix(n)
    return t[:, 0].copy(), t[:, 1].copy()


def _plane_slope(a00: float, a01: float, a02: float, a11: float, a12: float, a22: float,
                 b0: float, b1: float, b2: float) -> tuple[float, float] | None:
    """:func:`~tactex.ergodic.kernel.plane_slope` (c_u, c_v), or None when the block is not positive
    definite (collinear points)."""
    ok, c_u, c_v = plane_slope(a00, a01, a02, a11, a12, a22, b0, b1, b2, PLANE_PIVOT_RTOL)
    return (c_u, c_v) if ok else None


def _project_floats(patch: SurfacePatch, x: tuple, ref: tuple) -> tuple[tuple, tuple]:
    """:func:`_project_local` on Python floats: x and ref are 3-tuples, so are the point and normal.

    Sphere and plane (the per-step cases) in Python floats (:func:`~tactex.ergodic.kernel.project_floats`,
    which the compiled step shares): three numbers do not pay numpy's per-call overhead; the other
    kinds, and a point at a sphere's centre, go through :meth:`SurfacePatch.project`.
    """
    kind = _PATCH_KINDS.get(patch.kind)
    if kind is not None:
        ok, p0, p1, p2, n0, n1, n2 = project_floats(
            kind, *patch.center.tolist(), patch.radius, *patch.direction.tolist(), *x, *ref
        )
        if ok:
            return (p0, p1, p2), (n0, n1, n2)
    refa = np.array(ref)
    p, n = patch.project(np.array(x), refa)
    return tuple(p.tolist()), tuple((n if float(n @ refa) >= 0.0 else -n).tolist())


def _project_local(patch: SurfacePatch, x: np.ndarray, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closest point of the patch to x and the unit normal there, oriented along ``ref``."""
    p, n = _project_floats(patch, tuple(x.tolist()), tuple(ref.tolist()))
    return np.array(p), np.array(n)


class HedacExplorer:
    """Spectral HEDAC on a :class:`SurfaceCloud` with a Laplace eigenbasis.

    Args:
        cloud: the surface and its target mass (``cloud.target``, must hold mass somewhere).
        basis: a :class:`tactex.spectral.LaplaceBasis` of ``cloud`` (anything with ``mass`` (N,),
            ``evals`` (K,), ``evecs`` (N, K) M-orthonormal, ``spacing`` [m]).
        config: :class:`HedacConfig`.
        keep_out: optional boolean mask (N,) of cloud points no footprint may touch (a sticker, a
            sensor): they hold no target, and every agent keeps its point at least r_a + ½ voxel
            from them (its step slides along the zone or stops; a stop is a stall, and the agent
            relocates). ``keep_out_contacts`` counts kept-out points a footprint touched anyway.

    Relocation (``config.relocate``, :mod:`.relocation`): when walking makes no progress, ``step``
    returns a :class:`~tactex.ergodic.relocation.RelocationCommand` (lift off, fly, touch down)
    instead of an :class:`ExplorationCommand`, and the agent jumps to the touch-down point.
    """

    def __init__(self, cloud: SurfaceCloud, basis, config: HedacConfig | None = None,
                 keep_out: np.ndarray | None = None) -> None:
        self.config = config if config is not None else HedacConfig()
        if not isinstance(self.config, HedacConfig):
            raise ConfigError(f"config must be a HedacConfig, got {type(self.config).__name__}")
        if not isinstance(cloud, SurfaceCloud):
            raise InputError(f"cloud must be a SurfaceCloud, got {type(cloud).__name__}")
        n = len(cloud)
        evecs = np.asarray(basis.evecs, dtype=np.float64)
        if evecs.shape[0] != n:
            raise InputError(f"the basis has {evecs.shape[0]} points but the cloud {n}; build it from this cloud")
        if evecs.shape[1] < self.config.n_eigen:
            raise ConfigError(
                f"HedacConfig.n_eigen = {self.config.n_eigen} but the basis holds {evecs.shape[1]} eigenpairs; "
                "build the basis with at least n_eigen pairs or lower n_eigen"
            )
        if n < self.config.n_neighbors_fit:
            raise ExplorationError(
                f"the cloud has {n} points, fewer than n_neighbors_fit = {self.config.n_neighbors_fit}"
            )
        k = self.config.n_eigen
        self.cloud = cloud
        self.basis = basis
        # Read-only views whatever the caller's arrays: the compiled step is typed by its arguments'
        # flags too, and one set of types means one compilation.
        self._points = _read_only(cloud.points)
        self._phi = _read_only(np.ascontiguousarray(evecs[:, :k]))
        self._mass = np.asarray(basis.mass, dtype=np.float64)
        self._evals = np.asarray(basis.evals, dtype=np.float64)[:k]
        self.spacing = float(getattr(basis, "spacing", 0.0) or cloud.spacing)
        self._tree = cKDTree(self._points)
        cfg = self.config
        self._r_a = cfg.agent_radius_m
        self._eps2 = (cfg.footprint_sharpness / cfg.agent_radius_m) ** 2
        self._dt = cfg.step_duration_s
        self._v_max = cfg.max_velocity * self.spacing / self._dt
        self._step_max = cfg.max_velocity * self.spacing
        self._snap = cfg.max_snap_distance * self.spacing
        self._r_a2 = self._r_a**2
        self._off2 = (cfg.max_off_cloud * self.spacing) ** 2
        self._off = cfg.max_off_cloud * self.spacing
        self._source_w = float(cfg.source_weight)
        self._norm_target = cfg.coverage_normalization == "target"
        self._edge_braking = cfg.edge_braking
        self._n_n = cfg.n_neighbors_fit
        self._n_n1 = cfg.n_neighbors_fit - 1
        self._xf = np.ones((cfg.n_neighbors_fit, 10))
        xf = self._xf
        self._xf_lin, self._xf_quad, self._xf_cube = xf[:, 1:3], xf[:, 3:6], xf[:, 6:10]
        self._xf_uu, self._xf_vv = xf[:, 3], xf[:, 5]
        self._wt_col = np.empty((cfg.n_neighbors_fit, 1))  # the cubic's weights, as a column and flat
        self._wt = self._wt_col[:, 0]
        self._xw = np.empty((cfg.n_neighbors_fit, 10))  # the weighted monomials and their transpose
        self._xwt = self._xw.T
        self._a = np.empty((10, 10))  # the cubic's normal matrix, with a view of its diagonal
        self._a_diag = self._a.ravel()[::11]
        self._w = np.full((cfg.n_neighbors_fit, 5), -1.0)  # the fit's design matrix, column 3 stays −1
        self._w_q, self._w_sq = self._w[:, :3], self._w[:, 4]
        self._build_neighbourhoods()
        laplacian = getattr(basis, "L", None)  # a duck-typed basis without it: no hops
        self._bridge_max2 = (cfg.max_bridge * self.spacing) ** 2
        self._gaps = gap_links(self._points, laplacian, self._tree, self._off, cfg.max_bridge * self.spacing)
        self._bridges: list[Bridge | None] = []
        self._near = np.zeros(0, dtype=np.intp)
        self._rng = np.random.default_rng(cfg.seed)
        self._labels = self._part_labels(basis, n)
        self._set_keep_out(keep_out)
        self._decay_alpha = np.nan
        self._decay = np.ones(k)
        self._set_target(cloud.target)
        self._kernel_out = np.empty(_kernel.OUT_SIZE)
        self._kernel_prm = _kernel.params(
            agent_radius_m=self._r_a, eps2=self._eps2, source_weight=self._source_w,
            max_acceleration=cfg.max_acceleration * self.spacing / self._dt**2, max_velocity=self._v_max,
            max_step_m=self._step_max, dt=self._dt, max_off_m=self._off, edge_offset=EDGE_OFFSET,
            normalize_by_target=self._norm_target, order=cfg.order, edge_braking=cfg.edge_braking,
        )
        # The compiled step forms eq. 1–2's source itself: the sweep source runs the numpy step.
        self._walk_kernel = self._compile_kernel() if cfg.compiled and self._sweep is None else None
        self._agents: list[Agent] = []
        self._x = np.zeros((0, 3))
        self._nrm_t: list[tuple] = []  # each agent's unit normal as a float triple (the step reads these)
        self.step_count = 0
        self.bridges_taken = 0
        self._pass = _WHOLE
        self.compiled_steps = 0  # agent steps the compiled kernel took (the rest ran in numpy)
        self._monitors: list[ProgressMonitor] = []
        self._relocating = cfg.relocate
        self.relocations: list[RelocationCommand] = []
        self.air_path_lengths = np.zeros(0)

    # ------------------------------------------------------------------ parts and keep-out zones
    @staticmethod
    def _part_labels(basis, n: int) -> np.ndarray:
        """Connected part (N,) of each point as the basis' Laplacian links them (all 0 without one)."""
        if hasattr(basis, "component_labels") and getattr(basis, "L", None) is not None:
            return np.asarray(basis.component_labels(), dtype=np.intp)
        return np.zeros(n, dtype=np.intp)

    def _set_keep_out(self, keep_out: np.ndarray | None) -> None:
        n = len(self.cloud)
        if keep_out is None:
            mask = np.zeros(n, dtype=bool)
        else:
            mask = np.asarray(keep_out)
            if mask.shape != (n,) or mask.dtype != bool:
                raise InputError(f"keep_out must be a boolean mask of shape ({n},) (one per cloud point), "
                                 f"got {mask.dtype} {mask.shape}")
            mask = mask.copy()
        if mask.all():
            raise InputError("the keep-out zone marks every cloud point: nothing may be touched; mark fewer points "
                             "(--keep-out-threshold, --keep-out-mask)")
        self._keep_out = mask
        self._ko_idx = np.flatnonzero(mask)
        self._ko_clear = self._r_a + KEEP_OUT_MARGIN * self.spacing
        if self._ko_idx.size:
            self._ko_tree = cKDTree(self._points[self._ko_idx])
            self._ko_dist = self._ko_tree.query(self._points)[0]
        else:
            self._ko_tree = None
            self._ko_dist = np.full(n, np.inf)
        # Agent points near cloud point j are surely clear when j is this much farther than the
        # clearance: the agent is at most a step plus max_off_cloud from its nearest point.
        self._ko_sure = self._ko_clear + 2.0 * (self._step_max + self._off) + self.spacing
        self._safe = self._ko_dist >= self._ko_clear

    @property
    def keep_out(self) -> np.ndarray:
        """The kept-out cloud points (N,) (bool)."""
        return self._keep_out.copy()

    @property
    def clear_points(self) -> np.ndarray:
        """Cloud points (N,) (bool) an agent may stand on: at least r_a + ½ voxel from every kept-out point."""
        return self._safe.copy()

    @property
    def keep_out_clearance_m(self) -> float:
        """Least distance [m] between the agent and a kept-out point: footprint radius + ½ voxel."""
        return self._ko_clear

    @property
    def keep_out_contacts(self) -> int:
        """Kept-out cloud points inside a footprint so far (0 unless something is wrong)."""
        self._require_state()
        return int(np.count_nonzero(self._cov.take(self._ko_idx) > 0.0)) if self._ko_idx.size else 0

    def _clear_of_keep_out(self, x: np.ndarray, near: int) -> bool:
        if self._ko_tree is None or self._ko_dist.item(near) >= self._ko_sure:
            return True
        return float(self._ko_tree.query(x)[0]) >= self._ko_clear

    # ------------------------------------------------------------------ target and state
    def _set_target(self, mass: np.ndarray) -> None:
        p = np.asarray(mass, dtype=np.float64)
        if p.shape != (len(self.cloud),):
            raise InputError(f"target mass must have shape ({len(self.cloud)},), got {p.shape}")
        if not np.all(np.isfinite(p)) or p.min() < 0:
            raise InputError("target mass must be finite and ≥ 0 everywhere")
        near_count = 0
        if self._ko_idx.size:
            if float(p.sum()) > 0 and not p[~self._keep_out].any():
                raise ExplorationError(
                    "every target point is kept out (keep-out zone): nothing may be touched; shrink the keep-out "
                    "zone (--keep-out-threshold, --keep-out-mask) or mark other target points"
                )
            # Target closer to the zone than the clearance is no goal: the agent may not stand there, and the
            # relocations and the passes touch down and walk only where it may. It is left out of the target
            # (and so of the coverage residual) rather than left to attract the potential to the zone's edge.
            near = (p > 0) & ~self._keep_out & ~self._safe
            if near.any() and not p[self._safe].any():
                raise ExplorationError(
                    f"every target point lies in the keep-out zone or within {self._ko_clear * 1e3:.1f} mm of it "
                    "(footprint radius + ½ voxel): a footprint there would touch the zone; shrink the keep-out zone "
                    "(--keep-out-threshold, --keep-out-mask) or mark target farther from it"
                )
            near_count = int(np.count_nonzero(near))
            p = np.where(self._safe, p, 0.0)
        total = float(p.sum())
        if total <= 0:
            raise ExplorationError(
                "the target has no mass (all zeros): nothing to explore; mark target points first "
                "(e.g. tactex.pointcloud.target_from_channel)"
            )
        self.target_near_keep_out = near_count
        self._target = p
        self._tidx = np.flatnonzero(p > 0)
        self._p_t = p[self._tidx] / total
        self._tpos = np.full(len(p), -1, dtype=np.intp)
        self._tpos[self._tidx] = np.arange(self._tidx.size)
        # Rows of Φᵀ M restricted to the target: s vanishes elsewhere.
        self._phitm_t = np.ascontiguousarray(self._phi[self._tidx] * self._mass[self._tidx, None])
        # The source on the target rows, with a trailing 0 so that s_ext[tpos] is the source at any
        # cloud point (tpos = −1 off the target) without a mask.
        self._s_ext = np.zeros(self._tidx.size + 1)
        self._s_t = self._s_ext[:-1]
        # Target points a footprint may touch (clear of the keep-out zones), and their parts.
        self._t_safe = self._safe[self._tidx]
        self._t_part = self._labels[self._tidx]
        self._src = SourceSums(self._tidx.size, self._phi.shape[1])
        self._dcoef = np.zeros(self._phi.shape[1])
        cfg = self.config
        sweep = sweeps(cfg.source_mode, self._target, ~self._safe)
        self._sweep = SweepSource(self._points[self._tidx], self._p_t, cfg.sweep_plan_ratio * self._r_a,
                                  cfg.sweep_frontier_ratio * self._r_a, cfg.sweep_base) if sweep else None
        self._passes = None
        if sweep and cfg.sweep_pass_spacing > 0.0:
            laplacian = getattr(self.basis, "L", None)
            links = None if laplacian is None else laplacian.tocsr()[self._tidx][:, self._tidx]
            self._passes = RingPasses(self._points[self._tidx], links, cfg.sweep_pass_spacing * self._r_a,
                                      PASS_REACH * self.spacing, self.spacing, allowed=self._t_safe,
                                      origin=cfg.sweep_pass_origin, footprint_m=self._r_a, hops=self._target_hops())
        if hasattr(self, "_walk_kernel"):  # a new target may switch a running explorer between the sources
            if sweep:
                self._walk_kernel = None
            elif cfg.compiled and self._walk_kernel is None:
                self._walk_kernel = self._compile_kernel()

    def _target_hops(self) -> coo_matrix | None:
        """The gap links (hops, :mod:`.bridges`) between target points clear of the keep-out zones, as a (T, T) matrix
        of target positions, or None without any."""
        g = self._gaps
        if not g.n_links:
            return None
        src = np.repeat(np.arange(len(self._points)), np.diff(g.ptr))
        a, b = self._tpos[src], self._tpos[g.far]
        ok = (a >= 0) & (b >= 0)
        a, b = a[ok], b[ok]
        ok = self._t_safe[a] & self._t_safe[b]
        a, b = a[ok], b[ok]
        if a.size == 0:
            return None
        t = self._tidx.size
        return coo_matrix((np.ones(a.size), (a, b)), shape=(t, t))

    def _reset_fields(self) -> None:
        n = len(self.cloud)
        self._cov = np.zeros(n)
        self._cov_sum = 0.0
        self._coef = self._p_t @ self._phitm_t  # u(x, 0) = p̂ (eq. 5)
        self._s_ext[:] = 0.0
        self._src.clear()
        if self._sweep is not None:
            self._sweep.reset()
        if self._passes is not None:
            self._passes.reset()
        self._leftover_goal = -1
        self._on_speck = False  # the agent on a pass steers at a speck (see _speck)
        self._hop_to = -1  # cloud index the hunt hops to this step (see _leftover), or −1
        self._hop_goal = -1  # the hunt's goal (target index) that hop is on the way to
        self._given_up = np.zeros(self._tidx.size, dtype=bool)
        self._repair_failed = np.zeros(self._tidx.size, dtype=bool)  # a pass's step aside to it did not touch it
        self._repair_steps: dict[int, int] = {}

    def reset(self, x0: np.ndarray) -> list[ExplorationCommand]:
        """Start the agents at x0 (3,) or (n_agents, 3) [m]; each is projected onto the surface.

        Clears coverage, potential and path length. Returns each agent's starting command.
        """
        x = np.asarray(x0, dtype=np.float64)
        if x.ndim == 1:
            x = x[None, :]
        if x.ndim != 2 or x.shape[1] != 3 or x.shape[0] < 1:
            raise InputError(f"x0 must have shape (3,) or (n_agents, 3), got {np.shape(x0)}")
        if not np.all(np.isfinite(x)):
            raise InputError(f"x0 holds NaN/inf: {x.tolist()}")
        for i, xi in enumerate(x):  # every start checked before any state changes: a refused reset keeps the run
            self._check_distance(xi, "x0" if x.shape[0] == 1 else f"x0[{i}]")
        cfg = self.config
        self._agents = [
            make_agent(cfg.order, self._v_max, cfg.max_acceleration * self.spacing / self._dt**2, self._dt)
            for _ in range(x.shape[0])
        ]
        self._reset_fields()
        self._x = np.zeros((x.shape[0], 3))  # C order whatever x0's: the compiled step takes its rows
        self._nrm_t = [(0.0, 0.0, 0.0)] * x.shape[0]
        self._bridges = [None] * x.shape[0]
        self.path_lengths = np.zeros(x.shape[0])
        self.air_path_lengths = np.zeros(x.shape[0])
        self.relocations = []
        self.bridges_taken = 0
        self.compiled_steps = 0
        self._near = np.zeros(x.shape[0], dtype=np.intp)
        self.step_count = 0
        out = []
        for i, xi in enumerate(x):
            nb = self._tree.query(xi, k=self.config.n_neighbors_fit)[1]
            self._near[i] = int(nb[0])
            patch = fit_sphere_or_plane(self._points[nb], validate=False)
            p, nrm = _project_local(patch, xi, self._initial_normal(xi))
            self._x[i] = p
            self._nrm_t[i] = tuple(nrm.tolist())
            t1, t2 = _tangent_basis(nrm)
            out.append(ExplorationCommand(p.copy(), np.zeros(3), nrm.copy(), t1, t2, 0, i))
        if not cfg.relocate:
            for i, p in enumerate(self._x):
                if not self._clear_of_keep_out(p, int(self._near[i])):
                    raise ExplorationError(
                        f"the start {np.round(p, 4).tolist()} m lies within {self._ko_clear * 1e3:.1f} mm (footprint "
                        "radius + ½ voxel) of a keep-out point; start elsewhere, or let the explorer relocate off "
                        "it (relocation is off: HedacConfig.relocate)"
                    )
        self._monitors = [
            ProgressMonitor(p, 0, cfg.stall_radius * self.spacing, cfg.stall_steps, cfg.progress_steps) for p in self._x
        ]
        return out

    def _initial_normal(self, x: np.ndarray) -> np.ndarray:
        """Outward side: the cloud's normal at the nearest point when it has normals, else +z (up)."""
        if self.cloud.normals is not None:
            return self.cloud.normals[int(self._tree.query(x)[1])].copy()
        return _Z.copy()

    def _check_distance(self, x: np.ndarray, name: str) -> float:
        d = float(self._tree.query(x)[0])
        if d > self._snap:
            raise ExplorationError(
                f"{name} = {np.round(x, 4).tolist()} m is {d * 1e3:.1f} mm from the nearest cloud point, farther "
                f"than max_snap_distance = {self.config.max_snap_distance:g} voxels ({self._snap * 1e3:.1f} mm); "
                "start on (or just above) the surface, or raise HedacConfig.max_snap_distance"
            )
        return d

    def update_target(self, mass: np.ndarray, keep_coverage: bool = False) -> None:
        """Replace the target mass (N,) while running (vision feedback); the basis is kept.

        By default a new exploration cycle starts: coverage and potential restart from the new
        target (the old coverage would hide dirt that is still there). ``keep_coverage=True``
        keeps the accumulated coverage and the diffused potential.
        """
        self._set_target(mass)
        # A hop in progress goes on to the far side of its hole: dropped, it left the agent mid-air,
        # up to 2.7 voxels off the cloud and walking from a neighbourhood that held 5 of its 20 points.
        if not keep_coverage or not hasattr(self, "_cov"):
            if self._agents:
                self._reset_fields()
        else:
            self._s_ext[:] = 0.0

    # ------------------------------------------------------------------ stepping
    @property
    def source_mode(self) -> str:
        """The source term in use: 'sweep' (:mod:`.sweep`) or 'ergodic' (eq. 1–2); HedacConfig.source_mode
        'auto' resolved for the current target."""
        return "sweep" if self._sweep is not None else "ergodic"

    @property
    def planned_passes(self) -> bool:
        """Whether the sweep walks planned passes (:mod:`.passes`; HedacConfig.sweep_pass_spacing > 0, one agent)."""
        return self._passes is not None and self.n_agents <= 1

    @property
    def compiled(self) -> bool:
        """Whether the walking steps run compiled (numba, :mod:`.kernel`) rather than in numpy."""
        return self._walk_kernel is not None

    @property
    def n_agents(self) -> int:
        return len(self._agents)

    def step(self, measured_position: np.ndarray | None = None) -> ExplorationCommand:
        """One exploration step of a single agent; ``measured_position`` (3,) [m], e.g. the robot's
        TCP, replaces the virtual agent's position first (closed loop)."""
        if self.n_agents != 1:
            raise ExplorationError(
                f"step() drives one agent but {self.n_agents} are running; call reset() first or use step_all()"
            )
        return self.step_all(None if measured_position is None else np.asarray(measured_position)[None, :])[0]

    def step_all(self, measured_positions: np.ndarray | None = None) -> list[ExplorationCommand]:
        """One exploration step of every agent (they share the coverage, eq. 3)."""
        if not self._agents:
            raise ExplorationError("the explorer has no agent: call reset(x0) first")
        if measured_positions is not None:
            m = np.asarray(measured_positions, dtype=np.float64)
            if m.shape != self._x.shape:
                raise InputError(f"measured positions must have shape {self._x.shape}, got {m.shape}")
            if not np.all(np.isfinite(m)):
                raise InputError(f"measured position holds NaN/inf: {m.tolist()}")
            for i, mi in enumerate(m):
                self._check_distance(mi, "measured position" if m.shape[0] == 1 else f"measured position {i}")
            self._x = m.copy()
        self._update_decay()
        if self.step_count % REBUILD_STEPS == 0:
            self._src.clear()  # the running source sums restart from the direct sum: no drift builds up
        exact = measured_positions is not None
        before = self._x.copy() if self._ko_tree is not None else None
        moves = None
        if self._relocating and self.step_count % STALL_SAMPLE_EVERY == 0:
            moves = [self._relocation_due(i) for i in range(self.n_agents)]
            if not any(m is not None for m in moves):
                moves = None
        if moves is not None:
            cmds = self._step_with_relocations(moves, exact)
        elif self.n_agents == 1:
            cmds = [self._step_agent(0, exact)]
        else:
            # Eq. 3 and 19 with several agents: every footprint of this step in the coverage first, one
            # source and one diffusion, then each agent follows that potential. (Stepping the agents one
            # after the other diffused the potential once per agent.) The compiled step walks one agent
            # at a time and is not used here.
            near = self._near.copy()
            self._pass = _FOOTPRINT
            try:
                for i in range(self.n_agents):
                    self._step_agent(i, exact)
                self._update_potential()
                self._near[:] = near  # the move pass starts from the same neighbourhoods
                self._pass = _MOVE
                cmds = [self._step_agent(i, exact) for i in range(self.n_agents)]
            finally:
                self._pass = _WHOLE
        if before is not None:
            cmds = [c if isinstance(c, RelocationCommand) else self._keep_out_guard(c, before[c.agent]) for c in cmds]
        if self._sweep is not None:
            for c in cmds:
                self._sweep.mark(c.point)
                if self._passes is not None:
                    self._passes.mark(c.point)
        self.step_count += 1
        return cmds

    # ------------------------------------------------------------------ relocation (lift-and-move)
    def _untouched(self) -> np.ndarray:
        """Per target point, True when no footprint has touched it yet and one may (clear of keep-out)."""
        return (self._cov.take(self._tidx) < self._p_t) & self._t_safe

    def _relocation_due(self, i: int) -> str | None:
        """Why agent i should relocate now (a :data:`~.relocation.RELOCATION_REASONS` entry), or None."""
        if self._bridges[i] is not None:
            return None
        mon = self._monitors[i]
        k = self.step_count
        mon.moved_to(self._x[i], k)
        if self._ko_tree is not None and not self._clear_of_keep_out(self._x[i], int(self._near[i])):
            return "keep_out"
        stalled = mon.stalled(k)
        if not stalled and k % RELOCATION_CHECK_EVERY:
            return None
        untouched = self._untouched()
        count = int(np.count_nonzero(untouched))
        if count == 0:
            mon.restart(self._x[i], k, 0)  # nothing left to touch: HEDAC goes on revisiting in place
            return None
        if stalled:
            return "stall"
        part = self._labels.item(int(self._near[i]))
        if not (untouched & (self._t_part == part)).any():
            return "part_done"
        if self.planned_passes and not self._walkable_left(untouched):
            return "part_done"  # what is left of the part lies across a gap the agent may not walk
        if mon.no_progress(count, k):
            return "no_progress"
        return None

    def _walkable_left(self, untouched: np.ndarray) -> bool:
        """Whether untouched target (T,) (bool) is left that the agent may walk to: on its part of the passes'
        graph (links ≤ 2 voxels, see :mod:`.passes`) and not given up (it stalled on the way, or the way led off
        a scan edge). A speck across a wider gap, e.g. a few scan points hanging below a rim, is reached by
        relocating."""
        j = self._tpos.item(self._near[0])
        if j < 0:
            return True  # off the target: the potential leads there
        return self._passes.touchable(j, untouched & ~self._given_up, self._r_a)

    def _step_with_relocations(self, moves: list[str | None], exact: bool) -> list:
        """One step in which some agents relocate; the others (and those with nowhere to go) walk."""
        out: list = [self._relocate(i, m) if m is not None else None for i, m in enumerate(moves)]
        walking = [i for i, c in enumerate(out) if c is None]
        if len(walking) == 1:
            out[walking[0]] = self._step_agent(walking[0], exact)
        elif walking:
            near = self._near.copy()
            self._pass = _FOOTPRINT
            try:
                for i in walking:
                    self._step_agent(i, exact)
                self._update_potential()
                self._near[:] = near
                self._pass = _MOVE
                for i in walking:
                    out[i] = self._step_agent(i, exact)
            finally:
                self._pass = _WHOLE
        return out

    def _relocate(self, i: int, reason: str) -> RelocationCommand | None:
        """Agent i lifts off, flies to the chosen untouched target and lands there at rest."""
        untouched = self._untouched()
        cand = self._tidx[untouched]
        x = self._x[i].copy()
        j = self._next_on_tour(i) if reason == "stall" else None
        on_tour = j is not None
        if j is None and reason == "stall" and self.planned_passes:
            # A stall in the hunt touches down where the walks and hops from here still reach target: that side is
            # finished before the flight to a part they do not reach, which is then the only one left (else the
            # flight lands there, and another brings the agent back for the rest).
            same = self._passes.reach_mask(self._tpos.item(self._near[i]), untouched & ~self._given_up)
            if same.any():
                j = choose_touch_down(self._points, self._tidx[same], self._p_t[same], x, self._r_a)
        if j is None:
            j = choose_touch_down(self._points, cand, self._p_t[untouched], x, self._r_a)
        mon = self._monitors[i]
        if j is None:
            mon.restart(x, self.step_count, 0)
            return None
        end = self._points[j].copy()
        n_end = self._touch_down_normal(j, np.array(self._nrm_t[i]))
        n_start = np.array(self._nrm_t[i])
        c = self.config.relocation_clearance_m
        air = air_length(x, n_start, end, n_end, c)
        self._x[i] = end
        self._nrm_t[i] = tuple(n_end.tolist())
        self._near[i] = j
        self._agents[i].velocity = np.zeros(3)
        self.air_path_lengths[i] += air
        if self._passes is not None:
            self._passes.drop_goal(abandon=reason == "stall", replan=not on_tour)
            if reason == "stall" and self._leftover_goal >= 0:
                self._given_up[self._leftover_goal] = True  # it stalled on the way: not a goal again
            self._leftover_goal = -1
        mon.restart(end, self.step_count, None)
        t1, t2 = _tangent_basis(n_end)
        cmd = RelocationCommand(end.copy(), np.zeros(3), n_end, t1, t2, self.step_count, i, x, n_start, c, air, reason)
        self.relocations.append(cmd)
        _log.info("agent %d relocates (%s) from %s to %s m, %.3f m through the air", i, reason,
                  np.round(x, 4).tolist(), np.round(end, 4).tolist(), air)
        return cmd

    def _next_on_tour(self, i: int) -> int | None:
        """Where a guided agent that stalled touches down: its tour's next waypoint past the one it stalled on
        (cloud index), if that is untouched (it hops the obstacle and goes on with the plan); else None."""
        if not self.planned_passes:
            return None
        t = self._tpos.item(self._near[i])
        if t < 0:
            return None
        passes = self._passes
        passes.drop_goal(abandon=True)
        g = passes.next_pending(t)
        while g >= 0 and self._cov.item(self._tidx.item(g)) >= self._p_t.item(g):
            passes.pending[g] = False  # touched already: a footprint passed over it
            g = passes.next_pending(t)
        return None if g < 0 else int(self._tidx.item(g))

    def _touch_down_normal(self, j: int, current: np.ndarray) -> np.ndarray:
        """Unit outward normal at cloud point j: the fitted patch's, oriented along the cloud's own normal
        when it has normals, else away from the cloud's centroid (a closed object) or, where that is
        ambiguous (an open sheet seen edge-on from its centroid), along the agent's current normal."""
        end = self._points[j]
        nb = self._tree.query(end, k=self._n_n)[1]
        if self.cloud.normals is not None:
            ref = self.cloud.normals[j]
        else:
            ref = current
            radial = end - self._points.mean(axis=0)
            rn = float(np.sqrt(radial @ radial))
            if rn > 0.0:
                _, probe = _project_local(fit_sphere_or_plane(self._points[nb], validate=False), end, radial / rn)
                if abs(float(probe @ radial)) > 0.3 * rn:
                    ref = radial / rn
        _, n = _project_local(fit_sphere_or_plane(self._points[nb], validate=False), end, ref)
        return n

    def _keep_out_guard(self, cmd: ExplorationCommand, x_old: np.ndarray) -> ExplorationCommand:
        """The step of cmd, kept clear of the keep-out zones: slid along the zone (its part towards the
        nearest kept-out point dropped), or not taken at all (the agent stops; a stop is a stall)."""
        i = cmd.agent
        x_new = cmd.point
        if self._clear_of_keep_out(x_new, int(self._near[i])):
            return cmd
        self._bridges[i] = None  # a hop towards a keep-out zone ends here
        _, q = self._ko_tree.query(x_new)
        away = x_old - self._points[self._ko_idx[q]]
        na = float(np.sqrt(away @ away))
        move = x_new - x_old
        step_old = float(np.sqrt(move @ move))
        x_fix = x_old.copy()
        if na > 0.0:
            away /= na
            slid = move - min(float(move @ away), 0.0) * away
            if self._clear_of_keep_out(x_old + slid, int(self._near[i])) and \
                    float(self._ko_tree.query(x_old + slid)[0]) >= self._ko_clear:
                x_fix = x_old + slid
        move = x_fix - x_old
        step = float(np.sqrt(move @ move))
        self.path_lengths[i] += step - step_old
        v = move * (1.0 / self._dt)
        v -= float(v @ cmd.normal) * cmd.normal
        self._agents[i].velocity = v
        self._x[i] = x_fix
        self._near[i] = int(self._tree.query(x_fix)[1])
        return cmd._replace(point=x_fix.copy(), velocity=v.copy())

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
        self._ball = [np.asarray(b, dtype=np.intp) for b in self._tree.query_ball_point(self._points, radius)]

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
        # The per-step hot path: every line is a few µs, so vector algebra reuses the squared
        # distances dd instead of recomputing them (|d − s|² = dd − 2 d·s + |s|²).
        if self._bridges[i] is not None:
            return self._bridge_step(i)
        x = self._x[i]
        cand = self._candidates(i, x, True) if exact else self._ball[self._near[i]]
        if self._walk_kernel is not None and self._pass == _WHOLE:
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
        (p0, p1, p2), nt = _project_floats(patch, (0.0, 0.0, 0.0), self._nrm_t[i])
        sf = (p0 * scale, p1 * scale, p2 * scale)  # the projected agent, agent-centred [m]
        shift, nrm = np.array(sf), np.array(nt)

        # Every candidate on the tangent plane at the projected agent (eq. 31), and the kernel
        # φ(r) = exp(−ε² r²) of eq. 30 there: the footprint is φ inside r_a (3D distance, so the
        # far side of a thin wall stays out), the raw source's plane fit weighs the whole ball by it.
        tb0 = _tangent_matrix_0uv(nt)
        tb = tb0[:, 1:]
        rel = d - shift
        g1uv = rel.dot(tb0)  # rows (0, u, v) [m]; column 0 becomes 1 below
        rel *= rel
        d2 = _sum(rel, 1)
        kern = g1uv * g1uv
        kern = _sum(kern, 1)
        kern *= -self._eps2
        np.exp(kern, kern)
        g1uv[:, 0] = 1.0
        tuv = g1uv[:, 1:]
        inside = (d2 <= self._r_a2).nonzero()[0]
        fp = cand.take(inside)
        phi = kern.take(inside)
        if self._pass != _MOVE:
            self._add_coverage(fp, phi)
            if self._pass == _FOOTPRINT:
                return None
            self._update_potential()
        u = self._phi.take(nbr, 0).dot(self._coef)

        # Gradient on the tangent plane (eq. 32–33): weighted cubic in scaled (u, v).
        uv = tuv.take(part, 0)
        uv *= inv
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
        guide = None
        if self._passes is not None and self._pass == _WHOLE and self.n_agents == 1:
            guide = self._pass_direction(x, sf, nrm)
            if self._hop_to >= 0:
                here = np.array((x.item(0) + sf[0], x.item(1) + sf[1], x.item(2) + sf[2]))
                bridge = self._hop_bridge(self._hop_to, here, nrm)
                self._hop_to = -1
                if bridge is not None:
                    self._bridges[i] = bridge
                    return self._bridge_move(i, x, bridge)
                self._given_up[self._hop_goal] = True  # the hop's far side faces away: not a goal again
                guide = None
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
                if guide is not None and float(g.dot(g)) < EDGE_BLOCKED**2 * float(guide.dot(guide)):
                    # the way leads off the edge (across a hole the agent cannot cross): give the goal up
                    if not self._on_speck:
                        self._passes.drop_goal(abandon=True)
                    if self._leftover_goal >= 0:
                        self._given_up[self._leftover_goal] = True
                        self._leftover_goal = -1
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
            # Shortening may cut a corner past the edge: halve until back within max_off_cloud.
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
        self._nrm_t[i] = n_new
        # the command's frame at the landing point: the tangent basis of its normal, the velocity's
        # tangential part (the step is a chord)
        u0, u1, u2, w0, w1, w2 = tangent_floats(m0, m1, m2)
        x_new, n_new = np.array((x0 + s0, x1 + s1, x2 + s2)), np.array(n_new)
        self._x[i] = x_new
        return ExplorationCommand(x_new, np.array(v_t), n_new, np.array((u0, u1, u2)), np.array((w0, w1, w2)),
                                  self.step_count, i)

    def _pass_direction(self, x: np.ndarray, shift: tuple, nrm: np.ndarray) -> np.ndarray | None:
        """Towards the next waypoint of the planned passes, on the tangent plane (3,), or None: no pass left
        on the agent's part (the potential leads)."""
        here = np.array((x.item(0) + shift[0], x.item(1) + shift[1], x.item(2) + shift[2]))
        passes = self._passes
        j = self._tpos.item(self._near[0])
        near = j if j >= 0 else passes.nearest(here)
        wp = passes.waypoint(here, near, self._untouched)
        if wp is not None and passes.heading_far:
            self._drop_speck()  # a speck is touched in passing, not on the way to a far arc
        elif wp is None:
            self._drop_speck()
            wp = self._leftover(here)
            if wp is None:
                return None
        else:
            open_ = self._untouched() & ~self._given_up  # once per step: both look at it
            speck = self._speck(here, near, open_)
            if speck is not None:
                wp = speck
            else:
                miss = self._missed(here, near, open_)
                if miss is not None:
                    wp = miss
        to = wp - here
        to -= float(to.dot(nrm)) * nrm
        return to if float(to.dot(to)) > 0.0 else None

    def _missed(self, here: np.ndarray, near: int, open_: np.ndarray | None = None) -> np.ndarray | None:
        """On a pass: the nearest untouched target point [m] (3,) within ``REPAIR_RADIUS`` footprint radii of the agent
        at ``here`` that the passes walked past and none to come covers (the agent's tracking error left it
        at the footprint's edge), or None. The agent steps aside to touch it now, a detour of a fraction of a
        footprint radius; the hunt after the passes would come back for it from afar. A point it steered at for
        ``REPAIR_STEPS`` steps without touching it (across a fold, off an edge) is given up here and left to the
        hunt. ``open_``: the untouched target not given up (T,) (bool), when the caller has it."""
        if open_ is None:
            open_ = self._untouched() & ~self._given_up
        cand = open_ & ~self._repair_failed
        passes = self._passes
        for g in passes.missed(here, near, cand, REPAIR_RADIUS * self._r_a).tolist():
            p = passes.point(g)
            if float(np.linalg.norm(p - here)) < 0.5 * self._r_a:
                continue  # under the footprint: touched as the agent goes on
            n = self._repair_steps.get(g, 0) + 1
            self._repair_steps[g] = n
            if n > REPAIR_STEPS:
                self._repair_failed[g] = True
                continue
            return p
        return None

    def _drop_speck(self) -> None:
        """The agent no longer steers at a speck: its goal is not the hunt's."""
        if self._on_speck:
            self._on_speck = False
            self._leftover_goal = -1

    def _speck(self, here: np.ndarray, near: int, open_: np.ndarray) -> np.ndarray | None:
        """On a pass: where the agent steers [m] (3,) on its way to an untouched speck (a part of at most
        ``SPECK_POINTS`` footprint discs that the hops join to the agent's) within ``REPAIR_RADIUS`` footprint radii
        of the agent at ``here``, or None. The agent touches it as it passes: the hunt after the passes would walk
        back for each speck from afar. ``open_``: the untouched target not given up (T,) (bool)."""
        passes = self._passes
        if not passes.has_specks:
            return None
        g = self._leftover_goal
        if self._on_speck and g >= 0 and open_[g]:
            return self._leftover(here)
        limit = SPECK_POINTS * np.pi * (self._r_a / self.spacing) ** 2
        specks = passes.specks(here, near, open_, REPAIR_RADIUS * self._r_a, limit)
        self._on_speck = bool(specks.any())
        self._leftover_goal = -1
        if not self._on_speck:
            return None
        return self._leftover(here, specks)

    def _leftover(self, here: np.ndarray, candidates: np.ndarray | None = None) -> np.ndarray | None:
        """After the passes (or, with ``candidates``, on a pass to a speck): where the agent steers [m] (3,) on its
        way to the untouched target point nearest by
        surface distance over its walking part and the hops from it (or a speck within a footprint radius of them),
        kept as the goal until a footprint touches it; None when none is left. At the near end of a hop on the way
        it sets ``_hop_to`` (the far end's cloud index): the step hops there along the chord."""
        g = self._leftover_goal
        passes = self._passes
        if not (g >= 0 and self._cov.item(self._tidx.item(g)) < self._p_t.item(g)):
            j = self._tpos.item(self._near[0])
            near = j if j >= 0 else passes.nearest(here)
            if candidates is None:
                candidates = self._untouched() & ~self._given_up
            g = passes.closest(near, candidates, self._r_a)
            self._leftover_goal = g
            if g < 0:
                return None
        aim = passes.route(here, g)
        hop = passes.hop_due(here)
        if hop >= 0:
            self._hop_to = int(self._tidx.item(hop))
            self._hop_goal = g
            self._leftover_goal = -1  # planned again from the far side
        return aim

    def _compile_kernel(self):
        """The compiled walking step (:mod:`.kernel`), or None (numpy) without numba or when it fails.

        It is called once here on a dummy state of this explorer's array types: numba makes (or loads
        from its cache) the machine code now, not in the middle of the first step of a control loop.
        """
        if not _kernel.available():
            return None
        n, k = len(self._points), self._phi.shape[1]
        try:
            fn = _kernel.compiled_walk_step()
            if fn is None:  # numba's JIT switched off (NUMBA_DISABLE_JIT)
                return None
            if not fn.signatures:  # the first explorer of this process: numba compiles or loads its cache
                _log.info("preparing the compiled exploration step (numba compiles it once per machine, ~10–15 s)")
            fn(self._points, self._ball[0], self._points[0].copy(), np.array((0.0, 0.0, 1.0)), np.zeros(3),
               np.zeros(n), 0.0, self._tidx, self._tpos, self._p_t, self._phitm_t, np.zeros(k),
               np.zeros_like(self._s_ext), self._decay, self._phi, self._gaps.has, self._n_n, self._kernel_prm,
               np.empty(_kernel.OUT_SIZE), np.zeros_like(self._src.c_used), np.zeros_like(self._src.active),
               np.zeros_like(self._src.sums), np.zeros(k))
        except Exception as exc:  # numba's import, typing or compilation: numpy still works
            reason = f"{type(exc).__name__}: {exc}"
            _kernel.disable(reason)
            warnings.warn(f"the compiled exploration step is unavailable, running numpy ({reason})",
                          RuntimeWarning, stacklevel=3)
            return None
        return fn

    def _compiled_step(self, i: int, x: np.ndarray, cand: np.ndarray) -> ExplorationCommand | None:
        """The walking step of agent i compiled (:mod:`.kernel`), or None (nothing changed) for a
        case the kernel leaves to the numpy step: a degenerate fit, a scan edge with a hop across a
        hole in reach, or a vanishing gradient."""
        agent = self._agents[i]
        out = self._kernel_out
        try:
            status = self._walk_kernel(
                self._points, cand, x, np.array(self._nrm_t[i]), agent.velocity, self._cov, self._cov_sum,
                self._tidx, self._tpos, self._p_t, self._phitm_t, self._coef, self._s_ext, self._decay, self._phi,
                self._gaps.has, self._n_n, self._kernel_prm, out, self._src.c_used, self._src.active,
                self._src.sums, self._dcoef,
            )
        except Exception as exc:  # e.g. numba failing to type arguments it has not seen: numpy goes on
            self._walk_kernel = None
            warnings.warn(f"the compiled exploration step failed, this explorer runs numpy from now on "
                          f"({type(exc).__name__}: {exc})", RuntimeWarning, stacklevel=4)
            return None
        if status != _kernel.OK:
            return None
        self.compiled_steps += 1
        o = out.copy()  # the command, the agent and the explorer keep views of this one copy
        agent.velocity = o[15:18]
        self.path_lengths[i] = self.path_lengths.item(i) + o.item(18)
        self._near[i] = int(o.item(19))
        self._cov_sum = o.item(20)
        self._nrm_t[i] = tuple(o[6:9].tolist())
        self._x[i] = o[:3]
        return ExplorationCommand(o[:3], o[3:6], o[6:9], o[9:12], o[12:15], self.step_count, i)

    def _source_slope(self, cand: np.ndarray, g1uv: np.ndarray, d2: np.ndarray) -> tuple[float, float] | None:
        """Slope (c_u, c_v) [1/m] of the plane through the raw source over the candidate ball
        (rows (1, u, v) of the candidates ``cand`` with tangent-plane coordinates u, v [m], squared
        3D distances ``d2`` [m²] from the projected agent), or None when there is no source there
        or the plane is degenerate.

        The weights are the kernel φ of the 3D distance, not of the tangent-plane distance: the
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
        kern = d2 * -self._eps2
        np.exp(kern, kern)
        wg = g1uv * kern[:, None]
        b0, b1, b2 = src.dot(wg).tolist()
        if not b0 > 0.0:
            return None
        (a00, a01, a02), (_, a11, a12), (_, _, a22) = wg.T.dot(g1uv).tolist()
        return _plane_slope(a00, a01, a02, a11, a12, a22, b0, b1, b2)

    # ------------------------------------------------------------------ scan-hole bridges
    def _plan_bridge(self, nbr: np.ndarray, u: np.ndarray, u0: float, here: np.ndarray,
                     nrm: np.ndarray) -> Bridge | None:
        """A hop along a gap link of the neighbours (see :mod:`.bridges`) when the potential at its
        far end beats every value around the agent (u − u0 at the neighbours, plus the raw source)."""
        far = np.unique(self._gaps.of(nbr))
        # The flight starts here, not at the neighbour the link leaves from: keep it within max_bridge.
        reach = self._points.take(far, 0) - here
        far = far[np.einsum("ij,ij->i", reach, reach) <= self._bridge_max2]
        if far.size == 0:
            return None
        u_far = self._phi.take(far, 0).dot(self._coef)
        local = u
        if self._source_w > 0.0:
            local = u + self._source_w * self._source_at(nbr)
            u_far += self._source_w * self._source_at(far)
        k = int(u_far.argmax())
        if float(u_far[k]) <= float(local.max()) + u0:
            return None
        return self._hop_bridge(int(far[k]), here, nrm)

    def _hop_bridge(self, j: int, here: np.ndarray, nrm: np.ndarray) -> Bridge | None:
        """A hop from ``here`` [m] (normal ``nrm``) to cloud point j across a gap link, or None when j's side faces the
        other way (the back of a part, not across a hole)."""
        end = self._points[j]
        nb = self._tree.query(end, k=self._n_n)[1]
        normals = self.cloud.normals
        ref = nrm if normals is None else normals[j]  # the cloud's own outward side when it has one
        _, end_normal = _project_local(fit_sphere_or_plane(self._points[nb], validate=False), end, ref)
        if float(end_normal @ nrm) < 0.0:
            return None
        self.bridges_taken += 1
        return Bridge(j, here.copy(), end.copy(), nrm.copy(), end_normal)

    def _bridge_step(self, i: int) -> ExplorationCommand:
        """One step of a hop in progress: the footprint where the agent is, the potential, then
        on along the chord."""
        bridge = self._bridges[i]
        x = self._x[i]
        if self._pass != _MOVE:
            nrm = bridge.normal_at(x)
            cand = self._ball[int(self._tree.query(x)[1])]
            d = self._points.take(cand, 0)
            d -= x
            dd = np.einsum("ij,ij->i", d, d)
            inside = (dd <= self._r_a2).nonzero()[0]
            dn = d.take(inside, 0).dot(nrm)
            phi = np.exp(-self._eps2 * (dd.take(inside) - dn * dn))  # r on the plane ⊥ the chord's normal
            self._add_coverage(cand.take(inside), phi)
            if self._pass == _FOOTPRINT:
                return None
            self._update_potential()
        return self._bridge_move(i, x, bridge)

    def _bridge_move(self, i: int, x: np.ndarray, bridge: Bridge) -> ExplorationCommand:
        """Move from x [m] (the agent, or the robot's measured point) along the chord towards the
        bridge's end, at most v_max·dt from x: the goal is x's projection on the chord advanced by
        v_max·dt, so an agent off the chord (a measured point above it, the unprojected agent at
        the start) converges to it instead of drifting. The agent's limits hold on the hop too:
        the velocity changes by at most a_max·dt per step, so a hop that starts across the
        agent's heading first bends towards the chord. On arrival the walk resumes from the end."""
        chord = bridge.end - bridge.start
        length = float(np.sqrt(chord @ chord))
        t = bridge.share(x)
        if (1.0 - t) * length <= self._step_max:
            goal = bridge.end
        else:
            goal = bridge.start + chord * (t + self._step_max / length)
        move = goal - x
        ml = float(np.sqrt(move @ move))
        arrived = goal is bridge.end and ml <= self._step_max
        if ml > self._step_max:
            move *= self._step_max / ml
            ml = self._step_max
        v, limited = self._agents[i].reachable_velocity(move * (1.0 / self._dt))
        if limited:
            move = v * self._dt
            ml = float(np.sqrt(move @ move))
            arrived = False
        x_new = x + move
        if arrived:
            x_new = bridge.end.copy()
            nrm = bridge.end_normal.copy()
            self._bridges[i] = None
            self._near[i] = bridge.target
        else:
            nrm = bridge.normal_at(x_new)
        v = move * (1.0 / self._dt)
        self._agents[i].velocity = v - float(v @ nrm) * nrm
        self.path_lengths[i] += ml
        self._nrm_t[i] = tuple(nrm.tolist())
        self._x[i] = x_new
        t1, t2 = _tangent_basis(nrm)
        return ExplorationCommand(x_new.copy(), v, nrm, t1, t2, self.step_count, i)

    # ------------------------------------------------------------------ coverage and potential
    def _source_at(self, idx: np.ndarray) -> np.ndarray:
        """The source s of the last step at cloud points idx (zero off the target)."""
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
            dcoef = self._s_t.dot(self._phitm_t) if self._sweep.source(self._s_t) > 0.0 else np.zeros_like(self._coef)
        else:
            norm = float(_sum(cov.take(self._tidx))) if self._norm_target else self._cov_sum
            dcoef = update_source_numpy(cov, self._tidx, self._p_t, norm, self._s_t, self._src, self._phitm_t)
        # Diffuse after adding the source: the truncated projection of a sharp source rings
        # (Gibbs), its heat-kernel image does not; the raw source is added back at full resolution.
        coef = self._coef
        coef += dcoef
        coef *= self._decay

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
        (x0, x1, x2), n_new = _project_floats(patch, ((s0 + v0 * dt) * k, (s1 + v1 * dt) * k, (s2 + v2 * dt) * k), nrm)
        x0, x1, x2 = x0 * scale, x1 * scale, x2 * scale
        ss = x0 * x0 + x1 * x1 + x2 * x2  # np.dot's order for three numbers
        dq2 = d.dot(np.array((2.0 * x0, 2.0 * x1, 2.0 * x2)))  # = 2 d·step exactly (×2 is exact)
        np.subtract(dd, dq2, dq2)
        dq2 += ss
        return (x0, x1, x2), n_new, ss, dq2, int(dq2.argmin())

    # ------------------------------------------------------------------ read-outs
    @property
    def positions(self) -> np.ndarray:
        """Agents' current points on the surface [m] (n_agents, 3)."""
        return self._x.copy()

    @property
    def path_length(self) -> float:
        """Total path travelled on the surface by all agents [m]."""
        return float(self.path_lengths.sum()) if self._agents else 0.0

    @property
    def air_path_length(self) -> float:
        """Total path of all agents' relocations through the air [m] (see RelocationCommand.air_length_m)."""
        return float(self.air_path_lengths.sum()) if self._agents else 0.0

    @property
    def total_path_length(self) -> float:
        """Surface plus air path of all agents [m]."""
        return self.path_length + self.air_path_length

    @property
    def target(self) -> np.ndarray:
        """The current target mass (N,) (unnormalised)."""
        return self._target.copy()

    @property
    def coverage(self) -> np.ndarray:
        """Accumulated footprint sum c̃ (N,) (eq. 3 up to the 1/(N t) factor, which normalisation removes)."""
        self._require_state()
        return self._cov.copy()

    @property
    def potential(self) -> np.ndarray:
        """The potential u (N,) on the cloud as the agents see it (eq. 19, plus the source)."""
        self._require_state()
        u = self._phi @ self._coef
        u[self._tidx] += self.config.source_weight * self._s_t
        return u

    def hopping(self, agent: int = 0) -> bool:
        """True while the agent is hopping a scan hole (on the chord between its two sides)."""
        return self._bridges[agent] is not None if agent < len(self._bridges) else False

    @property
    def source(self) -> np.ndarray:
        """The source s (N,) of the last step (eq. 1, scaled to unit sum; zero off the target)."""
        self._require_state()
        s = np.zeros(len(self.cloud))
        s[self._tidx] = self._s_t
        return s

    def ergodicity(self, normalize: str = "l2") -> float:
        """Normalised ergodicity ε of eq. 48 (see :func:`tactex.ergodic.metrics.normalized_ergodicity`)."""
        self._require_state()
        return normalized_ergodicity(self._target, self._cov, self._mass, normalize)

    def untouched_count(self) -> int:
        """Target points no footprint has touched yet that one may touch (clear of the keep-out zones)."""
        self._require_state()
        return int(np.count_nonzero(self._untouched()))

    def coverage_residual(self) -> float:
        """Coverage residual of the authors' code (√share of target never inside a footprint)."""
        self._require_state()
        return coverage_residual(self._target, self._cov)

    def _require_state(self) -> None:
        if not hasattr(self, "_cov"):
            raise ExplorationError("the explorer has no state yet: call reset(x0) first")

    def with_config(self, **changes) -> HedacExplorer:
        """A fresh explorer on the same cloud and basis with some parameters changed."""
        return HedacExplorer(self.cloud, self.basis, replace(self.config, **changes),
                             keep_out=self._keep_out if self._ko_idx.size else None)

    # -- what a task follows (tactex.tasks.path_source.PathSource): reset, step, update_target, path_length and
    # relocations above, and
    @property
    def done(self) -> bool:
        """Never: the explorer has no end of its own; the task decides when to stop following it."""
        return False
