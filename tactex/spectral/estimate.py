"""What a Laplace basis will cost before it is built: an estimate of its time and peak memory from the point
count N and the eigenpairs n_K, and the size cap above which a run needs ``--force``.

The model is the hierarchical eigensolver's (the default from 1 000 points on) plus robust_laplacian's: the
Laplacian grows linearly in N; the solver's block iterations cost N·p² (Rayleigh–Ritz on p = n_K + max(n_K/5, 20)
vectors) and hold a few N×p blocks. Its constants were fitted on a busy two-core workstation; another machine
may be twice as fast or slow, which is why it is said as an estimate and the cap is in points.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from tactex.errors import CloudError
from tactex.pointcloud.mesh import MAX_MESH_POINTS
from tactex.pointcloud.voxel import voxel_indices

__all__ = ["MAX_BASIS_POINTS", "PROGRESS_MIN_POINTS",
           "BasisEstimate", "check_basis_size", "estimate_basis", "fitting_voxel_m"]

#: Largest cloud whose basis is built without ``--force`` [points]: the cap meshes are sampled under.
MAX_BASIS_POINTS = MAX_MESH_POINTS
#: A basis of this many points takes a minute or more: the commands say each of its phases (Laplacian, the
#: eigensolver's levels and iterations) from there on.
PROGRESS_MIN_POINTS = 50_000
#: The voxel size suggested for a cloud over the cap leaves at most this share of the cap (a file voxelised again
#: at it gives a slightly different count).
FIT_SHARE = 0.95
#: robust_laplacian's time per point [s] and its peak memory per point [bytes].
LAPLACIAN_S_PER_POINT = 9e-5
LAPLACIAN_BYTES_PER_POINT = 16e3
#: The eigensolver's time per N·p² [s] and its working blocks of N×p doubles (the iterate, its image, a spare, the
#: result and the sparse factor's share).
EIGEN_S_PER_NP2 = 4.5e-9
EIGEN_BLOCKS = 5.0


class BasisEstimate(NamedTuple):
    """The estimated wall-clock time [s] and peak memory [bytes] of a basis of ``n_points`` × ``n_eigen``."""

    n_points: int
    n_eigen: int
    seconds: float
    peak_bytes: float

    def describe(self) -> str:
        """"about 8 min and 9.6 GB" (rounded: it is an estimate)."""
        s = self.seconds
        when = f"{s:.0f} s" if s < 120 else f"{s / 60:.0f} min"
        size = f"{self.peak_bytes / 1e9:.1f} GB" if self.peak_bytes >= 1e8 else f"{self.peak_bytes / 1e6:.0f} MB"
        return f"about {when} and {size}"


def estimate_basis(n_points: int, n_eigen: int) -> BasisEstimate:
    """The time and peak memory the Laplacian and ``n_eigen`` eigenpairs of ``n_points`` points will take."""
    n, k = int(n_points), int(n_eigen)
    p = k + max(k // 5, 20)
    seconds = LAPLACIAN_S_PER_POINT * n + EIGEN_S_PER_NP2 * n * p * p
    peak = max(LAPLACIAN_BYTES_PER_POINT * n, EIGEN_BLOCKS * 8.0 * n * p)
    return BasisEstimate(n, k, seconds, peak)


def fitting_voxel_m(n_points: int, spacing_m: float, max_points: int = MAX_BASIS_POINTS,
                    points: np.ndarray | None = None) -> tuple[float, int]:
    """The voxel edge [m] (on a 0.1 mm grid) that leaves at most ``FIT_SHARE`` of ``max_points`` of a surface of
    ``n_points`` sampled every ``spacing_m``, and the points it leaves. Without ``points`` from the square law (a
    surface's count falls with the square of the spacing); with the (N, 3) ``points`` [m], the smallest such voxel
    by counting the voxels it fills (a grid slightly coarser than the sampling merges fewer points than the square
    law says)."""
    goal = FIT_SHARE * max_points
    ceiling = max(math.ceil(spacing_m * math.sqrt(n_points / goal) * 1e4), 1)  # in 0.1 mm
    if points is None:
        v = ceiling / 1e4
        return v, int(n_points * (spacing_m / v) ** 2)

    def filled(tenths: int) -> int:
        return int(voxel_indices(points, tenths / 1e4)[1].size)

    lo, hi = max(math.floor(spacing_m * 1e4), 1), ceiling  # filled(lo) is over the goal: the cloud's own grid
    while filled(hi) > goal:  # the square law fell short (an irregular cloud): widen
        lo, hi = hi, 2 * hi
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (lo, mid) if filled(mid) <= goal else (mid, hi)
    return hi / 1e4, filled(hi)


def check_basis_size(n_points: int, n_eigen: int, spacing_m: float, *, force: bool = False,
                     max_points: int | None = None, points: np.ndarray | None = None) -> BasisEstimate:
    """The estimate of the basis; above ``max_points`` points (None: :data:`MAX_BASIS_POINTS`) :class:`CloudError`
    unless ``force``, naming the estimate and the voxel size that fits (counted on ``points`` (N, 3) [m] when
    given, see :func:`fitting_voxel_m`)."""
    max_points = MAX_BASIS_POINTS if max_points is None else int(max_points)
    est = estimate_basis(n_points, n_eigen)
    if n_points > max_points and not force:
        v, fit = fitting_voxel_m(n_points, spacing_m, max_points, points)
        raise CloudError(
            f"the cloud has {n_points:,} points, over the {max_points:,} a Laplace basis is built for without "
            f"--force: its Laplacian and {n_eigen} eigenpairs would take {est.describe()} (estimated); give "
            f"voxel_size_m={v:g} (about {fit:,} points at that spacing), or --force to build it anyway")
    return est
