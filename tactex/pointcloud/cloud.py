"""The :class:`SurfaceCloud` type: a point-sampled surface with an exploration target; and
:class:`CloudFile`, a cloud as a reader returns it, with what reading the file did."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial import cKDTree

from tactex.errors import CloudError, UnitsError
from tactex.pointcloud.units import millimetre_hint

__all__ = ["MAX_EXTENT_M", "MAX_SPACING_M", "CloudFile", "SurfaceCloud", "mean_spacing", "validate_points"]

#: A cloud wider than this is almost surely in millimetres (a robot workspace is ~1 m).
MAX_EXTENT_M = 5.0


def validate_points(points: object, name: str = "points", min_points: int = 1) -> np.ndarray:
    """Return ``points`` as a C-contiguous float64 (N, 3) array, or raise :class:`CloudError`.

    Checks shape, finiteness, the minimum count and the units (a cloud over MAX_EXTENT_M wide whose
    points lie over MAX_GAP_M apart is in millimetres). No copy is made when ``points`` already is
    such an array (:class:`SurfaceCloud` copies what it keeps).
    """
    try:
        arr = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise CloudError(f"{name} must be an (N, 3) array of numbers [m]: {exc}") from exc
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise CloudError(f"{name} must have shape (N, 3), got {arr.shape}")
    if arr.shape[0] < min_points:
        raise CloudError(
            f"{name} holds {arr.shape[0]} point(s) but at least {min_points} are needed"
            + (" (the cloud is empty)" if arr.shape[0] == 0 else "")
        )
    bad = ~np.isfinite(arr).all(axis=1)
    if bad.any():
        idx = np.flatnonzero(bad)
        raise CloudError(
            f"{name} holds {idx.size} point(s) with NaN/inf coordinates (first at index "
            f"{idx[0]}: {arr[idx[0]].tolist()}); drop them first, e.g. points[np.isfinite(points).all(1)]"
        )
    extent = float(np.max(np.ptp(arr, axis=0))) if arr.shape[0] else 0.0
    if extent > MAX_EXTENT_M:
        # a camera frame reaching 3 m away spans ~5.5 m with an 87° field of view, its points mm apart
        gap = _median_gap(arr)
        if gap > MAX_GAP_M:
            raise UnitsError(
                f"{'the cloud' if name == 'points' else name} spans {extent:.3g} m along one axis with points "
                f"{gap:.3g} m apart; tactex works in metres and {millimetre_hint(extent)}"
            )
    return np.ascontiguousarray(arr)


#: Mean spacing above which any cloud is taken for millimetres (a small part in mm: 4 "m" wide, its
#: points 0.3 "m" apart); a tactile surface is sampled at a few mm.
MAX_SPACING_M = 0.1
#: Typical gap between neighbouring points above which a wide cloud is taken for millimetres: real
#: scans in metres are sampled at a few mm (a depth camera at 3 m: ~5 mm between pixels).
MAX_GAP_M = 0.05


def _median_gap(arr: np.ndarray, sample: int = 2000) -> float:
    """Median nearest-neighbour distance of (a fixed sample of) the points, duplicates aside."""
    if arr.shape[0] < 2:
        return 0.0
    idx = np.linspace(0, arr.shape[0] - 1, min(sample, arr.shape[0])).astype(np.intp)
    d = cKDTree(arr).query(arr[idx], k=2)[0][:, 1]
    d = d[d > 0]
    return float(np.median(d)) if d.size else 0.0



def mean_spacing(points: np.ndarray, tree: cKDTree | None = None) -> float:
    """Mean distance from each point to its nearest neighbour [m] (TEC §IV-A's h)."""
    if points.shape[0] < 2:
        raise CloudError("the mean spacing needs at least 2 points")
    tree = tree if tree is not None else cKDTree(points)
    dist, _ = tree.query(points, k=2)
    d = dist[:, 1]
    if not np.all(d > 0):
        raise CloudError(
            f"{int(np.sum(d <= 0))} point(s) coincide with another point; remove duplicates "
            "first with SurfaceCloud.deduplicated() or a voxel filter"
        )
    return float(d.mean())


def _optional_rows(value: object, n: int, name: str) -> np.ndarray | None:
    if value is None:
        return None
    try:
        arr = np.array(value, dtype=np.float64, copy=True)
    except (TypeError, ValueError) as exc:
        raise CloudError(f"{name} must be an ({n}, 3) array of numbers: {exc}") from exc
    if arr.shape != (n, 3):
        raise CloudError(f"{name} must have shape ({n}, 3) to match the points, got {arr.shape}")
    if not np.isfinite(arr).all():
        raise CloudError(f"{name} holds NaN/inf values")
    return np.ascontiguousarray(arr)


@dataclass(frozen=True, eq=False)
class SurfaceCloud:
    """A surface sampled by points, with the target mass to explore.

    Attributes:
        points: (N, 3) positions [m] in the world (or object) frame.
        normals: (N, 3) unit normals, or None.
        colors: (N, 3) RGB in [0, 1], or None.
        target: (N,) unnormalised target mass ≥ 0 (zeros when no target is set).
        spacing: mean nearest-neighbour spacing h [m]; 0 (the default) computes it.
    """

    points: np.ndarray
    normals: np.ndarray | None = None
    colors: np.ndarray | None = None
    target: np.ndarray | None = None
    spacing: float = field(default=0.0)

    def __post_init__(self) -> None:
        pts = validate_points(self.points)
        if np.may_share_memory(pts, self.points):  # the cloud owns its arrays: the caller's stay writable
            pts = pts.copy()
        n = pts.shape[0]
        normals = _optional_rows(self.normals, n, "normals")
        if normals is not None:
            norm = np.linalg.norm(normals, axis=1)
            if np.any(norm < 1e-12):
                raise CloudError("normals hold zero-length vectors; estimate them again or drop them")
            normals = normals / norm[:, None]
        colors = _optional_rows(self.colors, n, "colors")
        if colors is not None and (colors.min() < 0.0 or colors.max() > 1.0):
            raise CloudError(
                f"colors must lie in [0, 1], got range [{colors.min():.3g}, {colors.max():.3g}]; "
                "divide 8-bit colours by 255"
            )
        if self.target is None:
            target = np.zeros(n)
        else:
            try:
                target = np.array(self.target, dtype=np.float64, copy=True)
            except (TypeError, ValueError) as exc:
                raise CloudError(f"target must be an ({n},) array of numbers ≥ 0: {exc}") from exc
            if target.shape != (n,):
                raise CloudError(f"target must have shape ({n},), got {target.shape}")
            if not np.isfinite(target).all() or target.min() < 0.0:
                raise CloudError("target must be finite and ≥ 0 everywhere")
        try:
            spacing = float(self.spacing)
        except (TypeError, ValueError) as exc:
            raise CloudError(f"spacing must be a number of metres ≥ 0 (0: compute it), got {self.spacing!r}") from exc
        if not np.isfinite(spacing) or spacing < 0.0:
            raise CloudError(f"spacing must be a finite number of metres ≥ 0 (0: compute it), got {self.spacing}")
        given = spacing > 0.0
        if not given and n >= 2:
            # A raw scan may repeat points: they stay (a voxel filter averages them, deduplicated() drops
            # them, the Laplacian refuses them with that advice); h comes from the distinct points.
            distinct = np.unique(pts, axis=0)
            spacing = mean_spacing(distinct) if distinct.shape[0] >= 2 else 0.0
        if spacing > MAX_SPACING_M:
            if given:
                raise UnitsError(
                    f"spacing = {spacing:.3g} m was given; tactex works in metres and a surface sampled that "
                    f"coarsely (over {MAX_SPACING_M:g} m) is probably described in millimetres. Give the spacing "
                    "in metres."
                )
            raise UnitsError(
                f"the points lie {spacing:.3g} m apart on average; tactex works in metres and a surface sampled "
                f"that coarsely (over {MAX_SPACING_M:g} m) is probably in millimetres: convert it to metres (× 1e-3)."
            )
        for name, value in (("points", pts), ("normals", normals), ("colors", colors), ("target", target)):
            if value is not None:
                value.setflags(write=False)
            object.__setattr__(self, name, value)
        object.__setattr__(self, "spacing", spacing)

    def __len__(self) -> int:
        return int(self.points.shape[0])

    @property
    def n_target(self) -> int:
        """Number of points carrying target mass."""
        return int(np.count_nonzero(self.target))

    def with_target(self, target: np.ndarray) -> SurfaceCloud:
        """A copy with another target mass (N,) ≥ 0."""
        return replace(self, target=np.asarray(target, dtype=np.float64))

    def with_normals(self, normals: np.ndarray) -> SurfaceCloud:
        """A copy with (N, 3) normals."""
        return replace(self, normals=normals)

    def transformed(self, rotation: np.ndarray, translation: np.ndarray) -> SurfaceCloud:
        """A copy moved rigidly: x' = R x + t (normals rotated). Spacing is kept."""
        rot = np.asarray(rotation, dtype=np.float64)
        t = np.asarray(translation, dtype=np.float64)
        if rot.shape != (3, 3) or t.shape != (3,) or not (np.isfinite(rot).all() and np.isfinite(t).all()):
            raise CloudError(
                f"transformed needs a finite 3×3 rotation and a 3-vector, got shapes {rot.shape}, {t.shape}")
        if np.abs(rot @ rot.T - np.eye(3)).max() > 1e-6 or np.linalg.det(rot) < 0.0:
            raise CloudError("transformed needs a rotation matrix (orthonormal, det +1): a scaling would keep a "
                             "stale spacing; scale the points and build a new SurfaceCloud instead")
        normals = None if self.normals is None else self.normals @ rot.T
        return replace(self, points=self.points @ rot.T + t, normals=normals)

    def subset(self, mask_or_index: np.ndarray) -> SurfaceCloud:
        """A copy keeping the selected points (boolean mask or index array); spacing recomputed."""
        sel = np.asarray(mask_or_index)

        def take(a: np.ndarray | None) -> np.ndarray | None:
            return None if a is None else a[sel]

        return SurfaceCloud(
            points=self.points[sel],
            normals=take(self.normals),
            colors=take(self.colors),
            target=take(self.target),
        )

    def deduplicated(self, tolerance_m: float = 0.0) -> SurfaceCloud:
        """A copy without points closer than ``tolerance_m`` to an earlier one (exact duplicates at 0)."""
        if tolerance_m <= 0.0:
            _, first = np.unique(self.points, axis=0, return_index=True)
            keep = np.sort(first)
        else:
            tree = cKDTree(self.points)
            pairs = tree.query_pairs(tolerance_m, output_type="ndarray")
            drop = np.unique(pairs.max(axis=1)) if len(pairs) else np.empty(0, dtype=int)
            keep = np.setdiff1d(np.arange(len(self)), drop)
        return self.subset(keep)


@dataclass(frozen=True)
class CloudFile:
    """A cloud read from a file, with what reading it did.

    Attributes:
        cloud: the points (finite), in metres.
        n_dropped: points left out for NaN/inf coordinates or normals.
        n_faces: faces of a mesh file (0 for a point cloud); its points are samples of its surface.
        notes: those facts in words, for the user.
        kept: per row of a point cloud file (bool), whether it is in ``cloud``; None when every row is
            (or for a mesh). A per-point array given for the file (a keep-out mask) is carried over by it.
    """

    cloud: SurfaceCloud
    n_dropped: int = 0
    n_faces: int = 0
    notes: tuple[str, ...] = ()
    kept: np.ndarray | None = None
    keep_out: np.ndarray | None = None  # per point of ``cloud``: a PLY's own keep_out property (ply_marks)
