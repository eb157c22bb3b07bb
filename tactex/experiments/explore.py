"""`tactex explore`: kinematic ergodic exploration of one cloud, with metrics and plots (TEC §V-B).

The run follows the paper's simulated experiments: voxelise the cloud (3 mm), take the target
from its red marking (by hue and saturation, :mod:`tactex.pointcloud.target`; TEC's raw red channel
threshold on request) or draw a marking on a built-in object, build the Laplace basis once,
then step the HEDAC explorer kinematically and record the normalised ergodicity (eq. 48), the
coverage residual and the path length after every step.

Outputs in the run directory: ``metrics.json`` (scalars), ``series.npz`` (per step: ergodicity,
coverage residual, path length [m], step time [s]), ``trajectory.npy`` (steps × 3 [m]),
``fields.npz`` (points, target, coverage, potential), ``metrics.png``, ``cloud.png`` and
``explore.html`` (interactive, works offline; a long path is drawn decimated, a big cloud through an
even subset of its points). Ctrl-C during the steps writes the steps done (``metrics.json`` with
``"partial": true`` and ``steps_done``), then raises :class:`~tactex.errors.RunInterrupted`.
"""

from __future__ import annotations

import collections
import dataclasses
import math
import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from tactex.config import param, to_jsonable
from tactex.errors import ConfigError, ExplorationError, InputError, RunInterrupted
from tactex.experiments.run_folder import prepare_out_dir
from tactex.pointcloud import SurfaceCloud
from tactex.pointcloud.io import SUPPORTED_SUFFIXES
from tactex.pointcloud.keep_out import (
    DEFAULT_KEEP_OUT_THRESHOLD,
    check_keep_out_options,
    raw_keep_out,
)
from tactex.pointcloud.markings import marked_cloud, resolve_marking
from tactex.pointcloud.shapes import get_surface, resolve_surface_name, surface_names
from tactex.pointcloud.target import DEFAULT_MIN_SATURATION, TARGET_CHOICES, TargetRule, describe_target
from tactex.pointcloud.target_file import load_target_file
from tactex.pointcloud.units import check_units
from tactex.spectral.eigen import check_eigensolver
from tactex.spectral.modes import auto_n_eigen

__all__ = [
    "DEFAULT_MARKINGS",
    "TARGET_CHANNELS",
    "ExploreConfig",
    "ExploreResult",
    "authors_starts",
    "load_explore_cloud",
    "run_explore",
    "write_explore_report",
]

#: TEC §V-C marks its plate with shapes, its bowl with 'RLI' and its cup with an 'X'.
DEFAULT_MARKINGS = {"plate": "shapes", "bowl": "RLI", "cup": "X"}
#: Where the target comes from for a cloud file.
TARGET_CHANNELS = TARGET_CHOICES
#: TEC §V-B: r_a = 15 mm on the (larger) plate, 7.5 mm on the cup and the bunny.
PLATE_AGENT_RADIUS_M = 0.015
AGENT_RADIUS_M = 0.0075

#: Seconds between progress lines on a long run (and at least every tenth of the steps).
PROGRESS_EVERY_S = 3.0
#: Per-step series kept in metrics.json's place: series.npz.
SERIES = ("ergodicity", "coverage_residual", "path_length_m", "air_path_length_m")

#: The colour bars' labels of the fields drawn (all three are dimensionless).
FIELD_LABELS = {"target": "target p [-]", "coverage": "coverage c [-]", "potential": "potential u [-]"}
#: Target in red on a grey surface (TEC Fig. 8 style); a white zero would hide the cloud.
TARGET_COLORSCALE = [[0.0, "lightgrey"], [1.0, "red"]]

Progress = Callable[[str], None]


