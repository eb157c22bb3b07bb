"""`tactex sweep`: the parameter study of TEC §V-B (Fig. 6–11).

The paper explores each cloud from ten start positions for every pair of the number of
eigencomponents n_K ∈ {25, 50, 100, 200} and the diffusion scale α ∈ {1, 5, 10, 50, 100}, 1000
steps each, and reports the normalised ergodicity (eq. 48) against n_K (Fig. 6, 9), against α
(Fig. 7, 10) and over time at n_K = 200, α = 10 (Fig. 11), with example paths (Fig. 8).

The basis is built once per cloud with the largest n_K; a smaller n_K uses its first columns,
which are exactly the smaller eigenbasis (the eigenpairs are sorted). The settings are
independent runs on an :class:`~tactex.experiments.executor.Executor` (local processes or Ray; the
clouds and bases are its shared input); the result does not depend on the executor, the number of
workers or the order the settings finish in.

Each setting is written to ``settings/`` in the run directory as soon as it is done (an ``.npz``
named by cloud, n_K and α, holding a fingerprint of everything its result depends on). A sweep
that stops — Ctrl-C, a power cut, an error — is resumed by running the same command again with the
same ``--out``: settings whose fingerprint matches are read back instead of run again. On Ctrl-C the
report of the settings done is written (``sweep.json`` with ``"partial": true``, the settings not run
listed under ``not_run``), then :class:`~tactex.errors.RunInterrupted` is raised.

Outputs in the run directory: ``sweep.json`` (configuration, per-setting statistics, failed
settings with their errors, ``ran_on``: the worker and attempt of each setting run in this session),
``table.csv`` (one row per cloud, setting and start: the final ergodicity, coverage residual and
path length — the table pandas or polars users load),
``curves.npz`` (per cloud: ergodicity, coverage residual and path length of every run and step,
and the path of the first start for every setting), and per cloud ``<name>_vs_n_eigen.png``,
``<name>_vs_alpha.png``, ``<name>_time.png`` and ``<name>_paths.png``.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from tactex.config import param, to_jsonable, write_json
from tactex.errors import ConfigError, ExplorationError, RunInterrupted
from tactex.experiments.executor import Executor, LocalExecutor
from tactex.experiments.explore import (
    ExploreConfig,
    _default_agent_radius,
    authors_starts,
    load_explore_cloud_keep_out,
)
from tactex.experiments.run_folder import prepare_out_dir
from tactex.pointcloud.keep_out import DEFAULT_KEEP_OUT_THRESHOLD

__all__ = ["SweepConfig", "SweepResult", "run_sweep", "sweep_starts"]

Progress = Callable[[str], None]

#: The setting of TEC Fig. 11 (time evolution), taken when it is part of the grid.
FIG11_SETTING = (200, 10.0)


@dataclass(frozen=True)
class SweepConfig:
    """The grid and the fixed parameters; defaults are the paper's (§V-B, Table II)."""

    n_eigen: tuple[int, ...] = param((25, 50, 100, 200), "numbers of eigencomponents n_K to compare (Fig. 6, 9) [-]")
    alpha: tuple[float, ...] = param((1.0, 5.0, 10.0, 50.0, 100.0), "diffusion scales α to compare (Fig. 7, 10) [-]")
    starts: int = param(10, "start positions per setting (the authors' *_x0_arr_10.npz when beside the file) [-]")
    steps: int = param(1000, "exploration steps per run [-]")
    voxel_size_m: float = param(0.003, "voxel edge of the down-sampling (sampling spacing of meshes and built-ins) "
                                       "[m]", aliases=("--voxel-size",))
    n_neighbors: int = param(30, "neighbours of the Laplacian; decides which parts connect (TEC §VI-D) [-]")
    agent_radius_m: float | None = param(
        None, "agent footprint radius r_a [m]; by default 0.015 on plates, else 0.0075 (TEC §V-B)",
        aliases=("--agent-radius",))
    seed: int = param(0, "seed of the random start positions (clouds without the authors' starts) [-]")
    coverage_normalization: str = param(
        "domain",
        "coverage normalisation of the source: 'domain' = eq. 2 as in the paper's study (the explorer's default "
        "'target' favours touching every target point over the time share that eq. 48 measures)",
    )
    target: str = param(
        "auto", "target of a cloud file, as in `tactex explore`: red, green or blue (by hue and saturation), "
        "stored, all (the whole surface), or auto (the stored target if there is one, else red)",
        aliases=("--target-channel",))
    target_saturation: float = param(0.5, "least saturation of a marked colour, 0–1, as in `tactex explore`")
    target_threshold: float | None = param(
        None, "TEC's raw rule instead of hue: the --target colour's channel ≥ this level, 0–1")
    units: str = param("m", "length unit of the cloud and mesh files: m, mm or in, as in `tactex explore`")
    keep_out_channel: str = param(
        "", "colour channel marking a keep-out zone no footprint may touch, as in `tactex explore`: red, green or "
        "blue ('' = none); a PLY's own keep_out property is kept out too, merged with these options")
    keep_out_threshold: float = param(DEFAULT_KEEP_OUT_THRESHOLD, "with --keep-out-channel: the channel level at or "
                                      "above which a point is kept out, 0–1 [-]")
    keep_out_mask: str = param(
        "", "a .npy file with one boolean per row of every cloud file given (True = keep out), as in `tactex explore`")
    workers: int = param(0, "worker processes; 0 = one per core [-]")
    cache: bool = param(True, "reuse/store the Laplace basis in the cache ($TACTEX_CACHE_DIR)")

    def __post_init__(self) -> None:
        for name, kind in (("n_eigen", int), ("alpha", float)):
            values = getattr(self, name)
            if isinstance(values, (int, float)):
                values = (values,)
            try:
                values = tuple(kind(v) for v in values)
            except (TypeError, ValueError) as exc:
                raise ConfigError(f"SweepConfig.{name} must be a list of numbers, got {getattr(self, name)!r}") from exc
            if not values:
                raise ConfigError(f"SweepConfig.{name} needs at least one value")
            if any(not math.isfinite(v) or v <= 0 for v in values):
                raise ConfigError(f"SweepConfig.{name} values must be positive, got {values}")
            if name == "n_eigen" and any(v != float(x) for v, x in zip(values, getattr(self, name), strict=True)):
                raise ConfigError(f"SweepConfig.n_eigen values must be integers, got {getattr(self, name)!r}")
            if len(set(values)) != len(values):
                raise ConfigError(f"SweepConfig.{name} lists a value twice: {values}")
            object.__setattr__(self, name, tuple(sorted(values)))
        from tactex.ergodic.config import check_coverage_normalization

        check_coverage_normalization(self.coverage_normalization, "SweepConfig")
        for name, low in (("starts", 1), ("steps", 1), ("n_neighbors", 1), ("workers", 0), ("seed", 0)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < low:
                raise ConfigError(f"SweepConfig.{name} must be an integer ≥ {low}, got {v!r}")
        # the remaining fields are checked by ExploreConfig with the same rules as `tactex explore`
        self.explore_config()

    def explore_config(self) -> ExploreConfig:
        return ExploreConfig(voxel_size_m=self.voxel_size_m, n_eigen=max(self.n_eigen), n_neighbors=self.n_neighbors,
                             steps=self.steps, agent_radius_m=self.agent_radius_m, seed=self.seed, cache=self.cache,
                             target=self.target, target_saturation=self.target_saturation,
                             target_threshold=self.target_threshold, units=self.units,
                             keep_out_channel=self.keep_out_channel, keep_out_threshold=self.keep_out_threshold,
                             keep_out_mask=self.keep_out_mask, html=False)


@dataclass
class SweepResult:
    """What a sweep produced: ``summary`` is what ``sweep.json`` holds; ``curves`` per cloud name."""

    out_dir: Path
    summary: dict[str, Any]
    curves: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    files: dict[str, Path] = field(default_factory=dict)


def sweep_starts(cloud, source_info: dict[str, Any], count: int, seed: int,
                 keep_out: np.ndarray | None = None) -> tuple[np.ndarray, str]:
    """(count, 3) start positions [m]: the authors' starts beside a cloud file (TEC data), topped
    up with cloud points drawn with ``seed`` (outside the ``keep_out`` zone, (N,) bool, when there is
    one); for built-in objects all drawn."""
    starts = np.zeros((0, 3))
    origin = f"cloud points drawn with seed {seed}"
    found = authors_starts(source_info)
    if found is not None:
        arr, name = found
        starts = arr[np.isfinite(arr).all(axis=1)][:count]
        origin = name if len(starts) == count else f"{name} + {origin}"
    missing = count - len(starts)
    if missing > 0:
        rng = np.random.default_rng(seed)
        allowed = np.arange(len(cloud)) if keep_out is None else np.flatnonzero(~np.asarray(keep_out, dtype=bool))
        idx = allowed[rng.choice(allowed.size, size=missing, replace=missing > allowed.size)]
        starts = np.vstack([starts, cloud.points[idx]])
    return starts, origin


def _cloud_key(source: str, info: dict[str, Any], taken: set[str]) -> str:
    base = info.get("name") or Path(info.get("path", source)).stem
    key = re.sub(r"[^A-Za-z0-9_-]+", "_", str(base)) or "cloud"
    out, i = key, 2
    while out in taken:
        out, i = f"{key}_{i}", i + 1
    return out


# -- worker side: one (cloud, n_K, α) setting, all starts -----------------------------------------------
def _run_setting(task: tuple, clouds: dict[str, tuple]) -> dict[str, np.ndarray]:
    """One setting (a run of the executor); ``clouds`` are the shared, read-only clouds and bases."""
    from tactex.ergodic import HedacConfig, HedacExplorer

    key, n_eigen, alpha, steps, normalization = task
    cloud, basis, starts, radius, keep_out = clouds[key]
    # The paper's study measures eq. 1–2's HEDAC: no sweep source, even for a whole-surface target.
    hedac = HedacConfig(alpha=alpha, n_eigen=n_eigen, agent_radius_m=radius, coverage_normalization=normalization,
                        source_mode="ergodic")
    explorer = HedacExplorer(cloud, basis, hedac, keep_out=keep_out)
    n = len(starts)
    erg, res, path = np.empty((n, steps)), np.empty((n, steps)), np.empty((n, steps))
    contacts = np.zeros(n)  # kept-out points a footprint touched in each run (0 unless something is wrong)
    first_path = np.empty((steps, 3))
    for s, x0 in enumerate(starts):
        explorer.reset(x0)
        for k in range(steps):
            cmd = explorer.step()
            erg[s, k] = explorer.ergodicity()
            res[s, k] = explorer.coverage_residual()
            path[s, k] = explorer.path_length
            if s == 0:
                first_path[k] = cmd.point
        contacts[s] = explorer.keep_out_contacts
    if not (np.isfinite(erg).all() and np.isfinite(res).all() and np.isfinite(first_path).all()):
        raise ExplorationError(f"{key}: n_K={n_eigen}, α={alpha:g} produced NaN/inf; please report it with the cloud")
    return {"ergodicity": erg, "coverage_residual": res, "path_length_m": path, "first_path": first_path,
            "keep_out_contacts": contacts}


# -- driver ----------------------------------------------------------------------------------------------
def prepare_clouds(sources: Sequence[str | Path], cfg: SweepConfig, say: Progress, force: bool = False
                   ) -> tuple[dict[str, tuple], dict[str, Any]]:
    """Per source: (cloud, basis of the largest n_K, starts, agent radius, keep-out zone (N,) bool or
    None) — the runs' shared input — and what ``sweep.json`` says about it. A cloud over the basis size cap is
    refused unless ``force``."""
    from tactex.spectral import build_basis, estimate
    from tactex.spectral.estimate import check_basis_size

    ecfg = cfg.explore_config()
    clouds: dict[str, tuple] = {}
    info_out: dict[str, Any] = {}
    for source in sources:
        cloud, info, keep_out = load_explore_cloud_keep_out(source, ecfg)
        key = _cloud_key(str(source), info, set(clouds))
        for note in info.get("notes", []):
            say(f"{key}: {note}")
        if max(cfg.n_eigen) >= len(cloud):
            raise ConfigError(f"{key} has {len(cloud)} points; n_K = {max(cfg.n_eigen)} must be smaller")
        est = check_basis_size(len(cloud), max(cfg.n_eigen), cloud.spacing, force=force,
                               points=cloud.points)
        say(f"{key}: {len(cloud)} points, {cloud.n_target} target; Laplacian and {max(cfg.n_eigen)} eigenpairs: "
            f"{est.describe()} (estimated) ...")
        t0 = time.perf_counter()
        basis = build_basis(cloud, n_eigen=max(cfg.n_eigen), n_neighbors=cfg.n_neighbors, cache=cfg.cache,
                            progress=say if len(cloud) >= estimate.PROGRESS_MIN_POINTS else None)
        basis_s = time.perf_counter() - t0
        radius = cfg.agent_radius_m if cfg.agent_radius_m is not None else _default_agent_radius(info)
        starts, origin = sweep_starts(cloud, info, cfg.starts, cfg.seed, keep_out)
        clouds[key] = (cloud, basis, starts, radius, keep_out)
        n_keep_out = int(keep_out.sum()) if keep_out is not None else 0
        if n_keep_out:
            say(f"{key}: keep-out zone: {n_keep_out} points; the footprint stays off them")
        info_out[key] = {"source": info, "n_points": len(cloud), "n_target": cloud.n_target,
                         "keep_out_points": n_keep_out,
                         "spacing_m": cloud.spacing, "n_components": basis.n_components, "basis_time_s": basis_s,
                         "agent_radius_m": radius, "starts": starts, "starts_from": origin}
        if basis.n_components > 1:
            say(f"{key}: warning: the Laplacian sees {basis.n_components} separate parts; heat does not cross "
                f"between them (TEC §VI-D); raise --n-neighbors (now {cfg.n_neighbors}) to join them")
    return clouds, info_out


def run_sweep(sources: Sequence[str | Path], out_dir: str | Path, config: SweepConfig | None = None, *,
              progress: Progress | None = None, executor: Executor | None = None, force: bool = False) -> SweepResult:
    """Run the grid of ``config`` on every source (cloud file or built-in object) and write the report.

    The settings run on ``executor`` (default: ``config.workers`` local processes), which gets the
    clouds and bases once as shared input. A setting that raises is listed under ``failed`` in
    ``sweep.json`` with its error; its curves are NaN and the others are unaffected. ``force`` builds the basis of a
    cloud over :data:`~tactex.spectral.estimate.MAX_BASIS_POINTS` points (refused otherwise)."""
    cfg = config if config is not None else SweepConfig()
    say = progress or (lambda msg: None)
    if isinstance(sources, (str, Path)) or not sources:
        raise ConfigError("run_sweep needs a list of one or more clouds (files or built-in objects)")
    out = prepare_out_dir(out_dir)
    clouds, info_out = prepare_clouds(sources, cfg, say, force)
    all_jobs = [(key, k, a) for key in clouds for k in cfg.n_eigen for a in cfg.alpha]
    store = _SettingStore(out / "settings", clouds, cfg)
    results: dict[tuple, dict[str, np.ndarray]] = {job: r for job in all_jobs if (r := store.load(job)) is not None}
    if results:
        say(f"resuming: {len(results)} of {len(all_jobs)} settings already done in {store.folder}")
    jobs = [job for job in all_jobs if job not in results]
    ex = executor if executor is not None else LocalExecutor(max(1, min(cfg.workers or os.cpu_count() or 1,
                                                                       len(jobs))))
    runs = len(jobs) * cfg.starts
    say(f"{len(jobs)} settings × {cfg.starts} starts × {cfg.steps} steps = {runs} runs on {ex.describe()}")
    t0 = time.perf_counter()
    failed: list[dict[str, Any]] = []
    ran_on: list[dict[str, Any]] = []  # where each setting of this session ran (worker, attempt): sweep.json
    tasks = [(*job, cfg.steps, cfg.coverage_normalization) for job in jobs]
    interrupted = False
    try:
        for done, outcome in enumerate(ex.run(_run_setting, tasks, clouds), start=1):
            job = jobs[outcome.index]
            ran_on.append({"cloud": job[0], "n_eigen": job[1], "alpha": job[2], "worker": outcome.worker,
                           "attempt": outcome.attempt, "seconds": outcome.seconds})
            if outcome.ok:
                results[job] = outcome.value
                store.save(job, outcome.value)  # on disk at once: a stopped sweep resumes from here
                _report(say, done, len(jobs), job, results[job], t0)
            else:
                failed.append({"cloud": job[0], "n_eigen": job[1], "alpha": job[2], "error": outcome.error,
                               "traceback": outcome.traceback})
                say(f"[{done}/{len(jobs)}] {job[0]} n_K={job[1]} α={job[2]:g}: FAILED {outcome.error}")
    except KeyboardInterrupt:
        if not results:
            raise
        # Ctrl-C: the report of the settings done is written (the others NaN, "not run"), then the interrupt goes on
        interrupted = True
        say(f"interrupted: writing the {len(results)} of {len(all_jobs)} settings done")
    finally:
        if executor is None:
            ex.close()
    if not results:
        raise ExplorationError(f"every setting of the sweep failed; the first: {failed[0]['error']}")
    nan = {"ergodicity": np.full((cfg.starts, cfg.steps), np.nan),
           "coverage_residual": np.full((cfg.starts, cfg.steps), np.nan),
           "path_length_m": np.full((cfg.starts, cfg.steps), np.nan), "first_path": np.full((cfg.steps, 3), np.nan),
           "keep_out_contacts": np.full(cfg.starts, np.nan)}
    not_run = [job for job in all_jobs if job not in results and all(
        (f["cloud"], f["n_eigen"], f["alpha"]) != job for f in failed)]
    for job in all_jobs:
        results.setdefault(job, nan)
    sweep_s = time.perf_counter() - t0

    curves: dict[str, dict[str, np.ndarray]] = {}
    summary: dict[str, Any] = {"config": asdict(cfg), "executor": ex.describe(), "sweep_time_s": sweep_s,
                               "partial": interrupted, "failed": failed, "ran_on": ran_on,
                               "not_run": [{"cloud": c, "n_eigen": k, "alpha": a} for c, k, a in not_run],
                               "clouds": {}}
    nk, na = len(cfg.n_eigen), len(cfg.alpha)
    for key in clouds:
        c = {name: np.empty((nk, na, cfg.starts, cfg.steps)) for name in ("ergodicity", "coverage_residual",
                                                                           "path_length_m")}
        c["first_path"] = np.empty((nk, na, cfg.steps, 3))
        c["keep_out_contacts"] = np.empty((nk, na, cfg.starts))
        rows = []
        for i, k in enumerate(cfg.n_eigen):
            for j, a in enumerate(cfg.alpha):
                r = results[(key, k, a)]
                for name in r:
                    c[name][i, j] = r[name]
                final = r["ergodicity"][:, -1]
                rows.append({"n_eigen": k, "alpha": a,
                             "final_ergodicity_mean": float(final.mean()), "final_ergodicity_std": float(final.std()),
                             "final_ergodicity": final,
                             "final_coverage_residual_mean": float(r["coverage_residual"][:, -1].mean()),
                             "path_length_mean_m": float(r["path_length_m"][:, -1].mean()),
                             "keep_out_contacts_max": float(np.max(r["keep_out_contacts"]))})
        c["n_eigen"] = np.asarray(cfg.n_eigen)
        c["alpha"] = np.asarray(cfg.alpha)
        c["agent_radius_m"] = np.asarray(clouds[key][3])
        c["starts"] = clouds[key][2]
        if clouds[key][4] is not None:
            c["keep_out"] = clouds[key][4]
        curves[key] = c
        best = min(rows, key=lambda row: (not np.isfinite(row["final_ergodicity_mean"]), row["final_ergodicity_mean"]))
        summary["clouds"][key] = {**info_out[key], "results": rows,
                                  "best": {"n_eigen": best["n_eigen"], "alpha": best["alpha"],
                                           "final_ergodicity_mean": best["final_ergodicity_mean"]}}
    say(f"writing the report to {out}")
    files = _write(out, summary, curves, clouds)
    files["table"] = _write_table(out / "table.csv", curves, {(f["cloud"], f["n_eigen"], f["alpha"]): f["error"]
                                                              for f in failed}, set(not_run))
    if interrupted:
        raise RunInterrupted(f"the {len(all_jobs) - len(not_run)} settings done (of {len(all_jobs)}) are in {out}: "
                             "sweep.json (\"partial\": true), table.csv, curves.npz and the plots; run the same "
                             "command again to resume")
    return SweepResult(out_dir=out, summary=to_jsonable(summary), curves=curves, files=files)


def _write_table(path: Path, curves: dict[str, dict[str, np.ndarray]], failed: dict[tuple, str],
                 not_run: set[tuple] = frozenset()) -> Path:
    from tactex.experiments.study_table import write_csv

    cols = ["cloud", "n_eigen", "alpha", "start", "status", "error", "final_ergodicity", "final_coverage_residual",
            "path_length_m"]
    rows = []
    for key, c in curves.items():
        for i, k in enumerate(c["n_eigen"].tolist()):
            for j, a in enumerate(c["alpha"].tolist()):
                error = failed.get((key, k, a), "")
                for s in range(c["ergodicity"].shape[2]):
                    status = "failed" if error else "not run" if (key, k, a) in not_run else "ok"
                    rows.append([key, k, a, s, status, error.splitlines()[0] if error else "",
                                 float(c["ergodicity"][i, j, s, -1]), float(c["coverage_residual"][i, j, s, -1]),
                                 float(c["path_length_m"][i, j, s, -1])])
    return write_csv(path, cols, rows)


def _report(say: Progress, done: int, total: int, job: tuple, r: dict[str, np.ndarray], t0: float) -> None:
    key, k, a = job
    final = r["ergodicity"][:, -1]
    elapsed = time.perf_counter() - t0
    eta = elapsed / done * (total - done)
    say(f"[{done}/{total}] {key} n_K={k} α={a:g}: final ergodicity {final.mean():.4f} ± {final.std():.4f} (std of "
        f"{final.size} starts; {elapsed:.0f} s, about {eta:.0f} s left)")


class _SettingStore:
    """One ``.npz`` per finished (cloud, n_K, α) setting, keyed by a fingerprint of its inputs."""

    def __init__(self, folder: Path, clouds: dict[str, tuple], cfg: SweepConfig) -> None:
        self.folder = folder
        self.prints: dict[str, str] = {}
        for key, (cloud, _basis, starts, radius, keep_out) in clouds.items():
            h = hashlib.sha256()
            for arr in (cloud.points, cloud.target, np.asarray(starts, dtype=float)):
                h.update(np.ascontiguousarray(arr, dtype=np.float64).tobytes())
            if keep_out is not None:  # a setting run without the zone is not one run with it
                h.update(b"keep_out" + np.packbits(keep_out).tobytes())
            h.update(json.dumps([cfg.steps, cfg.n_neighbors, cfg.coverage_normalization, float(radius),
                                 float(cloud.spacing), max(cfg.n_eigen)]).encode())
            self.prints[key] = h.hexdigest()

    def _path(self, job: tuple) -> Path:
        key, k, a = job
        return self.folder / f"{key}_K{k}_alpha{a:g}.npz"

    def _print(self, job: tuple) -> str:
        key, k, a = job
        return f"{self.prints[key]}:{k}:{a!r}"

    def load(self, job: tuple) -> dict[str, np.ndarray] | None:
        path = self._path(job)
        if not path.is_file():
            return None
        try:
            with np.load(path, allow_pickle=False) as z:
                if str(z["fingerprint"]) != self._print(job):
                    return None  # another cloud or other parameters: run it again
                return {name: z[name] for name in ("ergodicity", "coverage_residual", "path_length_m", "first_path",
                                                   "keep_out_contacts")}
        except (OSError, ValueError, KeyError):  # a file cut short by the stop: run it again
            return None

    def save(self, job: tuple, r: dict[str, np.ndarray]) -> None:
        self.folder.mkdir(parents=True, exist_ok=True)
        tmp = self._path(job).with_suffix(".tmp.npz")
        np.savez(tmp, fingerprint=np.asarray(self._print(job)), **r)
        os.replace(tmp, self._path(job))  # never a half-written setting under its real name


# -- report ----------------------------------------------------------------------------------------------
def _write(out: Path, summary: dict[str, Any], curves: dict[str, dict[str, np.ndarray]],
           clouds: dict[str, tuple]) -> dict[str, Path]:
    out.mkdir(parents=True, exist_ok=True)
    files = {"summary": write_json(to_jsonable(summary), out / "sweep.json")}
    flat = {f"{key}.{name}": arr for key, c in curves.items() for name, arr in c.items()}
    np.savez_compressed(out / "curves.npz", **flat)
    files["curves"] = out / "curves.npz"
    for key, c in curves.items():
        cloud = clouds[key][0]
        files[f"{key}_vs_n_eigen"] = _plot_final(c, "n_eigen", out / f"{key}_vs_n_eigen.png", key)
        files[f"{key}_vs_alpha"] = _plot_final(c, "alpha", out / f"{key}_vs_alpha.png", key)
        files[f"{key}_time"] = _plot_time(c, out / f"{key}_time.png", key)
        files[f"{key}_paths"] = _plot_paths(c, cloud, out / f"{key}_paths.png", key)
    return files


def _figure(width: float, height: float):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=110)
    FigureCanvasAgg(fig)
    return fig


