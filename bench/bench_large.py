"""Large surfaces (issue 19): the hierarchical eigensolver against ARPACK and the authors' pipeline, and
how the basis and the exploration step scale from 3k to 150k points.

Clouds: a gently curved panel sampled on a jittered 3 mm grid (0.9 × 0.6 m at 60k points; the same
aspect, and so a larger area, at more points), the TEC bunny (3 mm voxels) for the comparison with
the authors. Every solver runs with one BLAS thread (``tactex.spectral.exact``); ratios are of
medians of calls interleaved in the same run (a, b, a, b, …; for three, a, b, c, a, c, b, … so that each
call follows each of the others equally often), since this machine's speed swings.

* ``large.speedup_vs_authors_3k``: the authors' released pipeline (robust_laplacian with 40
  neighbours, scipy's generalised shift-invert ``eigsh(L, 100, M, sigma=1e-12)``) over ours
  (``build_basis(n_eigen=100)``, solver ``auto``) on the bunny; ``authors_3k_s`` and ``ours_3k_s``
  are the medians, ``ours_3k_hierarchical_s`` ours with the hierarchical solver forced (``*_cpu_s``:
  the same in process CPU time, steadier than wall time on a loaded machine); ``*_3k_hierarchical``
  errors and span angle: the hierarchical basis against ARPACK's, as for 60k below.
* ``large.speedup_vs_arpack_60k``: our ARPACK path over the hierarchical solver, K = 200, on the
  60k panel (eigenpairs only, from the same L and M); ``arpack_60k_s``, ``hierarchical_60k_s``.
* ``large.eigenvalue_max_rel_error_60k``: max over k = 2…200 of |λ_k − λ_k(ARPACK)| / λ_k(ARPACK);
  ``span_angle_deg_60k``: the largest principal angle between the two 200-dimensional spans (M inner
  product); ``hierarchical_60k_info``: levels, iterations, the η² reached.
* ``large.sizes.<N>.{laplacian_s, eigen_s, peak_memory_gb, step_us_median}``: per panel size N, in a
  fresh process each: Laplacian, eigenbasis (K = 200, solver ``auto``; numba's first use in the process,
  which the exploration step would pay otherwise, is timed before it as ``numba_init_s``), the process's peak resident
  memory, and the median exploration step (compiled, 1 agent) with a target band covering 30 % of
  the panel (``target_fraction``), over ``STEPS`` steps after ``WARMUP`` (the basis is computed once
  per size: the step's cost does not depend on how it was computed); ``step_us_median_target_1pct``
  the same with a 1 % band (what the target's size still costs: an O(n_target) scalar pass).
* ``large.tec_coverage``: coverage residual at 0.5/1/2 m of path on the TEC clouds (bench_ergodic's
  protocol and ten starts) with the ARPACK basis and with the hierarchical one, and the mean and
  standard error of their per-start difference.
* ``large.whole_surface_100k.{pass_plan_s, pass_plan_cpu_s, first_progress_s, step_us_median, step_us_p90,
  step_cpu_us_median, n_points, n_eigen, waypoints, arcs, ...}``: a whole-surface target (``--target all``: the
  sweep with planned passes) on the 100k panel, in a fresh process: the basis with ``WHOLE_N_EIGEN`` eigenpairs
  (the hierarchical solver; the basis is not what is measured), then the explorer's first step, which lays the
  pass plan (``pass_plan_s``, wall and CPU), the time from the start of that step to its first progress line
  (``first_progress_s``; ``explorer_setup_s`` comes before it, and ``tactex explore`` announces it), and the
  median and 90th percentile of ``WHOLE_STEPS`` steps after it (wall, and CPU in ``step_cpu_us_*``);
  ``load_avg_1min`` beside them.
* ``bench/large.png``: the scaling table as a plot.

``--quick`` runs the bunny comparison (2 repeats), the 3k and 18k sizes and no 60k/150k or coverage.
``--cases whole_surface`` (bench/run.py) runs only the whole-surface row.
"""

from __future__ import annotations

import functools
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))

from bench_spectral import _authors_pipeline, _timed_each  # noqa: E402

SIZES = (3000, 18000, 60000, 150000)
QUICK_SIZES = (3000, 18000)
K = 200
STEPS = 600
WARMUP = 100
TARGET_FRACTION = 0.3
PANEL_ASPECT = (0.9, 0.6)  # [m] at 60k points

