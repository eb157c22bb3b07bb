"""Region growing on normals (PCL *RegionGrowing*, the segmentation VA-UFIC §II-B uses).

PCL's algorithm: take the unlabelled point of lowest curvature as a seed; add every neighbour
whose normal is within the smoothness angle of the current point's normal (|n_i·n_j| ≥ cos θ);
neighbours whose curvature is below the curvature threshold become seeds themselves and keep
growing; discard segments smaller than ``min_cluster_size`` or larger than ``max_cluster_size``.

This implementation is the order-independent, vectorised form of that algorithm:

1. *Seed points* (curvature ≤ threshold) joined by agreeing normals form the connected
   components of a sparse graph (``scipy.sparse.csgraph``) — on a symmetric neighbourhood
   graph these are exactly PCL's regions, because a region grows through seeds only.
2. A non-seed point joins a region when a seed neighbour of that region agrees with it; if
   several regions can claim it, it goes to the region whose lowest seed curvature is smallest —
   the region PCL would have grown first.
3. Non-seed points no region claims are noise (label −1). PCL would start a region at such a
   point that stops after one ring of neighbours; such regions are below any sensible
   ``min_cluster_size`` (> neighbourhood size), so the result is the same.

Neighbour graphs: :func:`grid_edges` (8-connected image grid with a 3-D distance gate against
depth discontinuities) and :func:`knn_edges` (k nearest neighbours, PCL's default).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from tactex.config import param
from tactex.errors import CloudError, ConfigError

__all__ = ["RegionGrowingParams", "grid_edges", "knn_edges", "region_growing"]


@dataclass(frozen=True)
class RegionGrowingParams:
    """Region-growing thresholds.

    PCL's tutorial uses 3° and curvature 1.0 on clean scans; the defaults here are tuned for a
    D435i-class wrist camera (normals over ~8 mm windows): 10° between neighbours and a
    curvature threshold of 0.05, under which a plane, a sphere or cylinder of radius ≥ 2 cm
    stay seeds while a 90° edge (curvature ≈ 0.1–0.15 on the ridge) stops the growth.
    """

    smoothness_angle_deg: float = param(10.0, "max angle between neighbouring normals [deg]")
    curvature_threshold: float = param(0.05, "max surface variation of a point that keeps growing [-]")
    min_cluster_size: int = param(50, "smallest segment kept [points]")
    max_cluster_size: int = param(1_000_000, "largest segment kept [points]")

    def __post_init__(self) -> None:
        if not 0.0 < self.smoothness_angle_deg < 90.0:
            raise ConfigError(f"smoothness_angle_deg must lie in (0, 90), got {self.smoothness_angle_deg}")
        if not 0.0 <= self.curvature_threshold <= 1.0:
            raise ConfigError(f"curvature_threshold must lie in [0, 1], got {self.curvature_threshold}")
        if not 1 <= self.min_cluster_size <= self.max_cluster_size:
            raise ConfigError(
                f"need 1 ≤ min_cluster_size ≤ max_cluster_size, got {self.min_cluster_size}, {self.max_cluster_size}"
            )


def grid_edges(
    cell_index: np.ndarray, points: np.ndarray, max_edge_m: np.ndarray | float
) -> tuple[np.ndarray, np.ndarray]:
    """Edges between 8-connected grid cells.

    Args:
        cell_index: (H, W) int, index into ``points`` of each cell, −1 where empty.
        points: (N, 3) [m].
        max_edge_m: largest 3-D length of an edge [m], scalar or (N,) per first endpoint; longer
            pairs straddle a depth discontinuity and are not neighbours.

    Returns:
        (i, j) arrays of undirected edges, each listed once.
    """
    gi, gj = [], []
    h, w = cell_index.shape
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
        a = cell_index[: h - dr, max(0, -dc): w - max(0, dc)]
        b = cell_index[dr:, max(0, dc): w + min(0, dc)]
        both = (a >= 0) & (b >= 0)
        gi.append(a[both])
        gj.append(b[both])
    i, j = np.concatenate(gi), np.concatenate(gj)
    length = np.linalg.norm(points[i] - points[j], axis=1)
    limit = max_edge_m if np.isscalar(max_edge_m) else np.asarray(max_edge_m)[i]
    keep = length <= limit
    return i[keep], j[keep]


def knn_edges(points: np.ndarray, k: int = 16, *, workers: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Directed edges i → j for the ``k`` nearest neighbours j of each point i."""
    if int(k) != k or k < 1:
        raise ConfigError(f"k must be a positive integer, got {k!r}")
    if points.shape[0] <= k:
        raise CloudError(f"{points.shape[0]} points are too few for {k} neighbours")
    _, idx = cKDTree(points).query(points, k=int(k) + 1, workers=workers)
    i = np.repeat(np.arange(points.shape[0]), k)
    return i, idx[:, 1:].reshape(-1)