@dataclass(frozen=True)
class ExploreConfig:
    """One exploration run; defaults are TEC's (§V-B, Table II, Fig. 11: K = 200, α = 10)."""

    voxel_size_m: float = param(
        0.003, "voxel edge of the down-sampling, and sampling spacing of meshes and built-in objects; 0 = none [m]",
        aliases=("--voxel-size",))
    n_eigen: int | None = param(
        None, "eigenpairs n_K of the spectral diffusion (TEC eq. 19); default: one per 5 footprint areas of the "
        "surface, at least TEC's 200 (which small objects keep), at most 1000 [-]")
    n_neighbors: int = param(30, "neighbours of the Laplacian; decides which parts connect (TEC §VI-D) [-]")
    alpha: float = param(10.0, "diffusion scale α of δt = α h² (TEC eq. 21) [-]")
    steps: int = param(1000, "exploration steps [-]")
    agent_radius_m: float | None = param(
        None, "agent footprint radius r_a [m]; by default 0.015 on plates, else 0.0075 (TEC §V-B)",
        aliases=("--agent-radius",))
    max_velocity: float = param(1.0, "agent speed limit (Table II: 3 mm/s at 3 mm voxels) [voxels/step]")
    x0: tuple[float, float, float] | None = param(
        None,
        "start position; default: the authors' start #seed mod 10 when <cloud>_x0_arr_10.npz lies beside "
        "the file, else a cloud point drawn with the seed [m]",
        cli=False,
    )
    seed: int = param(0, "seed of the start position and of the explorer [-]")
    target: str = param(
        "auto",
        "target of a cloud file: red, green or blue (a marking of that colour, judged by hue and saturation), "
        "stored (the file's target array), all (the whole surface), or auto (the stored target if the file "
        "has one, else red)", aliases=("--target-channel",))
    target_saturation: float = param(
        DEFAULT_MIN_SATURATION, "least saturation of a marked colour, 0–1 (white 0, beige ~0.3, a red marker ~0.8)")
    target_threshold: float | None = param(
        None, "TEC's raw rule instead of hue: the --target colour's channel ≥ this level, 0–1 (TEC clouds: 1.0); "
        "white passes a red ≥ level rule too")
    marking: str | None = param(
        None, "drawn target of a built-in object: X, RLI, blobs, shapes, full; by default plate shapes, bowl RLI, "
        "else X")
    keep_out_channel: str = param(
        "", "colour channel marking a keep-out zone no footprint may touch: red, green or blue ('' = none)"
    )
    keep_out_threshold: float = param(DEFAULT_KEEP_OUT_THRESHOLD, "with --keep-out-channel: the channel level at or "
                                      "above which a point is kept out, 0–1 [-]")
    keep_out_mask: str = param(
        "", "a .npy file with one boolean per row of the cloud file, rows with NaN coordinates included (or per "
        "point of the sampled built-in); True = keep out; not for meshes (their points are samples)"
    )
    units: str = param("m", "length unit of the cloud or mesh file: m, mm or in; its coordinates are converted to "
                            "metres as it is read (every other option stays in metres)")
    cache: bool = param(True, "reuse/store the Laplace basis in the cache ($TACTEX_CACHE_DIR)")
    eigensolver: str = param(
        "auto", "eigensolver of the Laplace basis: arpack (exact, the papers'), hierarchical (hierarchical subspace "
        "iteration, 2-6x faster, eigenvalues within about 1 %) or auto (hierarchical from 1000 points on)")
    eigen_tol: float = param(5e-3, "hierarchical eigensolver: bound on each pair's squared relative residual "
                                   "(≈ relative eigenvalue error) [-]")
    html: bool = param(True, "write the interactive explore.html (inline plotly: 5 MB for a small cloud, at most "
                             "10 MB for a big one, drawn through 100 000 of its points)")

    def __post_init__(self) -> None:
        if int(self.seed) != self.seed or self.seed < 0:
            raise ConfigError(f"seed must be an integer ≥ 0, got {self.seed!r}")
        if not math.isfinite(self.voxel_size_m) or self.voxel_size_m < 0:
            raise ConfigError(f"voxel_size_m={self.voxel_size_m} is not a length; give metres ≥ 0 (0 keeps the cloud)")
        if self.voxel_size_m > 0.1:
            raise ConfigError(f"voxel_size_m={self.voxel_size_m} is over 10 cm; it is in metres (0.003 = 3 mm)")
        for name in ("steps", "n_eigen", "n_neighbors"):
            value = getattr(self, name)
            if name == "n_eigen" and value is None:
                continue
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ConfigError(f"{name}={value!r} is not a whole number ≥ 1")
        if not math.isfinite(self.alpha) or self.alpha <= 0:
            raise ConfigError(f"alpha={self.alpha} must be a positive number")
        check_eigensolver(self.eigensolver, self.eigen_tol)
        if not math.isfinite(self.max_velocity) or self.max_velocity <= 0:
            raise ConfigError(f"max_velocity={self.max_velocity} must be a positive number of voxels per step")
        if self.agent_radius_m is not None and (
            not math.isfinite(self.agent_radius_m) or not 0 < self.agent_radius_m <= 1
        ):
            raise ConfigError(f"agent_radius_m={self.agent_radius_m} must be a positive number of metres up to 1 "
                              "(0.0075 = 7.5 mm)")
        if self.x0 is not None:
            x0 = np.asarray(self.x0, dtype=float)
            if x0.shape != (3,) or not np.isfinite(x0).all():
                raise ConfigError(f"x0={self.x0!r} must be three finite coordinates [m]")
        object.__setattr__(self, "target", self.target_rule().target)
        if self.marking is not None:
            object.__setattr__(self, "marking", resolve_marking(self.marking))
        check_keep_out_options(self.keep_out_channel, self.keep_out_threshold, self.keep_out_mask)
        check_units(self.units)

    def target_rule(self) -> TargetRule:
        """How a cloud file's target is chosen (``target``, ``target_saturation``, ``target_threshold``)."""
        return TargetRule(self.target, self.target_saturation, self.target_threshold)