def _plot_final(c: dict[str, np.ndarray], axis: str, path: Path, key: str) -> Path:
    """Fig. 6/9 (x = n_K, one line per α) or Fig. 7/10 (x = α, one line per n_K): final ergodicity,
    mean ± std over the starts."""
    final = c["ergodicity"][..., -1]  # (n_K, α, starts)
    x, other, other_name = (c["n_eigen"], c["alpha"], "α") if axis == "n_eigen" else (c["alpha"], c["n_eigen"], "n_K")
    data = final if axis == "n_eigen" else final.transpose(1, 0, 2)  # (x, other, starts)
    fig = _figure(5.5, 3.6)
    ax = fig.add_subplot(1, 1, 1)
    for j, v in enumerate(other):
        mean, std = data[:, j].mean(axis=1), data[:, j].std(axis=1)
        ax.errorbar(x, mean, yerr=std, marker="o", capsize=3, label=f"{other_name} = {v:g}")
    ax.set_xscale("log")
    ax.minorticks_off()
    ax.set_xticks(x, [f"{v:g}" for v in x])
    ax.set_xlabel("number of eigencomponents n_K" if axis == "n_eigen" else "diffusion scale α")
    ax.set_ylabel("ergodicity after the run (eq. 48)")
    ax.set_title(f"{key}: final ergodicity, mean ± std of {final.shape[2]} starts")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path)
    return path


