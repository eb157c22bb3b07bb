"""Reading and writing point clouds: PLY (plyfile), PCD (pypcd4), NPZ, and Open3D objects.

All readers return a :class:`SurfaceCloud` in metres; colours are scaled to [0, 1]. NPZ files are
read with ``allow_pickle=False`` (a cloud a user receives must never execute code).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from tactex.errors import CloudError, InputError, MissingDependencyError
from tactex.pointcloud.cloud import SurfaceCloud

__all__ = [
    "SUPPORTED_SUFFIXES",
    "from_open3d",
    "load_cloud",
    "load_npz",
    "load_pcd",
    "load_ply",
    "save_cloud",
    "save_npz",
    "save_ply",
    "to_open3d",
]

SUPPORTED_SUFFIXES = (".ply", ".pcd", ".npz")


def _colors_to_unit(rgb: np.ndarray) -> np.ndarray:
    rgb = np.asarray(rgb)
    if np.issubdtype(rgb.dtype, np.integer):
        return rgb.astype(np.float64) / 255.0
    rgb = rgb.astype(np.float64)
    # Float colours in 0..255 appear in the wild; 0..1 is the convention.
    return rgb / 255.0 if rgb.size and rgb.max() > 1.0 else rgb


def _check_file(path: str | Path) -> Path:
    p = Path(path)
    if not p.is_file():
        raise InputError(f"point cloud file '{p}' does not exist (or is not a file)")
    return p


def load_ply(path: str | Path) -> SurfaceCloud:
    """Read a PLY file's vertex element: x y z, optional nx ny nz and red green blue."""
    from plyfile import PlyData, PlyParseError

    p = _check_file(path)
    try:
        ply = PlyData.read(str(p))
    except (PlyParseError, ValueError, OSError) as exc:
        raise CloudError(f"'{p}' is not a readable PLY file: {exc}") from exc
    if "vertex" not in ply:
        raise CloudError(f"'{p}' has no 'vertex' element")
    v = ply["vertex"]
    names = set(v.data.dtype.names or ())
    if not {"x", "y", "z"} <= names:
        raise CloudError(f"'{p}' vertices lack x/y/z properties (found {sorted(names)})")
    points = np.stack([v["x"], v["y"], v["z"]], axis=1).astype(np.float64)
    normals = (
        np.stack([v["nx"], v["ny"], v["nz"]], axis=1).astype(np.float64)
        if {"nx", "ny", "nz"} <= names
        else None
    )
    colors = (
        _colors_to_unit(np.stack([v["red"], v["green"], v["blue"]], axis=1))
        if {"red", "green", "blue"} <= names
        else None
    )
    target = np.asarray(v["target"], dtype=np.float64) if "target" in names else None
    return SurfaceCloud(points=points, normals=normals, colors=colors, target=target)


def save_ply(cloud: SurfaceCloud, path: str | Path, *, extra: dict[str, np.ndarray] | None = None) -> Path:
    """Write a binary PLY with x y z, normals and 8-bit colours when present, the target, and
    any ``extra`` per-point float properties (e.g. ``curvature``)."""
    from plyfile import PlyData, PlyElement

    n = len(cloud)
    fields: list[tuple[str, str]] = [("x", "f8"), ("y", "f8"), ("z", "f8")]
    if cloud.normals is not None:
        fields += [("nx", "f8"), ("ny", "f8"), ("nz", "f8")]
    if cloud.colors is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    fields.append(("target", "f8"))
    extra = extra or {}
    for key, values in extra.items():
        if np.shape(values) != (n,):
            raise InputError(f"extra property '{key}' must have shape ({n},), got {np.shape(values)}")
        fields.append((key, "f8"))
    data = np.empty(n, dtype=fields)
    data["x"], data["y"], data["z"] = cloud.points.T
    if cloud.normals is not None:
        data["nx"], data["ny"], data["nz"] = cloud.normals.T
    if cloud.colors is not None:
        rgb = np.round(cloud.colors * 255.0).astype(np.uint8)
        data["red"], data["green"], data["blue"] = rgb.T
    data["target"] = cloud.target
    for key, values in extra.items():
        data[key] = values
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    PlyData([PlyElement.describe(data, "vertex")]).write(str(out))
    return out


