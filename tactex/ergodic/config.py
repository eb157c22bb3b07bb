"""Parameters of the HEDAC explorer, with TEC's values as defaults (Table II, §V-B, §VI-E)."""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

from tactex.config import accept_old_names, param
from tactex.errors import ConfigError

__all__ = ["COVERAGE_NORMALIZATIONS", "SOURCE_MODES", "HedacConfig", "check_coverage_normalization"]

#: Domains the coverage is normalised over in the source term (see HedacConfig.coverage_normalization).
COVERAGE_NORMALIZATIONS = ("target", "domain")
#: Source terms of the explorer (see HedacConfig.source_mode and tactex.ergodic.sweep).
SOURCE_MODES = ("auto", "ergodic", "sweep")
#: Where the sweep's planned passes start (see HedacConfig.sweep_pass_origin and tactex.ergodic.passes).
PASS_ORIGINS = ("edge", "start")


def check_coverage_normalization(value: object, owner: str) -> None:
    """ConfigError unless ``value`` is one of :data:`COVERAGE_NORMALIZATIONS` (``owner`` names the config)."""
    if value not in COVERAGE_NORMALIZATIONS:
        raise ConfigError(f"{owner}.coverage_normalization must be one of {COVERAGE_NORMALIZATIONS}, got {value!r}")


def _check_number(name: str, value: object, strict: bool) -> None:
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if not ok or (value <= 0 if strict else value < 0):  # type: ignore[operator]
        kind = "a positive finite number" if strict else "a finite number ≥ 0"
        raise ConfigError(f"HedacConfig.{name} must be {kind}, got {value!r}")