def _nearest(values: np.ndarray, target: float) -> int:
    return int(np.argmin(np.abs(np.log(np.asarray(values, dtype=float) / target))))


def _plot_time(c: dict[str, np.ndarray], path: Path, key: str) -> Path:
    """Fig. 11: ergodicity over time at the grid point nearest n_K = 200, α = 10 — each start thin,
    the mean, and ± one standard deviation shaded."""
    i, j = _nearest(c["n_eigen"], FIG11_SETTING[0]), _nearest(c["alpha"], FIG11_SETTING[1])
    runs = c["ergodicity"][i, j]  # (starts, steps)
    steps = np.arange(1, runs.shape[1] + 1)
    fig = _figure(5.5, 3.6)
    ax = fig.add_subplot(1, 1, 1)
    for r in runs:
        ax.plot(steps, r, color="tab:blue", alpha=0.25, lw=0.8)
    mean, std = runs.mean(axis=0), runs.std(axis=0)
    ax.fill_between(steps, mean - std, mean + std, color="tab:blue", alpha=0.2)
    ax.plot(steps, mean, color="tab:blue", lw=2, label="mean")
    ax.set_xlabel("step")
    ax.set_ylabel("ergodicity (eq. 48)")
    ax.set_title(f"{key}: n_K = {c['n_eigen'][i]}, α = {c['alpha'][j]:g}, {runs.shape[0]} starts")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path)
    return path