@dataclass
class ExploreResult:
    """What a run produced: the metrics written to ``metrics.json`` and the files."""

    out_dir: Path
    metrics: dict[str, Any]
    trajectory: np.ndarray
    files: dict[str, Path] = field(default_factory=dict)


def _is_file_source(source: str) -> bool:
    p = Path(source)
    return p.suffix.lower() in SUPPORTED_SUFFIXES or p.exists() or "/" in source or "\\" in source


def load_explore_cloud(source: str | Path, cfg: ExploreConfig) -> tuple[SurfaceCloud, dict[str, Any]]:
    """The cloud to explore, with its target, and a description of where it came from.

    ``source`` is a cloud or mesh file (voxelised, or sampled, at ``cfg.voxel_size_m``; target by
    ``cfg.target_rule()``) or a built-in object name, in any case (sampled at ``cfg.voxel_size_m`` with
    a marking). The description holds what loading did (``notes``: points dropped, a mesh sampled)
    and where the target is (``target_where``).
    """
    cloud, info, _ = load_explore_cloud_keep_out(source, cfg)
    return cloud, info


def load_explore_cloud_keep_out(
    source: str | Path, cfg: ExploreConfig
) -> tuple[SurfaceCloud, dict[str, Any], np.ndarray | None]:
    """:func:`load_explore_cloud` and the keep-out zone (a boolean per point of the returned cloud, or
    None without ``--keep-out-*`` options; see :mod:`tactex.pointcloud.keep_out`)."""
    src = str(source)
    builtin = resolve_surface_name(src)
    if builtin is not None and not Path(src).is_file():
        src = builtin
        if cfg.voxel_size_m <= 0:
            raise ConfigError("voxel_size_m=0 cannot sample a built-in object: give its spacing in metres (0.003)")
        marking = cfg.marking or DEFAULT_MARKINGS.get(src, "X")
        cloud = marked_cloud(get_surface(src), marking, spacing_m=cfg.voxel_size_m)
        if cloud.n_target == 0:
            raise InputError(f"the marking '{marking}' leaves no target point on '{src}' at "
                             f"{cfg.voxel_size_m} m spacing")
        if cfg.units != "m":
            raise ConfigError(f"units={cfg.units} is the unit of a cloud file; the built-in '{src}' is in metres")
        keep_out = raw_keep_out(cloud, cfg.keep_out_channel, cfg.keep_out_threshold, cfg.keep_out_mask)
        return cloud, {"kind": "builtin", "name": src, "marking": marking, "target_rule": f"marking {marking}",
                       "target_where": describe_target(cloud), "notes": []}, keep_out
    if not _is_file_source(src):
        raise ConfigError(
            f"'{src}' is neither a built-in object ({', '.join(surface_names())}) nor a cloud file "
            f"({', '.join(SUPPORTED_SUFFIXES)})"
        )
    path = Path(src)
    if path.is_dir():
        raise InputError(f"'{path}' is a directory; give a point cloud file ({', '.join(SUPPORTED_SUFFIXES)})")
    if not path.is_file():
        raise InputError(f"point cloud file '{path}' does not exist")
    if cfg.marking is not None:
        raise ConfigError("--marking applies to built-in objects; a file's target comes from --target")
    loaded = load_target_file(src, cfg.voxel_size_m, cfg.target_rule(), keep_out_channel=cfg.keep_out_channel,
                              keep_out_threshold=cfg.keep_out_threshold, keep_out_mask=cfg.keep_out_mask,
                              units=cfg.units)
    read, cloud = loaded.read, loaded.cloud
    return cloud, {"kind": "file", "path": str(path.resolve()), "n_points_raw": len(read.cloud),
                   "n_dropped_nonfinite": read.n_dropped, "n_mesh_faces": read.n_faces, "notes": list(read.notes),
                   "target_rule": loaded.target_rule, "target_where": describe_target(cloud)}, loaded.keep_out


def _default_agent_radius(source_info: dict[str, Any]) -> float:
    name = source_info.get("name") or Path(source_info.get("path", "")).stem
    return PLATE_AGENT_RADIUS_M if str(name).startswith("plate") else AGENT_RADIUS_M