def region_growing(
    normals: np.ndarray,
    curvature: np.ndarray,
    edges: tuple[np.ndarray, np.ndarray],
    params: RegionGrowingParams | None = None,
) -> np.ndarray:
    """Segment points into smooth regions.

    Args:
        normals: (N, 3) unit normals (rows with NaN are never part of a region).
        curvature: (N,) per-point surface variation.
        edges: (i, j) neighbour pairs (see :func:`grid_edges`, :func:`knn_edges`).
        params: thresholds.

    Returns:
        (N,) int labels: 0, 1, … by decreasing segment size; −1 for noise or dropped segments.
    """
    prm = params or RegionGrowingParams()
    n = normals.shape[0]
    if curvature.shape != (n,):
        raise CloudError(f"curvature must have shape ({n},), got {curvature.shape}")
    if n == 0:
        return np.empty(0, dtype=np.int64)
    ok = np.isfinite(normals).all(axis=1) & np.isfinite(curvature)
    seed = ok & (curvature <= prm.curvature_threshold)
    i, j = (np.asarray(e, dtype=np.int64) for e in edges)
    cos_t = np.cos(np.deg2rad(prm.smoothness_angle_deg))
    both_ok = ok[i] & ok[j]
    i, j = i[both_ok], j[both_ok]
    agree = np.abs(np.einsum("ij,ij->i", normals[i], normals[j])) >= cos_t
    i, j = i[agree], j[agree]

    ss = seed[i] & seed[j]
    graph = coo_matrix((np.ones(int(ss.sum()), dtype=np.int8), (i[ss], j[ss])), shape=(n, n))
    _, comp = connected_components(graph, directed=False)
    labels = np.where(seed, comp, -1)

    if seed.any():
        # Order regions by their lowest seed curvature (PCL grows them in that order).
        seed_idx = np.flatnonzero(seed)
        first_curv = np.full(comp.max() + 1, np.inf)
        np.minimum.at(first_curv, comp[seed_idx], curvature[seed_idx])
        rank = np.empty(first_curv.size, dtype=np.int64)
        rank[np.lexsort((np.arange(first_curv.size), first_curv))] = np.arange(first_curv.size)
        # Non-seed points adjacent (with agreeing normals) to a seed: claimed by the first region.
        claim_s = np.concatenate([i[seed[i] & ~seed[j]], j[seed[j] & ~seed[i]]])
        claim_t = np.concatenate([j[seed[i] & ~seed[j]], i[seed[j] & ~seed[i]]])
        best = np.full(n, np.iinfo(np.int64).max)
        np.minimum.at(best, claim_t, rank[comp[claim_s]])
        claimed = (~seed) & (best < np.iinfo(np.int64).max)
        order = np.argsort(rank)
        labels[claimed] = order[best[claimed]]

    out = np.full(n, -1, dtype=np.int64)
    member = labels >= 0
    if not member.any():
        return out
    uniq, inverse, counts = np.unique(labels[member], return_inverse=True, return_counts=True)
    keep = (counts >= prm.min_cluster_size) & (counts <= prm.max_cluster_size)
    # Renumber kept regions by decreasing size (ties: lower original id first).
    kept = np.flatnonzero(keep)
    new_id = np.full(uniq.size, -1, dtype=np.int64)
    new_id[kept[np.lexsort((kept, -counts[kept]))]] = np.arange(kept.size)
    out[member] = new_id[inverse]
    return out