@accept_old_names
@dataclass(frozen=True)
class HedacConfig:
    """HEDAC spectral exploration on a point cloud.

    Lengths of the agent's motion are in units of the cloud spacing h (the voxel size, 3 mm in
    the paper; a field in voxels says so in its name, or in its unit per step), so Table II's 3 mm/s and
    3 mm/s² at a 3 mm voxel and a 1 s step are
    ``max_velocity = 1`` voxel/step and ``max_acceleration = 1`` voxel/step². Table II's
    "M = 20" is the number of nearest neighbours n_N of the tangent-space fit and the gradient
    (the authors' code: ``nb_minimum_neighbors = 20``).

    ``coverage_normalization = "target"`` (the default) departs from eq. 2 on purpose. Eq. 2
    divides c̃ by its integral over the whole cloud, and most of a footprint usually lands off a
    thin or small target. A covered target point then keeps the deficit p − c > 0 for good, and
    the source of hundreds of covered points outweighs the few target points no footprint has
    touched yet: the agent goes back over covered strokes while isolated target points wait.
    Dividing by the integral over the target's support keeps HEDAC's ergodic behaviour (it still
    revisits the target in proportion to p) but lets an untouched point stand out, and on the TEC
    clouds it leaves no target point untouched where eq. 2 leaves some. When the target covers
    the whole cloud the two options are the same. ``"domain"`` is eq. 2 literally. The price is
    paid in eq. 48: eq. 2's deficit is exactly what eq. 48 measures, so HEDAC with it dwells on
    the target in proportion to p, while with ``"target"`` the agent moves on once a point has its
    share of the on-target coverage, and eq. 48 reads higher. Choose ``"domain"`` when the time
    share matters more than touching every point;
    ``tactex sweep`` (the paper's parameter study) uses it.
    """

    alpha: float = param(10.0, "diffusion scale α of δt = α h² (TEC eq. 21) [-]")
    alpha_final: float = param(
        0.0, "α at the end of the schedule (high α first, lower later, §VI-E); 0 = constant α [-]"
    )
    alpha_decay_steps: int = param(300, "steps over which α decays geometrically to alpha_final [steps]")
    cooling: float = param(
        0.0,
        "heat loss β per step, the −u term of eq. 4 (HEDAC's cooling): each step is u̇ = αh²Δu − βu + s, so the "
        "potential forgets a source within ~1/β steps and settles to a screened field of eq. 4's form reaching "
        "about √(α/β)·h around a source; the agent then finishes what is near before crossing to far target. "
        "0 = none, as the authors' code (the potential keeps all past heat); 0.05 is a tuned value [1/step]",
    )
    n_eigen: int = param(200, "eigenpairs n_K of the spectral diffusion (eq. 19) [-]")
    agent_radius_m: float = param(0.0075, "agent footprint radius r_a (15 mm on the plate) [m]")
    footprint_sharpness: float = param(
        1.0, "ε·r_a of the Gaussian footprint φ(r) = exp(−ε² r²) (eq. 30); φ(r_a) = exp(−sharpness²) [-]"
    )
    n_neighbors_fit: int = param(20, "nearest neighbours n_N of the sphere/plane and cubic fits (Table II 'M') [-]")
    max_velocity: float = param(1.0, "speed limit ẋmax [voxels/step] (Table II: 3 mm/s at 3 mm, 1 s)")
    max_acceleration: float = param(1.0, "acceleration limit ẍmax [voxels/step²] (Table II: 3 mm/s²)")
    step_duration_s: float = param(1.0, "duration of one exploration step, converts voxels/step to m/s [s]")
    order: int = param(2, "agent dynamics: 1 (velocity along the gradient) or 2 (acceleration, eq. 6) [-]")
    source_weight: float = param(
        1.0, "weight of the undiffused source added to the potential (the authors' code: 1; 0 = diffused only) [-]"
    )
    max_off_cloud_voxels: float = param(
        1.0,
        "farthest the agent may stray from the nearest cloud point (it stays on the fitted surface, so this "
        "lets it bridge scan holes the Laplacian connects) [voxels]",
        old_names=("max_off_cloud",),
    )
    max_bridge_voxels: float = param(
        6.0,
        "longest hop across a scan hole, along a link of the Laplacian that joins its two sides, taken when the "
        "potential beyond is higher than anywhere around the agent (0 = never hop) [voxels]",
        old_names=("max_bridge",),
    )
    max_snap_distance_voxels: float = param(
        10.0, "farthest start/measured position from the cloud that is projected onto it [voxels]",
        old_names=("max_snap_distance",),
    )
    coverage_normalization: str = param(
        "target",
        "integral the coverage c̃ is normalised by in the source (eq. 2): 'target' = over the target's support "
        "(footprint spent off the target does not dilute the target's coverage; the same as eq. 2 when the "
        "target covers the whole cloud), 'domain' = over the whole cloud, eq. 2 literally",
    )
    seed: int = param(0, "seed of the random heading used when the potential is exactly flat [-]")
    edge_braking: bool = param(
        True,
        "at a scan edge the second-order agent spends its acceleration on stopping its outward motion first, so "
        "the realised velocity change stays within max_acceleration; False: the outward part is dropped on "
        "landing (a change of up to ~1.3 a_max·dt in one step, but the agent slides along the edge)",
    )
    relocate: bool = param(
        True,
        "lift and move (TEC §VI-B) when walking makes no progress: the agent's Laplacian part holds no untouched "
        "target, it stalls (stall_steps within stall_radius_voxels), or the untouched target stops shrinking "
        "(progress_steps); it touches down at untouched target elsewhere (see tactex.ergodic.relocation)",
    )
    stall_steps: int = param(20, "steps within stall_radius_voxels of one point that count as a stall [steps]")
    stall_radius_voxels: float = param(2.0, "radius of the stall rule [voxels]", old_names=("stall_radius",))
    progress_steps: int = param(
        300, "steps without a newly touched target point, while untouched target is left, before relocating "
        "(0 = never) [steps]"
    )
    relocation_clearance_m: float = param(
        0.02, "height of a relocation's flight above the lift-off and touch-down points, along their normals [m]"
    )
    source_mode: str = param(
        "auto",
        "source term: 'ergodic' = eq. 1–2 (match the target distribution), 'sweep' = pass over every target point "
        "once (tactex.ergodic.sweep: open target next to covered ground first, strokes overlapping a little), "
        "'auto' = sweep when the target is the whole surface at one level (--target all), else ergodic",
    )
    sweep_plan_ratio: float = param(
        0.8, "sweep source: a point counts as done once the agent came within this share of r_a (< 1: strokes "
        "overlap) [-]"
    )
    sweep_frontier_ratio: float = param(
        1.2, "sweep source: radius of the neighbourhood whose done share weighs an open point, in r_a [-]"
    )
    sweep_base: float = param(
        0.02, "sweep source: weight of an open point with no done neighbour, relative to one surrounded by done "
        "ground (1 = no preference for the edge of the covered region) [-]"
    )
    sweep_pass_spacing: float = param(
        1.8, "sweep: distance between the planned passes along rings of surface distance from the start, in r_a "
        "(tactex.ergodic.passes; < 2 leaves an overlap for the tracking error; a part's plan may tighten it to 0.9 "
        "of this where the full spacing leaves many islands at the footprint's edge); 0 = no passes, the sweep "
        "source's potential alone [-]"
    )
    sweep_pass_origin: str = param(
        "edge", "sweep: where the planned passes' rings start: 'edge' = from the target's outer edge inwards "
        "(contour-parallel) or from the start, whichever plan walks shorter (from the start on a surface without an "
        "edge), 'start' = from the agent's start outwards"
    )
    compiled: bool = param(
        True,
        "run the walking step compiled by numba when the optional 'fast' extra is installed (about 5x faster; "
        "the same steps as numpy to round-off); False or without numba: numpy",
    )

    def __post_init__(self) -> None:
        if isinstance(self.seed, bool) or not isinstance(self.seed, numbers.Integral) or self.seed < 0:
            raise ConfigError(f"seed must be an integer ≥ 0, got {self.seed!r}")
        positive = (
            "alpha",
            "agent_radius_m",
            "footprint_sharpness",
            "max_velocity",
            "max_acceleration",
            "step_duration_s",
            "max_off_cloud_voxels",
            "max_snap_distance_voxels",
            "stall_radius_voxels",
            "relocation_clearance_m",
        )
        for name in positive:
            _check_number(name, getattr(self, name), strict=True)
        for name in ("alpha_final", "source_weight", "max_bridge_voxels", "cooling"):
            _check_number(name, getattr(self, name), strict=False)
        for name, low in (("n_eigen", 1), ("n_neighbors_fit", 5), ("alpha_decay_steps", 1), ("stall_steps", 2),
                          ("progress_steps", 0)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise ConfigError(f"HedacConfig.{name} must be an integer ≥ {low}, got {value!r}")
        check_coverage_normalization(self.coverage_normalization, "HedacConfig")
        if self.source_mode not in SOURCE_MODES:
            raise ConfigError(f"HedacConfig.source_mode must be one of {SOURCE_MODES}, got {self.source_mode!r}")
        for name in ("sweep_plan_ratio", "sweep_frontier_ratio"):
            _check_number(name, getattr(self, name), strict=True)
        _check_number("sweep_base", self.sweep_base, strict=True)
        _check_number("sweep_pass_spacing", self.sweep_pass_spacing, strict=False)
        if self.sweep_pass_origin not in PASS_ORIGINS:
            raise ConfigError(
                f"HedacConfig.sweep_pass_origin must be one of {PASS_ORIGINS}, got {self.sweep_pass_origin!r}")
        if self.sweep_pass_spacing > 2.0:
            raise ConfigError(
                f"HedacConfig.sweep_pass_spacing must be 0 (no passes) or at most 2 (footprint widths touch), got "
                f"{self.sweep_pass_spacing!r}; passes farther apart than 2 r_a leave a strip between them uncovered"
            )
        if self.sweep_base > 1.0:
            raise ConfigError(f"HedacConfig.sweep_base must be in (0, 1], got {self.sweep_base!r}")
        for name in ("compiled", "edge_braking", "relocate"):
            if not isinstance(getattr(self, name), bool):
                raise ConfigError(f"HedacConfig.{name} must be True or False, got {getattr(self, name)!r}")
        if self.order not in (1, 2) or isinstance(self.order, bool):
            raise ConfigError(f"HedacConfig.order must be 1 or 2, got {self.order!r}")
        if self.agent_radius_m > 1.0:
            raise ConfigError(
                f"HedacConfig.agent_radius_m = {self.agent_radius_m} m is larger than a robot workspace; "
                "it is in metres (e.g. 0.0075 for 7.5 mm)"
            )

    def alpha_at(self, step: int) -> float:
        """α of the schedule at ``step`` (constant when alpha_final = 0)."""
        if self.alpha_final <= 0 or step <= 0:
            return self.alpha
        frac = min(step / self.alpha_decay_steps, 1.0)
        return self.alpha * (self.alpha_final / self.alpha) ** frac