WHOLE_POINTS = 100_000
WHOLE_N_EIGEN = 100
WHOLE_STEPS = 600
TARGETS = {
    "large.whole_surface_100k.pass_plan_s": ("<=", 10.0),
    "large.whole_surface_100k.first_progress_s": ("<=", 5.0),
    "large.whole_surface_100k.step_us_median": ("<=", 1000.0),
    "large.speedup_vs_authors_3k": (">=", 2.0),
    "large.speedup_vs_arpack_60k": (">=", 5.0),
    "large.eigenvalue_max_rel_error_60k": ("<=", 0.01),
    "large.sizes.150000.peak_memory_gb": ("<=", 4.0),
    "large.sizes.150000.step_us_median": ("<=", 1000.0),
}


def panel(n_points: int, seed: int = 0):
    """A gently curved panel of about ``n_points`` points on a jittered 3 mm grid, as a SurfaceCloud (no target)."""
    from tactex.pointcloud import SurfaceCloud

    h = np.sqrt(PANEL_ASPECT[0] * PANEL_ASPECT[1] / 60000)
    scale = np.sqrt(n_points / 60000)
    w, d = PANEL_ASPECT[0] * scale, PANEL_ASPECT[1] * scale
    nx, ny = round(w / h), round(d / h)
    x, y = np.meshgrid((np.arange(nx) + 0.5) * h - w / 2, (np.arange(ny) + 0.5) * h - d / 2, indexing="ij")
    rng = np.random.default_rng(seed)
    x = x.ravel() + rng.uniform(-0.15, 0.15, x.size) * h
    y = y.ravel() + rng.uniform(-0.15, 0.15, y.size) * h
    z = 0.32 * (x / 0.9) ** 2 + 0.12 * (y / 0.6) ** 2  # 8 cm and 3 cm of sag over the 60k panel
    return SurfaceCloud(np.c_[x, y, z], spacing=h)


def _peak_rss_gb() -> float:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 2**20
    return float("nan")


def measure_size(n_points: int) -> dict:
    """One size, in this process: Laplacian, eigenbasis, step with a 30 % target band."""
    from tactex.ergodic import HedacConfig, HedacExplorer
    from tactex.spectral import laplace_eigenpairs, point_cloud_laplacian
    from tactex.spectral.basis import LaplaceBasis
    from tactex.spectral.eigen import resolve_eigensolver
    from tactex.spectral.hierarchy import HierarchyInfo

    cloud = panel(n_points)
    numba_init_s = _numba_init_s()
    t0 = time.perf_counter()
    L, M = point_cloud_laplacian(cloud.points, 30)
    lap_s = time.perf_counter() - t0
    mass = M.diagonal().copy()
    solver = resolve_eigensolver("auto", len(cloud))
    info = HierarchyInfo()
    t0 = time.perf_counter()
    evals, evecs = laplace_eigenpairs(L, mass, K, solver=solver, points=cloud.points, spacing=cloud.spacing, info=info)
    eig_s = time.perf_counter() - t0
    basis = LaplaceBasis(L=L, M=M, mass=mass, evals=evals, evecs=evecs, spacing=cloud.spacing, n_neighbors=30,
                         key="bench", eigensolver=solver)
    x = cloud.points[:, 0]
    lo, hi = np.quantile(x, [0.35, 0.35 + TARGET_FRACTION])
    target = ((x >= lo) & (x <= hi)).astype(float)
    cloud = cloud.with_target(target)
    ex = HedacExplorer(cloud, basis, HedacConfig(n_eigen=K, agent_radius_m=0.0075))
    x0 = cloud.points[np.argmin(np.abs(x - lo))]
    times = _step_times(ex, x0)
    compiled = ex.compiled_steps  # (reset() restarts the count)
    # The same explorer on a target 30× smaller (a 1 % band at the same place): what the target's size costs.
    ex.update_target(((x >= lo) & (x <= np.quantile(x, 0.36))).astype(float))
    small = _step_times(ex, x0)
    return {
        "n_points": len(cloud),
        "laplacian_s": lap_s,
        "eigen_s": eig_s,
        "numba_init_s": numba_init_s,
        "eigensolver": solver,
        "levels": info.level_points,
        "peak_memory_gb": _peak_rss_gb(),
        "step_us_median": float(np.median(times[WARMUP:]) * 1e6),
        "step_us_p90": float(np.percentile(times[WARMUP:], 90) * 1e6),
        "step_us_median_target_1pct": float(np.median(small[WARMUP:]) * 1e6),
        "compiled_share": compiled / times.size,
        "target_fraction": float(target.mean()),
        "target_rows": int(target.sum()),
    }


