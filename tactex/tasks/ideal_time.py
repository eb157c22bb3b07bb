"""The physical bound on the time to clean: the dirty area swept once by the pad's width at the sliding speed.

No method that slides a pad of effective width w at speed v can wipe an area A faster than A / (w v), plus
the transit it cannot avoid (from where the robot starts to the dirt, and between islands too far apart to
slide). A method's time divided by this bound says how far it is from the physics.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from tactex.errors import ConfigError, InputError
from tactex.pointcloud.cloud import SurfaceCloud

__all__ = ["KERNEL_CUTOFF", "dirty_area_m2", "ideal_time_s", "point_areas_m2"]

#: Where the density kernel of :func:`point_areas_m2` is cut off, in kernel widths (its tail beyond holds
#: exp(−cutoff²/2) of its mass, which the estimate adds back) [-].
KERNEL_CUTOFF = 3.5


def point_areas_m2(cloud: SurfaceCloud) -> np.ndarray:
    """The surface area each point stands for (N,) [m²]: the inverse of the points' density there, estimated with
    a 2-D Gaussian kernel as wide as the cloud's spacing (cut off at :data:`KERNEL_CUTOFF` widths). A kernel that
    wide sums a regular grid exactly, unlike a count of the points in a disc, whose rim cuts through rows of
    points; on a scan it averages the sampling's unevenness over a few neighbours. At the cloud's border, where
    half the kernel finds no points, a point's area comes out up to twice too large."""
    if len(cloud) < 2:
        raise InputError(f"the area per point needs a cloud of at least 2 points, got {len(cloud)}")
    sigma = cloud.spacing
    tree = cKDTree(cloud.points)
    pairs = tree.sparse_distance_matrix(tree, KERNEL_CUTOFF * sigma, output_type="ndarray")  # each point with itself
    weight = np.bincount(pairs["i"], weights=np.exp(-0.5 * (pairs["v"] / sigma) ** 2), minlength=len(cloud))
    density = weight / (2.0 * np.pi * sigma**2)
    density /= 1.0 - np.exp(-0.5 * KERNEL_CUTOFF**2)
    return 1.0 / density


def dirty_area_m2(cloud: SurfaceCloud, point_area_m2: np.ndarray | None = None) -> float:
    """The area of the dirty surface (target > 0) [m²]: the dirty points' areas summed, from
    ``point_area_m2`` (N,) [m²] when given (e.g. a Laplacian's lumped mass matrix's diagonal), else
    :func:`point_areas_m2`."""
    dirty = cloud.target > 0
    if not dirty.any():
        return 0.0
    if point_area_m2 is None:
        point_area_m2 = point_areas_m2(cloud)
    area = np.asarray(point_area_m2, dtype=float)
    if area.shape != (len(cloud),) or not np.isfinite(area).all() or area.min() < 0:
        raise InputError(f"point_area_m2 must be ({len(cloud)},) finite areas ≥ 0 [m²], got shape {area.shape}")
    return float(area[dirty].sum())


def ideal_time_s(dirty_area_m2: float, pad_effective_width_m: float, speed_m_s: float, transit_s: float = 0.0) -> float:
    """The least time [s] to wipe ``dirty_area_m2`` [m²] once with a pad whose wiped stripe is
    ``pad_effective_width_m`` [m] wide sliding at ``speed_m_s`` [m/s], plus ``transit_s`` [s] of transit no
    method avoids: area / (width × speed) + transit."""
    for name, value in (("dirty_area_m2", dirty_area_m2), ("transit_s", transit_s)):
        if not (np.isfinite(value) and value >= 0):
            raise ConfigError(f"{name} must be a finite value ≥ 0, got {value!r}")
    for name, value in (("pad_effective_width_m", pad_effective_width_m), ("speed_m_s", speed_m_s)):
        if not (np.isfinite(value) and value > 0):
            raise ConfigError(f"{name} must be > 0, got {value!r}")
    return float(dirty_area_m2 / (pad_effective_width_m * speed_m_s) + transit_s)
