"""Spectral preprocessing on the TEC clouds (TEC §VI-A, Table I, Fig. 4–5).

Measures, with the cache disabled and as the median of several runs:
- ``spectral.<cloud>.laplacian_s``: L and M (robust_laplacian) of the 3 mm voxelised cloud;
- ``spectral.<cloud>.laplacian_eig100_s``: L, M and 100 eigenpairs (TEC: 278 ms on the bunny);
- ``spectral.<cloud>.laplacian_eig200_s``: the same with 200 eigenpairs (the explorer default);
- ``spectral.<cloud>.spectral_step_s`` / ``implicit_step_s``: one diffusion step (K = 100) and the
  sparse implicit reference (Fig. 5);
- ``spectral.table1``: {n_points: Laplacian seconds} for the raw bunny voxelised to ≈ 3k…18k points.

``*_min_s`` are the fastest of the repeats: on a 2-core machine shared with other jobs the median
measures the load as much as the code; targets are checked on the medians.
"""

from __future__ import annotations

import os
import statistics
import time
from pathlib import Path

import numpy as np

from tactex.pointcloud import load_cloud, voxel_down_sample
from tactex.spectral import ImplicitDiffusion, SpectralDiffusion, build_basis, diffusion_timestep, point_cloud_laplacian

REPO = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("TACTEX_SHARED_DATA", REPO.parent / "shared" / "data")) / "tactile_ergodic_control"
CLOUDS = ("bun270_X", "cup_X", "plate_shapes")
VOXEL_M = 0.003
TABLE1_SIZES = (2996, 6070, 9097, 11910, 14993, 18001)  # TEC Table I
TABLE1_PAPER_MS = (59, 103, 178, 228, 293, 342)

TARGETS = {
    "spectral.bun270_X.laplacian_eig100_s": ("<=", 0.125),
    "spectral.table1_18k_s": ("<=", 0.342),
}


_MINIMA: dict[str, float] = {}


def _median_time(fn, repeats: int, key: str | None = None) -> float:
    """Median wall time [s]; the minimum is kept under ``key`` (the intrinsic cost on a busy machine)."""
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    if key is not None:
        _MINIMA[key] = min(times)
    return statistics.median(times)


def _voxel_for_count(raw, n_target: int) -> tuple[float, int]:
    """Voxel size [m] whose down-sampled cloud has the point count closest to ``n_target`` (bisection)."""
    lo, hi = 1e-4, 0.02  # fine → many points, coarse → few
    best = (hi, 0)
    for _ in range(30):
        mid = np.sqrt(lo * hi)
        n = len(voxel_down_sample(raw, mid))
        if abs(n - n_target) < abs(best[1] - n_target):
            best = (mid, n)
        if n == n_target:
            break
        if n > n_target:
            lo = mid
        else:
            hi = mid
    return best


def run(args) -> dict:
    quick = bool(getattr(args, "quick", False))
    repeats = 3 if quick else 7
    if not DATA.is_dir():
        print(f"   skipped: TEC clouds not found in {DATA}")
        return {"spectral": {"skipped": f"no data in {DATA}"}}
    out: dict = {}
    for name in CLOUDS:
        path = DATA / f"{name}.ply"
        if not path.is_file():
            print(f"   skipped {name}: {path} not found")
            continue
        cloud = voxel_down_sample(load_cloud(path), VOXEL_M)
        res: dict = {"n_points": len(cloud)}
        res["laplacian_s"] = _median_time(lambda c=cloud: point_cloud_laplacian(c.points), repeats, "lap")
        res["laplacian_min_s"] = _MINIMA["lap"]
        for k in (100, 200):
            res[f"laplacian_eig{k}_s"] = _median_time(
                lambda c=cloud, k=k: build_basis(c, n_eigen=k, cache=False),
                repeats if k == 100 else max(2, repeats // 2),
                "eig",
            )
            res[f"laplacian_eig{k}_min_s"] = _MINIMA["eig"]
        basis = build_basis(cloud, n_eigen=100, cache=False)
        dt = diffusion_timestep(10.0, basis.spacing)
        u = np.random.default_rng(0).random(len(cloud))
        spectral, implicit = SpectralDiffusion(basis, dt), ImplicitDiffusion(basis.L, basis.M, dt)
        res["spectral_step_s"] = _median_time(lambda s=spectral, u=u: s(u), 200)
        res["implicit_step_s"] = _median_time(lambda s=implicit, u=u: s(u), 50)
        out[name] = res
        print(f"   {name}: {res}", flush=True)

    raw_path = DATA / "bun270_X.ply"
    if raw_path.is_file():
        raw = load_cloud(raw_path)
        table: dict = {}
        voxels: dict = {}
        for n_target in TABLE1_SIZES:
            voxel, _ = _voxel_for_count(raw, n_target)
            cloud = voxel_down_sample(raw, voxel)
            table[str(len(cloud))] = _median_time(lambda c=cloud: point_cloud_laplacian(c.points), repeats)
            voxels[str(len(cloud))] = voxel
        out["table1"] = table
        out["table1_voxel_m"] = voxels
        out["table1_paper_s"] = {str(n): ms / 1e3 for n, ms in zip(TABLE1_SIZES, TABLE1_PAPER_MS, strict=True)}
        out["table1_18k_s"] = table[max(table, key=int)]
        print(f"   table1: {table}", flush=True)
    return {"spectral": out}