def authors_starts(source_info: dict[str, Any]) -> tuple[np.ndarray, str] | None:
    """The authors' start positions (k, 3) [m] stored beside a cloud file as
    ``<stem>_x0_arr_10.npz`` (the TEC data), with the file's name; None when there is none."""
    if source_info.get("kind") != "file":
        return None
    p = Path(source_info["path"])
    authors = p.with_name(f"{p.stem}_x0_arr_10.npz")
    if not authors.is_file():
        return None
    with np.load(authors, allow_pickle=False) as z:
        return np.asarray(z["x0_arr"], dtype=float).reshape(-1, 3), authors.name


def _start_position(cloud: SurfaceCloud, cfg: ExploreConfig, source_info: dict[str, Any]) -> tuple[np.ndarray, str]:
    if cfg.x0 is not None:
        return np.asarray(cfg.x0, dtype=float), "given"
    found = authors_starts(source_info)
    if found is not None:
        arr, name = found
        if arr.shape[0] and np.isfinite(arr).all():
            i = cfg.seed % arr.shape[0]
            return arr[i], f"{name}[{i}]"
    i = int(np.random.default_rng(cfg.seed).integers(len(cloud)))
    return cloud.points[i].copy(), f"cloud point {i} (seed {cfg.seed})"


#: A run ends stalled when its agent stayed within STALL_RADIUS voxels of where it ended over its
#: last STALL_MIN_STEPS steps (or a tenth of the run, or the steps a slow agent needs to cross that
#: circle, whichever is longest) while more than STALL_RESIDUAL of coverage residual was left (it may
#: still dither in place).
STALL_MIN_STEPS = 50
STALL_RADIUS = 2.0
STALL_RESIDUAL = 0.01


