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
``max_off_cloud_voxels`` voxels from the nearest cloud point (it still lies on the fitted surface).

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

Starting and measured positions farther than ``max_snap_distance_voxels`` voxels from the cloud are
rejected with :class:`~tactex.errors.ExplorationError` (a robot that far from the surface is not
in contact, and a silent snap would hide it); nearer ones are projected onto the surface.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from tactex.ergodic import compiled_step
from tactex.ergodic.agents import Agent, make_agent
from tactex.ergodic.bridges import Bridge, gap_links
from tactex.ergodic.command import ExplorationCommand
from tactex.ergodic.config import HedacConfig
from tactex.ergodic.guidance import PASS_REACH, REPAIR_RADIUS, REPAIR_STEPS, SPECK_POINTS, PassGuidance
from tactex.ergodic.hedac_step import EDGE_OFFSET, WHOLE, HedacStep
from tactex.ergodic.hops import Hops
from tactex.ergodic.keep_out import KEEP_OUT_MARGIN, KeepOut
from tactex.ergodic.metrics import coverage_residual, normalized_ergodicity
from tactex.ergodic.multi_agent import MultiAgent
from tactex.ergodic.passes import RingPasses
from tactex.ergodic.relocation import STALL_SAMPLE_EVERY, ProgressMonitor, Relocating, RelocationCommand
from tactex.ergodic.source import REBUILD_STEPS, SourceSums
from tactex.ergodic.surface_fit import plane_slope_checked, project_local, tangent_basis
from tactex.ergodic.sweep import SweepSource, sweeps
from tactex.errors import ConfigError, ExplorationError, InputError
from tactex.geometry.fit import fit_sphere_or_plane
from tactex.pointcloud import SurfaceCloud

# The explorer's own names, and its parts' constants importable from here too (their home is the part).
__all__ = ["EDGE_OFFSET", "KEEP_OUT_MARGIN", "PASS_REACH", "REBUILD_STEPS", "REPAIR_RADIUS", "REPAIR_STEPS",
           "SPECK_POINTS", "Exploration", "HedacExplorer", "check_snap_distance", "explore"]

_project_local = project_local
_sum = np.add.reduce
_plane_slope = plane_slope_checked
_Z = np.array([0.0, 0.0, 1.0])


def _read_only(a: np.ndarray) -> np.ndarray:
    view = a.view()
    view.setflags(write=False)
    return view


def check_snap_distance(tree: cKDTree, x_m: np.ndarray, name: str, max_voxels: float, spacing_m: float) -> float:
    """The distance [m] from ``x_m`` (3,) to the nearest point of the cloud in ``tree``; an
    :class:`ExplorationError` naming ``name`` when it is over ``max_voxels`` voxels of ``spacing_m`` [m]
    (``HedacConfig.max_snap_distance_voxels``): a start that far from the surface is no start on it."""
    d = float(tree.query(x_m)[0])
    snap = max_voxels * spacing_m
    if d > snap:
        raise ExplorationError(
            f"{name} = {np.round(x_m, 4).tolist()} m is {d * 1e3:.1f} mm from the nearest cloud point, farther "
            f"than max_snap_distance_voxels = {max_voxels:g} ({snap * 1e3:.1f} mm); "
            "start on (or just above) the surface, or raise HedacConfig.max_snap_distance_voxels"
        )
    return d