def load_pcd(path: str | Path) -> SurfaceCloud:
    """Read a PCL PCD file (ascii/binary/binary_compressed) with pypcd4; packed ``rgb`` is decoded."""
    from pypcd4 import PointCloud

    p = _check_file(path)
    try:
        pc = PointCloud.from_path(p)
    except Exception as exc:  # pypcd4 raises bare exceptions of several kinds on bad headers
        raise CloudError(f"'{p}' is not a readable PCD file: {exc}") from exc
    fields = tuple(pc.fields)
    arr = pc.numpy()
    col = {name: arr[:, i] for i, name in enumerate(fields)}
    if not {"x", "y", "z"} <= set(fields):
        raise CloudError(f"'{p}' lacks x/y/z fields (found {list(fields)})")
    points = np.stack([col["x"], col["y"], col["z"]], axis=1).astype(np.float64)
    finite = np.isfinite(points).all(axis=1)  # organised PCDs pad with NaN
    normals = None
    if {"normal_x", "normal_y", "normal_z"} <= set(fields):
        normals = np.stack([col["normal_x"], col["normal_y"], col["normal_z"]], axis=1)[finite]
    colors = None
    if "rgb" in fields:
        packed = np.asarray(col["rgb"], dtype=np.float32).view(np.uint32)
        rgb = np.stack([(packed >> 16) & 255, (packed >> 8) & 255, packed & 255], axis=1)
        colors = rgb[finite].astype(np.float64) / 255.0
    return SurfaceCloud(points=points[finite], normals=normals, colors=colors)


def load_npz(path: str | Path) -> SurfaceCloud:
    """Read an ``.npz`` with ``points`` (N, 3) and optional ``normals``, ``colors``, ``target``."""
    p = _check_file(path)
    try:
        with np.load(p, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except (ValueError, OSError) as exc:
        raise CloudError(f"'{p}' is not a readable .npz of arrays: {exc}") from exc
    if "points" not in data:
        raise CloudError(f"'{p}' has no 'points' array (found {sorted(data)})")
    colors = _colors_to_unit(data["colors"]) if "colors" in data else None
    spacing = float(data["spacing"]) if "spacing" in data else 0.0
    return SurfaceCloud(
        points=data["points"],
        normals=data.get("normals"),
        colors=colors,
        target=data.get("target"),
        spacing=spacing,
    )


def save_npz(cloud: SurfaceCloud, path: str | Path) -> Path:
    """Write a cloud as an ``.npz`` of plain arrays (no pickle)."""
    arrays: dict[str, Any] = {"points": cloud.points, "target": cloud.target, "spacing": cloud.spacing}
    if cloud.normals is not None:
        arrays["normals"] = cloud.normals
    if cloud.colors is not None:
        arrays["colors"] = cloud.colors
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    np.savez(out, **arrays)
    return out


def load_cloud(path: str | Path) -> SurfaceCloud:
    """Read a cloud, choosing the reader from the suffix (.ply, .pcd, .npz)."""
    p = Path(path)
    readers = {".ply": load_ply, ".pcd": load_pcd, ".npz": load_npz}
    reader = readers.get(p.suffix.lower())
    if reader is None:
        raise InputError(
            f"cannot read '{p}': unknown suffix '{p.suffix}'; supported: {', '.join(SUPPORTED_SUFFIXES)}"
        )
    return reader(p)


def save_cloud(cloud: SurfaceCloud, path: str | Path) -> Path:
    """Write a cloud as .ply or .npz, by suffix."""
    p = Path(path)
    if p.suffix.lower() == ".ply":
        return save_ply(cloud, p)
    if p.suffix.lower() == ".npz":
        return save_npz(cloud, p)
    raise InputError(f"cannot write '{p}': use a .ply or .npz suffix")


def _open3d() -> Any:
    try:
        import open3d
    except ImportError as exc:
        raise MissingDependencyError("open3d", "open3d", "Converting Open3D point clouds") from exc
    return open3d


def from_open3d(pcd: Any) -> SurfaceCloud:
    """Convert an ``open3d.geometry.PointCloud`` (needs the ``open3d`` extra)."""
    _open3d()
    points = np.asarray(pcd.points)
    normals = np.asarray(pcd.normals) if pcd.has_normals() else None
    colors = np.asarray(pcd.colors) if pcd.has_colors() else None
    return SurfaceCloud(points=points, normals=normals, colors=colors)


def to_open3d(cloud: SurfaceCloud) -> Any:
    """Convert to an ``open3d.geometry.PointCloud`` (needs the ``open3d`` extra)."""
    o3d = _open3d()
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cloud.points))
    if cloud.normals is not None:
        pcd.normals = o3d.utility.Vector3dVector(cloud.normals)
    if cloud.colors is not None:
        pcd.colors = o3d.utility.Vector3dVector(cloud.colors)
    return pcd