def _stalled_from(trajectory: np.ndarray, spacing: float, max_velocity: float = 1.0) -> int | None:
    """The 0-based index of the first step from which the agent stayed within STALL_RADIUS voxels of
    its final position, when that tail is long enough (see STALL_MIN_STEPS; ``max_velocity`` in
    voxels/step); else None."""
    n = len(trajectory)
    if n == 0:
        return None
    away = np.flatnonzero(np.linalg.norm(trajectory - trajectory[-1], axis=1) > STALL_RADIUS * spacing)
    start = int(away[-1]) + 1 if away.size else 0
    crossing = math.ceil(2.0 * STALL_RADIUS / max_velocity)
    return start if n - start >= max(STALL_MIN_STEPS, n // 10, crossing) else None


def _hedac_config(cfg: ExploreConfig, base, radius: float):
    from tactex.ergodic import HedacConfig

    base = base if base is not None else HedacConfig()
    return replace(
        base, alpha=cfg.alpha, n_eigen=cfg.n_eigen, agent_radius_m=radius, max_velocity=cfg.max_velocity, seed=cfg.seed
    )


def run_explore(
    source: str | Path,
    out_dir: str | Path,
    config: ExploreConfig | None = None,
    *,
    hedac=None,
    progress: Progress | None = None,
    force: bool = False,
    live=None,
) -> ExploreResult:
    """Explore ``source`` (file or built-in object) for ``config.steps`` steps and write the report.

    Args:
        source: cloud file or built-in object name.
        out_dir: run directory (created).
        config: run parameters.
        hedac: a :class:`tactex.ergodic.HedacConfig` for the explorer's other parameters; its
            alpha, n_eigen, agent radius, max velocity and seed are taken from ``config``.
        progress: called with one-line progress messages (e.g. print to stderr).
        force: build the basis of a cloud over :data:`~tactex.spectral.estimate.MAX_BASIS_POINTS` points (refused
            otherwise, before any work, with the voxel size that fits).
        live: a :class:`~tactex.tasks.live_feed.LiveFeed` the steps are shown on (``--view``), or None.

    Raises:
        RunInterrupted: Ctrl-C during the steps, once the steps done are written (a partial run).
    """
    cfg = config if config is not None else ExploreConfig()
    say = progress or (lambda msg: None)
    t0 = time.perf_counter()
    cloud, source_info, keep_out = load_explore_cloud_keep_out(source, cfg)
    load_s = time.perf_counter() - t0
    out = prepare_out_dir(out_dir)  # before the basis and the steps, which take the time
    radius = cfg.agent_radius_m if cfg.agent_radius_m is not None else _default_agent_radius(source_info)
    if cfg.n_eigen is None:
        # Each point of a voxelised cloud stands for about h² of surface.
        cfg = replace(cfg, n_eigen=auto_n_eigen(len(cloud) * cloud.spacing**2, radius, len(cloud)))
    hcfg = _hedac_config(cfg, hedac, radius)
    if cfg.x0 is not None:  # a start off the surface is refused before the basis, which takes the time
        from scipy.spatial import cKDTree

        from tactex.ergodic.explorer import check_snap_distance

        check_snap_distance(cKDTree(cloud.points), np.asarray(cfg.x0, dtype=float), "x0",
                            hcfg.max_snap_distance_voxels, cloud.spacing)
    for note in source_info.get("notes", []):
        say(f"cloud: {note}")
    say(f"cloud: {len(cloud)} points, spacing {cloud.spacing * 1e3:.2f} mm")
    say(f"target: {source_info['target_rule']}: {source_info['target_where']}")
    setup = _set_up(cloud, cfg, hcfg, keep_out, say, force)
    explorer, basis = setup.explorer, setup.basis
    labels = basis.component_labels()
    sizes = np.bincount(labels)
    _say_parts(cfg, hcfg, basis, sizes, explorer, keep_out, say)

    x0, x0_source = _start_position(cloud, cfg, source_info)
    start = explorer.reset(x0)[0].point
    start_part = int(labels[int(np.argmin(np.linalg.norm(cloud.points - start, axis=1)))])
    start_part_target = float(explorer.target[labels == start_part].sum())
    if start_part_target <= 0:
        say("the start lies in a part without target: the agent relocates to the target at its first step"
            if hcfg.relocate else
            "warning: the start lies in a part without target and relocation is off (--relocate); "
            "the agent will not find any")
    n = cfg.steps
    if live is not None:
        live.set_cloud(cloud.points, cloud.colors, explorer.target, keep_out)
    walk = _walk(explorer, n, say, live, setup.preprocess_s)
    trajectory, ergodicity, residual = walk.trajectory, walk.ergodicity, walk.residual
    path_length, air_length, step_s, done = walk.path_length, walk.air_length, walk.step_s, walk.done
    if not (np.isfinite(trajectory).all() and np.isfinite(ergodicity).all() and np.isfinite(residual).all()):
        raise ExplorationError("the exploration produced NaN/inf values; please report this with the cloud and seed")

    stalled = _stalled_from(trajectory, explorer.spacing, hcfg.max_velocity)
    stalled_from = None if stalled is None or residual[-1] <= STALL_RESIDUAL else stalled + 1  # 1-based, as "step k/n"
    relocations = [r for r in explorer.relocations if r.step < done]  # not the step Ctrl-C cut
    _say_outcome(explorer, hcfg, relocations, stalled_from, walk, say)
    coverage = explorer.coverage
    potential = explorer.potential
    metrics: dict[str, Any] = {
        "partial": done < n,  # Ctrl-C stopped the run after steps_done of config.steps
        "steps_done": done,
        "stalled_from_step": stalled_from,
        "source": source_info,
        "n_points": len(cloud),
        "n_target": cloud.n_target,
        "spacing_m": cloud.spacing,
        "n_components": basis.n_components,
        "component_sizes": sorted(sizes.tolist(), reverse=True),
        "start_part_has_target": start_part_target > 0,
        "load_time_s": load_s,
        "basis_time_s": setup.basis_s,
        "explorer_setup_time_s": setup.setup_s,
        "preprocess_time_s": setup.preprocess_s,
        "step_kernel": "numba" if explorer.compiled else "numpy",
        "source_mode": explorer.source_mode,
        "planned_passes": explorer.planned_passes,
        "basis_from_cache": basis.from_cache,
        "step_time_median_s": statistics.median(step_s.tolist()),
        "step_time_max_s": float(step_s.max()),
        "x0": x0,
        "x0_source": x0_source,
        "start_on_surface": start,
        "final_ergodicity": float(ergodicity[-1]),
        "final_coverage_residual": float(residual[-1]),
        "final_path_length_m": float(path_length[-1]),
        "ergodicity": ergodicity,
        "coverage_residual": residual,
        "path_length_m": path_length,
        "air_path_length_m": air_length,
        "final_air_path_length_m": float(air_length[-1]),
        "final_total_path_length_m": float(path_length[-1] + air_length[-1]),
        "relocations": len(relocations),
        "relocation_events": [
            {"step": r.step + 1, "reason": r.reason, "lift_off": r.lift_off, "touch_down": r.point,
             "touch_down_normal": r.normal, "air_length_m": r.air_length_m}
            for r in relocations
        ],
        "keep_out_points": int(keep_out.sum()) if keep_out is not None else 0,
        "keep_out_contacts": explorer.keep_out_contacts,
        "target_near_keep_out": explorer.target_near_keep_out,
        "step_time_s": step_s,
        "config": dataclasses.asdict(cfg),
        "explorer_config": dataclasses.asdict(hcfg),
    }
    say(f"writing the report to {out}")
    files = write_explore_report(out, cloud, trajectory, coverage, potential, metrics, html=cfg.html, start=start,
                                 flights=[r.step for r in relocations], keep_out=keep_out)
    if done < n:
        raise RunInterrupted(f"the {done} steps done (of {n}) are in {out}: metrics.json (\"partial\": true), "
                             "trajectory.npy, series.npz and the plots")
    return ExploreResult(out_dir=out, metrics=to_jsonable(metrics), trajectory=trajectory, files=files)


class _SetUp(NamedTuple):
    """The explorer of a run, its basis and the wall-clock times of making them [s]."""

    explorer: Any
    basis: Any
    basis_s: float
    setup_s: float
    preprocess_s: float


def _set_up(cloud: SurfaceCloud, cfg: ExploreConfig, hcfg, keep_out: np.ndarray | None, say: Progress,
            force: bool = False) -> _SetUp:
    """The Laplace basis of ``cloud`` and the HEDAC explorer on it, saying what they are (and first what the basis
    will cost; a cloud over the size cap is refused without ``force``)."""
    from tactex.ergodic import HedacExplorer
    from tactex.ergodic.kernel import compile_pending
    from tactex.ergodic.sweep import sweeps
    from tactex.spectral import build_basis, estimate
    from tactex.spectral.estimate import check_basis_size

    est = check_basis_size(len(cloud), cfg.n_eigen, cloud.spacing, force=force, points=cloud.points)
    say(f"basis: Laplacian and {cfg.n_eigen} eigenpairs of {len(cloud)} points: {est.describe()} (estimated"
        + ("; a second or two when the cache holds it) ..." if cfg.cache else ") ..."))
    t0 = time.perf_counter()
    basis = build_basis(cloud, n_eigen=cfg.n_eigen, n_neighbors=cfg.n_neighbors, cache=cfg.cache,
                        eigensolver=cfg.eigensolver, eigen_tol=cfg.eigen_tol,
                        progress=say if len(cloud) >= estimate.PROGRESS_MIN_POINTS else None)
    basis_s = time.perf_counter() - t0
    say(f"basis: {basis_s:.3f} s, " + ("read from the cache" if basis.from_cache else
                                        f"{basis.eigensolver} eigensolver")
        + f" ({basis.n_components} connected part(s))")
    # the sweep source steps in numpy (the explorer also leaves the keep-out zone's clearance band out; a target
    # uniform outside the zone is uniform outside the band too)
    if hcfg.compiled and not sweeps(hcfg.source_mode, cloud.target, keep_out) and compile_pending():
        say("explorer: preparing the compiled step (the first time on a machine numba compiles it, ~10–15 s) ...")
    if len(cloud) >= estimate.PROGRESS_MIN_POINTS:
        say(f"explorer: neighbourhoods of {len(cloud)} points (seconds on a large cloud) ...")
    t1 = time.perf_counter()
    # the set-up's neighbourhoods on a large cloud and the pass plan of a large target (laid at the first step) take
    # a while: both say how far they got
    explorer = HedacExplorer(cloud, basis, hcfg, keep_out=keep_out, progress=say)
    setup_s = time.perf_counter() - t1
    preprocess_s = time.perf_counter() - t0
    say(f"explorer: {setup_s:.3f} s, step {'compiled (numba)' if explorer.compiled else 'in numpy'}")
    if explorer.source_mode == "sweep" and explorer.planned_passes:
        origin = "outer edge" if hcfg.sweep_pass_origin == "edge" else "start"
        say(f"source: sweep (the target is the whole surface: every point passed over once) along planned passes "
            f"{hcfg.sweep_pass_spacing:g} r_a apart from the {origin} (0.9 of it where a part's plan leaves fewer "
            "gaps so), then a hunt along the surface and the potential over what they missed; "
            "--sweep-pass-spacing 0 for the potential alone, "
            "--source-mode ergodic for eq. 1–2")
    elif explorer.source_mode == "sweep":
        say("source: sweep (the target is the whole surface: every point passed over once, in passes along what "
            "is covered; --source-mode ergodic for eq. 1–2)")
    return _SetUp(explorer, basis, basis_s, setup_s, preprocess_s)


def _say_parts(cfg: ExploreConfig, hcfg, basis, sizes: np.ndarray, explorer, keep_out: np.ndarray | None,
               say: Progress) -> None:
    """What the run should know before the steps: separate parts of the Laplacian, a keep-out zone."""
    if basis.n_components > 1:
        if hcfg.relocate:
            say(
                f"the Laplacian sees {basis.n_components} separate parts (sizes {sorted(sizes.tolist())[::-1]}; heat "
                "does not diffuse between them, TEC §VI-D): the agent lifts off and moves to the target left on "
                "another part when its own is done"
            )
        else:
            say(
                f"warning: the Laplacian sees {basis.n_components} separate parts (sizes "
                f"{sorted(sizes.tolist())[::-1]}); heat does not diffuse between them (TEC §VI-D) and relocation is "
                f"off (--relocate): raise --n-neighbors (now {cfg.n_neighbors}) to join them"
            )
    if keep_out is not None:
        say(f"keep-out zone: {int(keep_out.sum())} points; the footprint stays off them")
        if explorer.target_near_keep_out:
            clear_mm = explorer.keep_out_clearance_m * 1e3
            say(f"{explorer.target_near_keep_out} target points lie within {clear_mm:.1f} mm of the zone (footprint "
                "radius + ½ voxel), where the agent may not stand: left out of the target and of the coverage "
                "residual (a footprint passing by may still touch them)")


class _Walk(NamedTuple):
    """Per step of a run (the first ``done``): the agent's point [m], ergodicity, coverage residual, path on the
    surface and through the air [m], and the step's wall-clock time [s]."""

    trajectory: np.ndarray
    ergodicity: np.ndarray
    residual: np.ndarray
    path_length: np.ndarray
    air_length: np.ndarray
    step_s: np.ndarray
    done: int


def _walk(explorer, n: int, say: Progress, live=None, preprocess_s: float = 0.0) -> _Walk:
    """``n`` steps of ``explorer`` and their series; Ctrl-C keeps the steps done (and re-raises before any). Shown on
    ``live`` (a LiveFeed) when given: the target no footprint touched yet, the agent, the time per stage."""
    trajectory = np.empty((n, 3))
    ergodicity = np.empty(n)
    residual = np.empty(n)
    path_length = np.empty(n)
    air_length = np.empty(n)
    step_s = np.empty(n)
    every = max(1, n // 10)
    t_loop = last_said = time.perf_counter()
    t_first = t_loop  # the end of the first step: the steps' rate is measured from there
    done = 0  # steps recorded in full
    try:
        for k in range(n):
            t = time.perf_counter()
            cmd = explorer.step()
            step_s[k] = time.perf_counter() - t
            trajectory[k] = cmd.point
            ergodicity[k] = explorer.ergodicity()
            residual[k] = explorer.coverage_residual()
            path_length[k] = explorer.path_length
            air_length[k] = explorer.air_path_length
            done = k + 1
            if live is not None and live.due():
                _show(live, explorer, cmd.point, done, n, time.perf_counter() - t_loop, preprocess_s)
            now = time.perf_counter()
            if k == 0:
                t_first = now
            if (k + 1) % every == 0 or k + 1 == n or now - last_said >= PROGRESS_EVERY_S:
                last_said = now
                # the first step may lay a pass plan (seconds to minutes): the rate of the others is what is left
                eta = (now - t_first) / k * (n - k - 1) if k else None
                say(f"step {k + 1}/{n}: ergodicity {ergodicity[k]:.4f}, coverage residual {residual[k]:.4f}"
                    + (f" (about {eta:.0f} s left)" if eta is not None and k + 1 < n else "")
                    + (f" (the first step: {now - t_loop:.1f} s)" if k == 0 else ""))
    except KeyboardInterrupt:
        if done == 0:
            raise
        # Ctrl-C on a long run: the steps done are written as a partial run, then the interrupt goes on
        say(f"interrupted after {done} of {n} steps: writing them")
        trajectory, ergodicity, residual = trajectory[:done], ergodicity[:done], residual[:done]
        path_length, air_length, step_s = path_length[:done], air_length[:done], step_s[:done]
    return _Walk(trajectory, ergodicity, residual, path_length, air_length, step_s, done)


def _show(live, explorer, point: np.ndarray, done: int, n: int, walk_s: float, preprocess_s: float) -> None:
    """One snapshot of an exploration for the live page; its time is the wall-clock time of the steps [s]."""
    live.publish(walk_s, phase="explore", agent_m=point, progress=done / n,
                 field=np.where(explorer.coverage > 0.0, 0.0, explorer.target),
                 breakdown_s={"basis_and_set_up": preprocess_s, "steps": walk_s},
                 figures={"ergodicity (eq. 48)": explorer.ergodicity(), "step": done})


def _say_outcome(explorer, hcfg, relocations: list, stalled_from: int | None, walk: _Walk, say: Progress) -> None:
    """The run's flights and a stall at its end, in words."""
    if relocations:
        counts = collections.Counter(m.reason for m in relocations)
        why = ", ".join(f"{r} {c}" for r, c in counts.items())
        say(f"relocated {len(relocations)} time(s) ({why}): {walk.air_length[-1]:.3f} m through the air, "
            f"{walk.path_length[-1]:.3f} m on the surface")
    if stalled_from is not None:
        say(
            f"warning: the agent stayed in place from step {stalled_from} on, coverage residual "
            f"{walk.residual[-1]:.3f}"
            + (f": {explorer.untouched_count()} target points left untouched, none the explorer may walk or fly "
               "to (each attempt stalled); HEDAC revisits the surface in place" if hcfg.relocate else
               ": the potential may rise only across gaps it may not leave the cloud to cross; let it relocate "
               "(--relocate), or see --max-off-cloud-voxels, --max-bridge-voxels")
        )


def write_explore_report(
    out: Path,
    cloud: SurfaceCloud,
    trajectory: np.ndarray,
    coverage: np.ndarray,
    potential: np.ndarray,
    metrics: dict[str, Any],
    *,
    html: bool = True,
    start: np.ndarray | None = None,
    flights: Sequence[int] = (),
    keep_out: np.ndarray | None = None,
) -> dict[str, Path]:
    """Write metrics.json, trajectory.npy, fields.npz and the plots of one run into ``out``.

    ``trajectory`` (T, 3) [m] holds each step's point; the plots draw the path from ``start`` (3,) [m]
    (the point the agent started from, before its first step) when given, the flights (the steps k of
    ``trajectory`` reached through the air: relocations) as dashed chords, and the ``keep_out`` (N,)
    (bool) points, which fields.npz also holds."""
    from matplotlib.colors import LinearSegmentedColormap

    from tactex.report import cloud_html, plot_cloud, plot_series, write_metrics

    target_cmap = LinearSegmentedColormap.from_list("target", [c for _, c in TARGET_COLORSCALE])

    out.mkdir(parents=True, exist_ok=True)
    per_step = (*SERIES, "step_time_s")
    scalars = {k: v for k, v in metrics.items() if k not in per_step}
    scalars["series_file"] = "series.npz"
    files = {"metrics": write_metrics(scalars, out / "metrics.json")}
    np.savez(out / "series.npz", **{k: np.asarray(metrics[k], dtype=float) for k in per_step if k in metrics})
    files["series"] = out / "series.npz"
    np.save(out / "trajectory.npy", trajectory, allow_pickle=False)
    files["trajectory"] = out / "trajectory.npy"
    zone = np.zeros(len(cloud), dtype=bool) if keep_out is None else np.asarray(keep_out, dtype=bool)
    np.savez(out / "fields.npz", points=cloud.points, target=cloud.target, coverage=coverage, potential=potential,
             keep_out=zone)
    files["fields"] = out / "fields.npz"
    name = metrics["source"].get("name") or Path(metrics["source"].get("path", "cloud")).stem
    title = f"{name}: {metrics['n_points']} points, K={metrics['config']['n_eigen']}, α={metrics['config']['alpha']:g}"
    steps = np.arange(1, trajectory.shape[0] + 1)
    files["metrics_png"] = plot_series(
        {
            "ergodicity ε (eq. 48)": metrics["ergodicity"],
            "coverage residual": metrics["coverage_residual"],
            "path length [m]": metrics["path_length_m"],
            **({"air path [m]": metrics["air_path_length_m"]} if metrics.get("relocations") else {}),
        },
        out / "metrics.png",
        x=steps,
        title=title,
    )
    fields = {"target": cloud.target, "coverage": coverage, "potential": potential}
    drawn = trajectory if start is None else np.vstack([np.asarray(start, dtype=float)[None], trajectory])
    shift = 0 if start is None else 1  # with the start first, step k's point is row k + 1
    path_kw = {"trajectory": drawn, "flights": [k + shift for k in flights if k + shift >= 1], "keep_out": keep_out}
    files["cloud_png"] = plot_cloud(
        cloud.points,
        fields,
        out / "cloud.png",
        **path_kw,
        title=title,
        cmaps={"target": target_cmap, "coverage": "viridis", "potential": "inferno"},
        labels=FIELD_LABELS,
    )
    if not html:  # a reused run folder must not keep another run's page beside these metrics
        (out / "explore.html").unlink(missing_ok=True)
    if html:
        files["html"] = cloud_html(
            cloud.points,
            fields,
            out / "explore.html",
            **path_kw,
            title=title,
            colorscales={"target": TARGET_COLORSCALE, "coverage": "Viridis", "potential": "Inferno"},
            keep=cloud.target > 0,
            normals=cloud.normals,
        )
    return files