class HedacExplorer(HedacStep, PassGuidance, Hops, Relocating, KeepOut, MultiAgent):
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
        progress: called with one-line messages during long work (the set-up's neighbourhoods on a large
            cloud, the pass plan of a large target), or None: silent (see the ``progress`` property).

    Relocation (``config.relocate``, :mod:`.relocation`): when walking makes no progress, ``step``
    returns a :class:`~tactex.ergodic.relocation.RelocationCommand` (lift off, fly, touch down)
    instead of an :class:`ExplorationCommand`, and the agent jumps to the touch-down point.

    The explorer is assembled from its parts, one file each: the walking step (:mod:`.hedac_step`, with
    the compiled twin :mod:`.compiled_step`), the guidance along planned passes (:mod:`.guidance`), hops
    across scan holes (:mod:`.hops`), relocation (:mod:`.relocation`), keep-out zones (:mod:`.keep_out`)
    and the team step (:mod:`.multi_agent`); this class holds the state they share and the public face.
    For one run from one start, :func:`explore` does it all in one call.
    """

    def __init__(self, cloud: SurfaceCloud, basis, config: HedacConfig | None = None,
                 keep_out: np.ndarray | None = None, progress: Callable[[str], None] | None = None) -> None:
        self._progress = progress
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
        # the cloud's own normals (oriented to the sensor when it has them): the outward side the agent's fitted
        # normal is kept on, so a poor local fit at a rim cannot carry it round to the inside
        self._outward = None if cloud.normals is None else np.ascontiguousarray(cloud.normals, dtype=np.float64)
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
        self._snap = cfg.max_snap_distance_voxels * self.spacing
        self._r_a2 = self._r_a**2
        self._off2 = (cfg.max_off_cloud_voxels * self.spacing) ** 2
        self._off = cfg.max_off_cloud_voxels * self.spacing
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
        self._bridge_max2 = (cfg.max_bridge_voxels * self.spacing) ** 2
        self._gaps = gap_links(self._points, laplacian, self._tree, self._off, cfg.max_bridge_voxels * self.spacing)
        self._bridges: list[Bridge | None] = []
        self._near = np.zeros(0, dtype=np.intp)
        self._rng = np.random.default_rng(cfg.seed)
        self._labels = self._part_labels(basis, n)
        self._set_keep_out(keep_out)
        self._decay_alpha = np.nan
        self._decay = np.ones(k)
        self._set_target(cloud.target)
        self._compiled_out = np.empty(compiled_step.OUT_SIZE)
        self._compiled_prm = compiled_step.params(
            agent_radius_m=self._r_a, eps2=self._eps2, source_weight=self._source_w,
            max_acceleration=cfg.max_acceleration * self.spacing / self._dt**2, max_velocity=self._v_max,
            max_step_m=self._step_max, dt=self._dt, max_off_m=self._off, edge_offset=EDGE_OFFSET,
            normalize_by_target=self._norm_target, order=cfg.order, edge_braking=cfg.edge_braking,
        )
        # The compiled step forms eq. 1–2's source itself: the sweep source runs the numpy step.
        self._walk_compiled = self._compile_step() if cfg.compiled and self._sweep is None else None
        self._agents: list[Agent] = []
        self._x = np.zeros((0, 3))
        self._nrm_t: list[tuple] = []  # each agent's unit normal as a float triple (the step reads these)
        self.step_count = 0
        self.bridges_taken = 0
        self._pass = WHOLE
        self.compiled_steps = 0  # agent steps the compiled step took (the rest ran in numpy)
        self._monitors: list[ProgressMonitor] = []
        self._relocating = cfg.relocate
        self.relocations: list[RelocationCommand] = []
        self.air_path_lengths = np.zeros(0)

    @staticmethod
    def _part_labels(basis, n: int) -> np.ndarray:
        """Connected part (N,) of each point as the basis' Laplacian links them (all 0 without one)."""
        if hasattr(basis, "component_labels") and getattr(basis, "L", None) is not None:
            return np.asarray(basis.component_labels(), dtype=np.intp)
        return np.zeros(n, dtype=np.intp)

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
        self._metric_terms(p)
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
                                  cfg.sweep_frontier_ratio * self._r_a, cfg.sweep_base, image_rows=self._phitm_t,
                                  progress=getattr(self, "_progress", None)) if sweep else None
        self._passes = None
        if sweep and cfg.sweep_pass_spacing > 0.0:
            laplacian = getattr(self.basis, "L", None)
            links = None if laplacian is None else laplacian.tocsr()[self._tidx][:, self._tidx]
            self._passes = RingPasses(self._points[self._tidx], links, cfg.sweep_pass_spacing * self._r_a,
                                      PASS_REACH * self.spacing, self.spacing, allowed=self._t_safe,
                                      origin=cfg.sweep_pass_origin, footprint_m=self._r_a, hops=self._target_hops())
            self._passes.progress = getattr(self, "_progress", None)
        if hasattr(self, "_walk_compiled"):  # a new target may switch a running explorer between the sources
            if sweep:
                self._walk_compiled = None
            elif cfg.compiled and self._walk_compiled is None:
                self._walk_compiled = self._compile_step()

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
            p, nrm = project_local(patch, xi, self._initial_normal(xi))
            self._x[i] = p
            self._nrm_t[i] = tuple(nrm.tolist())
            t1, t2 = tangent_basis(nrm)
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
            ProgressMonitor(p, 0, cfg.stall_radius_voxels * self.spacing, cfg.stall_steps, cfg.progress_steps)
            for p in self._x
        ]
        return out

    def _initial_normal(self, x: np.ndarray) -> np.ndarray:
        """Outward side: the cloud's normal at the nearest point when it has normals, else +z (up)."""
        if self.cloud.normals is not None:
            return self.cloud.normals[int(self._tree.query(x)[1])].copy()
        return _Z.copy()

    def _check_distance(self, x: np.ndarray, name: str) -> float:
        return check_snap_distance(self._tree, x, name, self.config.max_snap_distance_voxels, self.spacing)

    def update_target(self, mass: np.ndarray, keep_coverage: bool = False) -> None:
        """Replace the target mass (N,) while running (vision feedback); the basis is kept.

        By default a new exploration cycle starts: coverage and potential restart from the new
        target (the old coverage would hide dirt that is still there). ``keep_coverage=True``
        keeps the accumulated coverage and the diffused potential.
        """
        self._set_target(mass)
        # A hop in progress goes on to the far side of its hole: dropped, it would leave the agent mid-air,
        # off the cloud, walking from a neighbourhood that holds few of its points.
        if not keep_coverage or not hasattr(self, "_cov"):
            if self._agents:
                self._reset_fields()
        else:
            self._s_ext[:] = 0.0

    @property
    def source_mode(self) -> str:
        """The source term in use: 'sweep' (:mod:`.sweep`) or 'ergodic' (eq. 1–2); HedacConfig.source_mode
        'auto' resolved for the current target."""
        return "sweep" if self._sweep is not None else "ergodic"

    @property
    def progress(self) -> Callable[[str], None] | None:
        """Called with one-line messages during long work inside a step (the pass plan of a large target, laid
        at the first step); None: silent."""
        return getattr(self, "_progress", None)

    @progress.setter
    def progress(self, fn: Callable[[str], None] | None) -> None:
        self._progress = fn
        if self._passes is not None:
            self._passes.progress = fn

    @property
    def planned_passes(self) -> bool:
        """Whether the sweep walks planned passes (:mod:`.passes`; HedacConfig.sweep_pass_spacing > 0, one agent)."""
        return self._passes is not None and self.n_agents <= 1

    @property
    def compiled(self) -> bool:
        """Whether the walking steps run compiled (numba, :mod:`.compiled_step`) rather than in numpy."""
        return self._walk_compiled is not None

    @property
    def n_agents(self) -> int:
        """Agents running (0 before reset)."""
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
            if self._sweep is not None:
                self._sweep.rebuild()
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
            cmds = self._step_together(list(range(self.n_agents)), exact)  # eq. 3 and 19 with a team
        if before is not None:
            cmds = [c if isinstance(c, RelocationCommand) else self._keep_out_guard(c, before[c.agent]) for c in cmds]
        if self._sweep is not None:
            for c in cmds:
                self._sweep.mark(c.point)
                if self._passes is not None:
                    self._passes.mark(c.point)
        self.step_count += 1
        return cmds

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
        u[self._tidx] += self.config.source_weight * self._source_at(self._tidx)
        return u

    @property
    def source(self) -> np.ndarray:
        """The source s (N,) of the last step (eq. 1, scaled to unit sum; zero off the target)."""
        self._require_state()
        s = np.zeros(len(self.cloud))
        s[self._tidx] = self._source_at(self._tidx)
        return s

    def ergodicity(self, normalize: str = "l2") -> float:
        """Normalised ergodicity ε of eq. 48 (see :func:`tactex.ergodic.metrics.normalized_ergodicity`)."""
        self._require_state()
        pint, p_hat, p_norm, p_int = self._ergodicity_terms
        if pint <= 0 or normalize not in ("l2", "integral"):
            return normalized_ergodicity(self._target, self._cov, self._mass, normalize)  # its errors
        # eq. 48 as normalized_ergodicity forms it, without its checks and temporaries and with numpy's sums
        # instead of BLAS dot products (a large cloud's run computes it after every step: BLAS threads over 100k
        # points cost more than the step, and spin on after it)
        buf = self._metric_buf
        np.multiply(self._mass, self._cov, out=buf)
        cint = float(_sum(buf))
        if cint > 0:
            np.divide(self._cov, cint, out=buf)
        else:
            buf[:] = 0.0
        np.subtract(p_hat, buf, out=buf)
        np.maximum(buf, 0.0, out=buf)
        np.multiply(buf, buf, out=buf)
        err = float(np.sqrt(_sum(buf)))
        return err / (p_norm if normalize == "l2" else p_int)

    def untouched_count(self) -> int:
        """Target points no footprint has touched yet that one may touch (clear of the keep-out zones)."""
        self._require_state()
        return int(np.count_nonzero(self._untouched()))

    def coverage_residual(self) -> float:
        """Coverage residual of the authors' code (√share of target never inside a footprint)."""
        self._require_state()
        total, p_hat, p_norm = self._residual_terms
        if total <= 0:
            return coverage_residual(self._target, self._cov)  # its error
        buf = self._metric_buf  # coverage_residual's, without its checks and temporaries, summed as ergodicity()
        np.subtract(p_hat, self._cov, out=buf)
        np.maximum(buf, 0.0, out=buf)
        np.multiply(buf, buf, out=buf)
        return float(np.sqrt(_sum(buf)) / p_norm)

    def _metric_terms(self, p: np.ndarray) -> None:
        """The target's parts of eq. 48 and of the coverage residual (see :mod:`.metrics`), formed once per target."""
        self._metric_buf = np.empty(p.size)
        pint = float(self._mass @ p)
        p_hat = p / pint if pint > 0 else p
        # the norms summed as ergodicity() and coverage_residual() sum theirs: untouched, they are exactly 1
        self._ergodicity_terms = (pint, p_hat, float(np.sqrt(_sum(p_hat * p_hat))), float(self._mass @ p_hat))
        total = float(p.sum())
        p_hat = p / total if total > 0 else p
        self._residual_terms = (total, p_hat, float(np.sqrt(_sum(p_hat * p_hat))))

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