def _plot_paths(c: dict[str, np.ndarray], cloud, path: Path, key: str) -> Path:
    """Fig. 8: paths of the first start for the best, the worst and representative settings, on the
    cloud with the target in red; start green, end purple."""
    final = c["ergodicity"][..., -1].mean(axis=2)  # (n_K, α)
    order = np.argsort(final, axis=None)
    picks = list(dict.fromkeys([order[0], order[-1], *order[np.linspace(0, order.size - 1, 6).astype(int)]]))[:6]
    pts, tgt = cloud.points, cloud.target > 0
    fig = _figure(4.0 * min(3, len(picks)), 4.0 * math.ceil(len(picks) / 3))
    for n, flat in enumerate(picks):
        i, j = np.unravel_index(flat, final.shape)
        ax = fig.add_subplot(math.ceil(len(picks) / 3), min(3, len(picks)), n + 1, projection="3d")
        ax.computed_zorder = False
        ax.scatter(*pts[~tgt].T, s=1, color="lightgrey", label="surface")
        ax.scatter(*pts[tgt].T, s=1.5, color="red", label="target")
        if "keep_out" in c:
            ax.scatter(*pts[c["keep_out"]].T, s=1.5, color="tab:blue", label="keep-out")
        p = c["first_path"][i, j]
        ax.plot(*p.T, color="black", lw=0.8, label="path")
        ax.scatter(*p[0], color="green", s=25, label="start")
        ax.scatter(*p[-1], color="purple", s=25, label="end")
        radius_mm = 1e3 * float(c["agent_radius_m"])
        ax.set_title(f"({c['n_eigen'][i]}, {c['alpha'][j]:g}, {radius_mm:g})  ε={final[i, j]:.3f}", fontsize=8)
        ax.set_xlabel("x [m]", fontsize=7)
        ax.set_ylabel("y [m]", fontsize=7)
        ax.set_zlabel("z [m]", fontsize=7)
        ax.tick_params(labelsize=5)
        if n == 0:
            ax.legend(loc="upper left", fontsize=6, framealpha=0.8)
    fig.suptitle(f"{key}: (n_K, α, r_a [mm]) and final ergodicity")
    fig.tight_layout()
    fig.savefig(path)
    return path