def _numba_init_s() -> float:
    """Wall time [s] of numba's first use in this process (its import and the first cached kernel's load, about
    half a second of CPU), paid once per process by whichever compiled code runs first: here the small clouds'
    block solve, else the exploration step. Kept out of ``eigen_s`` and recorded as ``numba_init_s``."""
    import scipy.sparse as sp

    from tactex.spectral import block_lu

    t0 = time.perf_counter()
    if block_lu.available():
        block_lu.BlockLU(sp.identity(4, format="csc")).solve(np.ones((4, 1)))
    return time.perf_counter() - t0


def _step_times(ex, x0: np.ndarray) -> np.ndarray:
    """Wall time [s] of WARMUP + STEPS exploration steps from x0."""
    ex.reset(x0)
    times = np.empty(WARMUP + STEPS)
    for i in range(times.size):
        t0 = time.perf_counter()
        ex.step()
        times[i] = time.perf_counter() - t0
    return times


def measure_whole_surface(n_points: int = WHOLE_POINTS) -> dict:
    """The whole-surface row (see the module doc), in this process."""
    from tactex.ergodic import HedacConfig, HedacExplorer
    from tactex.spectral import build_basis

    cloud = panel(n_points)
    cloud = cloud.with_target(np.ones(len(cloud)))
    t0 = time.perf_counter()
    basis = build_basis(cloud, n_eigen=WHOLE_N_EIGEN, n_neighbors=30, cache=False)
    basis_s = time.perf_counter() - t0
    said: list[float] = []
    t0 = time.perf_counter()
    ex = HedacExplorer(cloud, basis, HedacConfig(n_eigen=WHOLE_N_EIGEN))
    ex.progress = lambda msg: said.append(time.perf_counter())
    setup_s = time.perf_counter() - t0
    ex.reset(cloud.points[len(cloud) // 3])
    said.clear()
    t1, c1 = time.perf_counter(), time.process_time()
    ex.step()
    plan_s, plan_cpu_s = time.perf_counter() - t1, time.process_time() - c1
    wall, cpu = np.empty(WHOLE_STEPS), np.empty(WHOLE_STEPS)
    for i in range(WHOLE_STEPS):
        a, b = time.perf_counter(), time.process_time()
        ex.step()
        wall[i], cpu[i] = time.perf_counter() - a, time.process_time() - b
    passes = ex._passes
    return {
        "n_points": len(cloud),
        "n_eigen": WHOLE_N_EIGEN,
        "basis_s": basis_s,
        "explorer_setup_s": setup_s,
        "pass_plan_s": plan_s,
        "pass_plan_cpu_s": plan_cpu_s,
        "first_progress_s": (said[0] - t1) if said else None,
        "step_us_median": float(np.median(wall) * 1e6),
        "step_us_p90": float(np.percentile(wall, 90) * 1e6),
        "step_cpu_us_median": float(np.median(cpu) * 1e6),
        "step_cpu_us_p90": float(np.percentile(cpu, 90) * 1e6),
        "steps": WHOLE_STEPS,
        "waypoints": int(np.count_nonzero(passes.ring >= 0)),
        "arcs": int(sum(np.unique(a).size for a in passes._arc.values())),
        "coverage_residual": ex.coverage_residual(),
        "path_length_m": ex.path_length,
        "load_avg_1min": os.getloadavg()[0],
    }


def _size_in_subprocess(n_points: int, flag: str = "--size") -> dict:
    done = subprocess.run([sys.executable, __file__, flag, str(n_points)], capture_output=True, text=True,
                          check=False, env={**os.environ, "PYTHONPATH": str(HERE.parent)})
    if done.returncode != 0:
        return {"error": done.stderr.strip().splitlines()[-1] if done.stderr.strip() else f"exit {done.returncode}"}
    return json.loads(done.stdout.strip().splitlines()[-1])


def _bunny_vs_authors(repeats: int) -> dict:
    from bench_spectral import DATA, VOXEL_M

    from tactex.pointcloud import load_cloud, voxel_down_sample
    from tactex.spectral import build_basis

    path = DATA / "bun270_X.ply"
    if not path.is_file():
        return {"skipped": f"{path} not found"}
    cloud = voxel_down_sample(load_cloud(path), VOXEL_M)
    ours = functools.partial(build_basis, cloud, n_eigen=100, n_neighbors=30, cache=False)
    hier = functools.partial(build_basis, cloud, n_eigen=100, n_neighbors=30, cache=False, eigensolver="hierarchical")
    authors = functools.partial(_authors_pipeline, cloud.points)
    t_ours, t_hier, t_auth = _timed_each((ours, hier, authors), repeats)
    exact = build_basis(cloud, n_eigen=100, n_neighbors=30, cache=False, eigensolver="arpack")
    approx = hier()
    return {
        "n_points_3k": len(cloud),
        "ours_3k_s": t_ours["s"],
        "ours_3k_hierarchical_s": t_hier["s"],
        "authors_3k_s": t_auth["s"],
        "ours_3k_cpu_s": t_ours["cpu_s"],
        "ours_3k_hierarchical_cpu_s": t_hier["cpu_s"],
        "authors_3k_cpu_s": t_auth["cpu_s"],
        "speedup_vs_authors_3k": t_auth["s"] / t_ours["s"],
        "speedup_vs_authors_3k_hierarchical": t_auth["s"] / t_hier["s"],
        "speedup_vs_authors_3k_hierarchical_cpu": t_auth["cpu_s"] / t_hier["cpu_s"],
        **{f"{key}_3k_hierarchical": value for key, value in _agreement(exact, approx).items()},
    }


def _agreement(exact, approx) -> dict:
    """Largest and median relative eigenvalue error over the non-zero exact eigenvalues, and the largest
    principal angle [deg] between the two spans (M inner product)."""
    nonzero = exact.evals > 1e-9 * exact.evals[-1]  # the null space: one constant per connected part
    rel = np.abs(approx.evals[nonzero] - exact.evals[nonzero]) / exact.evals[nonzero]
    cosines = np.linalg.svd(exact.evecs.T @ (exact.mass[:, None] * approx.evecs), compute_uv=False)
    return {"eigenvalue_max_rel_error": float(rel.max()), "eigenvalue_median_rel_error": float(np.median(rel)),
            "span_angle_deg": float(np.degrees(np.arccos(min(1.0, float(cosines.min())))))}


def _panel_vs_arpack(repeats: int) -> dict:
    from tactex.spectral import laplace_eigenpairs, point_cloud_laplacian
    from tactex.spectral.hierarchy import HierarchyInfo

    cloud = panel(60000)
    L, M = point_cloud_laplacian(cloud.points, 30)
    mass = M.diagonal().copy()
    out: dict = {}
    info = HierarchyInfo()

    def arpack():
        out["arpack"] = laplace_eigenpairs(L, mass, K, solver="arpack")

    def hierarchical():
        out["hier"] = laplace_eigenpairs(L, mass, K, solver="hierarchical", points=cloud.points,
                                         spacing=cloud.spacing, info=info)

    t_arp, t_hier = _timed_each((arpack, hierarchical), repeats)
    (ev_a, V_a), (ev_h, V_h) = out["arpack"], out["hier"]
    rel = np.abs(ev_h[1:] - ev_a[1:]) / ev_a[1:]
    sv = np.linalg.svd(V_a.T @ (mass[:, None] * V_h), compute_uv=False)
    return {
        "n_points_60k": len(cloud),
        "arpack_60k_s": t_arp["s"],
        "hierarchical_60k_s": t_hier["s"],
        "speedup_vs_arpack_60k": t_arp["s"] / t_hier["s"],
        "eigenvalue_max_rel_error_60k": float(rel.max()),
        "eigenvalue_median_rel_error_60k": float(np.median(rel)),
        "span_angle_deg_60k": float(np.degrees(np.arccos(min(1.0, float(sv.min()))))),
        "hierarchical_60k_info": {"levels": info.level_points, "subspace": info.subspace_size,
                                  "fine_iterations": info.fine_iterations, "max_eta2": info.max_residual2,
                                  "seconds": info.seconds},
    }


def _tec_coverage() -> dict:
    """bench_ergodic's protocol (ten starts, residual at 0.5/1/2 m of path) with the ARPACK and the
    hierarchical basis; per mark the two means, and the mean and standard error of the per-start
    difference (a difference within ~2 standard errors is the starts' noise)."""
    import bench_ergodic as be

    from tactex.ergodic import HedacConfig, HedacExplorer
    from tactex.spectral import build_basis

    if not be.DATA.is_dir():
        return {"skipped": f"{be.DATA} not found"}
    out = {}
    for name in be.CLOUDS:
        cloud, x0 = be._load(name)
        radius = 0.015 if name.startswith("plate") else 0.0075
        per_start = {}
        for solver in ("arpack", "hierarchical"):
            basis = build_basis(cloud, n_eigen=200, n_neighbors=40, cache=False, eigensolver=solver)
            ex = HedacExplorer(cloud, basis, HedacConfig(agent_radius_m=radius))
            per_start[solver] = np.array([be._residual_vs_path(ex, x)["residual"] for x in x0])
        diff = per_start["hierarchical"] - per_start["arpack"]
        marks = [f"{m:g}" for m in be.PATHS_M]
        res = {solver: dict(zip(marks, v.mean(axis=0).tolist(), strict=True)) for solver, v in per_start.items()}
        res["difference"] = dict(zip(marks, diff.mean(axis=0).tolist(), strict=True))
        res["difference_stderr"] = dict(zip(marks, (diff.std(axis=0, ddof=1) / np.sqrt(len(x0))).tolist(),
                                            strict=True))
        out[name] = res
        print(f"   TEC coverage {name}: {res}", flush=True)
    return out


def _plot(sizes: dict) -> Path | None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = sorted((int(n), r) for n, r in sizes.items() if "error" not in r)
    if not rows:
        return None
    n = np.array([r["n_points"] for _, r in rows])
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    axes[0].loglog(n, [r["laplacian_s"] for _, r in rows], "o-", label="Laplacian (robust_laplacian)")
    axes[0].loglog(n, [r["eigen_s"] for _, r in rows], "s-", label=f"eigenbasis K={K} (auto solver)")
    axes[0].set(xlabel="points", ylabel="seconds", title="basis")
    axes[0].legend(fontsize=8)
    axes[1].semilogx(n, [r["step_us_median"] for _, r in rows], "o-", label="median")
    axes[1].semilogx(n, [r["step_us_p90"] for _, r in rows], "^--", label="p90")
    axes[1].semilogx(n, [r["step_us_median_target_1pct"] for _, r in rows], "s:", label="median, 1 % target")
    axes[1].axhline(1000, color="r", lw=0.8, ls=":", label="1 ms target")
    axes[1].set(xlabel="points", ylabel="µs", title=f"exploration step, {TARGET_FRACTION:.0%} target")
    axes[1].legend(fontsize=8)
    axes[2].semilogx(n, [r["peak_memory_gb"] for _, r in rows], "o-")
    axes[2].axhline(4.0, color="r", lw=0.8, ls=":", label="4 GB target")
    axes[2].set(xlabel="points", ylabel="GB", title="peak resident memory")
    axes[2].legend(fontsize=8)
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    path = HERE / "large.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def run(args) -> dict:
    quick = bool(getattr(args, "quick", False))
    cases = tuple(getattr(args, "cases", None) or ())
    if cases:  # --cases: the named rows only (whole_surface)
        out_cases: dict = {}
        if any("whole_surface".startswith(c) or c.startswith("whole") for c in cases):
            out_cases["whole_surface_100k"] = _size_in_subprocess(WHOLE_POINTS, "--whole")
            print(f"   whole surface: {out_cases['whole_surface_100k']}", flush=True)
        return {"large": out_cases}
    out: dict = {"load_avg_1min": {"start": os.getloadavg()[0]}}
    out.update(_bunny_vs_authors(2 if quick else 7))
    print(f"   bunny vs authors: {({k: v for k, v in out.items() if '3k' in k})}", flush=True)
    if not quick:
        out.update(_panel_vs_arpack(2))
        print(f"   60k vs ARPACK: {({k: v for k, v in out.items() if '60k' in k})}", flush=True)
    sizes = {}
    for n in QUICK_SIZES if quick else SIZES:
        sizes[str(n)] = _size_in_subprocess(n)
        print(f"   size {n}: {sizes[str(n)]}", flush=True)
    out["sizes"] = sizes
    plot = _plot(sizes)
    if plot is not None:
        print(f"   plot: {plot}")
    if not quick:
        out["whole_surface_100k"] = _size_in_subprocess(WHOLE_POINTS, "--whole")
        print(f"   whole surface: {out['whole_surface_100k']}", flush=True)
        out["tec_coverage"] = _tec_coverage()
    out["load_avg_1min"]["end"] = os.getloadavg()[0]
    return {"large": out}


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--size":
        print(json.dumps(measure_size(int(sys.argv[2]))))
    elif len(sys.argv) == 3 and sys.argv[1] == "--whole":
        print(json.dumps(measure_whole_surface(int(sys.argv[2]))))