class Exploration(NamedTuple):
    """One agent's run from :func:`explore`: the start and ``steps`` steps (world frame).

    Attributes:
        points: the agent's point on the surface [m] (steps + 1, 3); row 0 is the start projected onto it.
        velocities: its velocity [m/s] (steps + 1, 3) (zero at the start and at a relocation's touch-down).
        normals: the unit outward surface normal there (steps + 1, 3).
        coverage_residual: the coverage residual after each step (steps,) [-]
            (:meth:`HedacExplorer.coverage_residual`: √share of target never inside a footprint).
        commands: every command, the start's first (steps + 1): :class:`ExplorationCommand`, or
            :class:`~tactex.ergodic.relocation.RelocationCommand` where the agent relocated.
        explorer: the explorer after the last step (its coverage, potential, ergodicity, path lengths).
    """

    points: np.ndarray
    velocities: np.ndarray
    normals: np.ndarray
    coverage_residual: np.ndarray
    commands: list
    explorer: HedacExplorer


def explore(cloud: SurfaceCloud, basis, x0: np.ndarray, steps: int, config: HedacConfig | None = None,
            keep_out: np.ndarray | None = None) -> Exploration:
    """Explore ``cloud`` with one agent from ``x0`` (3,) [m] for ``steps`` steps, in one call.

    The same as building a :class:`HedacExplorer` (``cloud``, its Laplace ``basis``, ``config``,
    ``keep_out``), resetting it at ``x0`` and stepping it ``steps`` times: the trajectory is the one a
    hand-driven explorer walks. For vision feedback (``update_target``), measured positions or several
    agents, drive a :class:`HedacExplorer` yourself.

    Raises:
        InputError: ``steps`` is not an integer ≥ 0, or ``x0`` is not one point (3,).
    """
    if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or steps < 0:
        raise InputError(f"steps must be an integer ≥ 0, got {steps!r}")
    if np.shape(x0) != (3,):
        raise InputError(f"x0 must be one point of shape (3,) [m], got shape {np.shape(x0)}; for several agents "
                         "use HedacExplorer.reset and step_all")
    explorer = HedacExplorer(cloud, basis, config, keep_out=keep_out)
    commands = list(explorer.reset(x0))
    residual = np.empty(int(steps))
    for k in range(int(steps)):
        commands.append(explorer.step())
        residual[k] = explorer.coverage_residual()
    return Exploration(np.array([c.point for c in commands]), np.array([c.velocity for c in commands]),
                       np.array([c.normal for c in commands]), residual, commands, explorer)
