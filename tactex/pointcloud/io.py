"""Reading and writing point clouds: PLY (plyfile), PCD (pypcd4), NPZ, meshes (trimesh), Open3D.

All readers return a :class:`SurfaceCloud` in metres; colours are scaled to [0, 1]. NPZ files are
read with ``allow_pickle=False`` (a cloud a user receives must never execute code).

One rule for points with NaN/inf coordinates (or normals), in every format: they are dropped and
counted (:attr:`CloudFile.n_dropped`), and the commands say so. Meshes — a PLY with faces, STL, OBJ:
the CAD parts industrial users have — are sampled on their surface at the voxel spacing
(:func:`tactex.pointcloud.mesh.sample_mesh`), never reduced to their vertices.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from tactex.errors import CloudError, InputError, MissingDependencyError, UnitsError
from tactex.pointcloud.cloud import CloudFile, SurfaceCloud
from tactex.pointcloud.units import check_units, inch_hint, metre_hint, to_metres

__all__ = [
    "MESH_SUFFIXES",
    "SUPPORTED_SUFFIXES",
    "CloudFile",
    "from_open3d",
    "load_cloud",
    "load_npz",
    "load_pcd",
    "load_ply",
    "read_cloud",
    "save_cloud",
    "save_npz",
    "save_ply",
    "to_open3d",
]

SUPPORTED_SUFFIXES = (".ply", ".pcd", ".npz", ".stl", ".obj")
#: Suffixes that always hold a mesh (a .ply holds one when it has faces).
MESH_SUFFIXES = (".stl", ".obj")
#: Sampling spacing of a mesh when none is given: TEC's voxel size [m].
DEFAULT_MESH_SPACING_M = 0.003


class _Finite:
    """Drops the rows where points (or normals) are not finite, remembering how many."""

    def __init__(self, points: np.ndarray, normals: np.ndarray | None) -> None:
        points = np.asarray(points, dtype=np.float64)
        if points.ndim != 2 or points.shape[1] != 3:
            self.keep = None  # SurfaceCloud reports the shape
            self.dropped = 0
            return
        keep = np.isfinite(points).all(axis=1)
        if normals is not None and np.shape(normals) == points.shape:
            keep &= np.isfinite(np.asarray(normals, dtype=np.float64)).all(axis=1)
        self.keep = keep
        self.dropped = int(keep.size - keep.sum())

    def kept_rows(self) -> np.ndarray | None:
        """Per row, whether it was kept; None when every row was."""
        return self.keep if self.dropped else None

    def __call__(self, values: Any) -> Any:
        if values is None or self.keep is None or not self.dropped:
            return values
        values = np.asarray(values)
        return values[self.keep] if values.shape[:1] == self.keep.shape else values


def _dropped_note(n: int, total: int) -> tuple[str, ...]:
    return (f"dropped {n} of {total} points with NaN/inf coordinates or normals",) if n else ()


#: Float colours up to this are taken as 0..1 (and clipped): a float32 1.0 written by another tool
#: may come back as 1.0000001, and must not turn the whole cloud into 0..255 colours.
_UNIT_COLOR_TOL = 1e-3


def _colors_to_unit(rgb: np.ndarray) -> np.ndarray:
    rgb = np.asarray(rgb)
    if np.issubdtype(rgb.dtype, np.integer):
        # 8-bit colours are 0..255; 16-bit ones 0..65535 (only when a value exceeds 255 can they be told apart)
        full = 255.0 if rgb.size == 0 or rgb.max() <= 255 else float(np.iinfo(rgb.dtype).max)
        return rgb.astype(np.float64) / full
    rgb = rgb.astype(np.float64)
    # Float colours in 0..255 appear in the wild; 0..1 is the convention.
    if rgb.size and rgb.max() > 1.0 + _UNIT_COLOR_TOL:
        return rgb / 255.0
    return np.clip(rgb, 0.0, 1.0)


def _check_file(path: str | Path) -> Path:
    p = Path(path)
    if not p.is_file():
        raise InputError(f"point cloud file '{p}' does not exist (or is not a file)")
    return p


def load_ply(path: str | Path) -> SurfaceCloud:
    """Read a PLY file's vertex element: x y z, optional nx ny nz and red green blue (a PLY with
    faces is sampled as a mesh: see :func:`read_cloud`)."""
    return _read_ply(_check_file(path), DEFAULT_MESH_SPACING_M).cloud


#: The vertex properties a PLY cloud is read from.
_USED = frozenset({"x", "y", "z", "nx", "ny", "nz", "red", "green", "blue", "target", "keep_out"})


def _read_ply(p: Path, mesh_spacing_m: float, units: str = "m") -> CloudFile:
    from plyfile import PlyListProperty

    from tactex.pointcloud.ply_check import read_ply
    from tactex.pointcloud.ply_marks import file_keep_out, keep_out_note

    ply = read_ply(p)
    if "face" in ply and ply["face"].count > 0:
        from tactex.pointcloud.mesh import read_mesh

        return read_mesh(p, mesh_spacing_m, units)
    if "vertex" not in ply:
        raise CloudError(f"'{p}' has no 'vertex' element")
    v = ply["vertex"]
    names = set(v.data.dtype.names or ())
    if not {"x", "y", "z"} <= names:
        raise CloudError(f"'{p}' vertices lack x/y/z properties (found {sorted(names)})")
    lists = sorted(prop.name for prop in v.properties if isinstance(prop, PlyListProperty) and prop.name in _USED)
    if lists:
        raise CloudError(f"'{p}': its vertex properties {', '.join(lists)} are lists; a vertex's x, y, z, normal, "
                         "colour, target and keep_out are single numbers")
    points = to_metres(np.stack([v["x"], v["y"], v["z"]], axis=1), units)
    normals = (
        np.stack([v["nx"], v["ny"], v["nz"]], axis=1).astype(np.float64)
        if {"nx", "ny", "nz"} <= names
        else None
    )
    finite = _Finite(points, normals)
    colors = (
        _colors_to_unit(finite(np.stack([v["red"], v["green"], v["blue"]], axis=1)))
        if {"red", "green", "blue"} <= names
        else None
    )
    target = np.asarray(v["target"], dtype=np.float64) if "target" in names else None
    cloud = SurfaceCloud(points=finite(points), normals=finite(normals), colors=colors, target=finite(target),
                         spacing=float(to_metres(_ply_spacing(ply), units)))
    keep_out = file_keep_out(v, finite)
    return CloudFile(cloud, finite.dropped, notes=_dropped_note(finite.dropped, len(points)) + keep_out_note(keep_out),
                     kept=finite.kept_rows(), keep_out=keep_out)


#: The comment save_ply writes so that a voxel-filtered cloud keeps its spacing h [m] through a PLY.
_SPACING_COMMENT = "tactex spacing_m "


def _ply_spacing(ply) -> float:
    for comment in ply.comments:
        if comment.startswith(_SPACING_COMMENT):
            try:
                value = float(comment[len(_SPACING_COMMENT):])
            except ValueError:
                break
            return value if np.isfinite(value) and value > 0.0 else 0.0
    return 0.0  # computed from the points


def save_ply(cloud: SurfaceCloud, path: str | Path, *, extra: dict[str, np.ndarray] | None = None) -> Path:
    """Write a binary PLY with x y z, normals and 8-bit colours when present, the target, and
    any ``extra`` per-point float properties (e.g. ``curvature``). The spacing h goes in a comment
    (``load_ply`` reads it back). Colours are quantised to 8 bits: a colour threshold applied again
    after a round trip may select slightly differently; the ``target`` itself is stored exactly."""
    from plyfile import PlyData, PlyElement

    n = len(cloud)
    fields: list[tuple[str, str]] = [("x", "f8"), ("y", "f8"), ("z", "f8")]
    if cloud.normals is not None:
        fields += [("nx", "f8"), ("ny", "f8"), ("nz", "f8")]
    if cloud.colors is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    fields.append(("target", "f8"))
    extra = extra or {}
    taken = {name for name, _ in fields}
    for key, values in extra.items():
        if key in taken:
            raise InputError(f"extra property '{key}' clashes with a standard one ({', '.join(sorted(taken))})")
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
    PlyData([PlyElement.describe(data, "vertex")], comments=[f"{_SPACING_COMMENT}{cloud.spacing!r}"]).write(str(out))
    return out


def load_pcd(path: str | Path) -> SurfaceCloud:
    """Read a PCL PCD file (VERSION .5/.6/.7; ascii/binary/binary_compressed) with pypcd4; packed
    ``rgb`` is decoded."""
    return _read_pcd(_check_file(path)).cloud


def _read_pcd(p: Path, units: str = "m") -> CloudFile:
    from tactex.pointcloud.pcd_header import read_pcd

    try:
        pc = read_pcd(p)
    except CloudError as exc:
        raise CloudError(f"'{p}': {exc}") from None
    fields = tuple(pc.fields)
    # the used fields as stored: pc.numpy() would cast every field, used or not, to one common type
    col = {name: np.atleast_1d(pc.pc_data[name]) for name in fields}
    if not {"x", "y", "z"} <= set(fields):
        raise CloudError(f"'{p}' lacks x/y/z fields (found {list(fields)})")
    points = to_metres(np.stack([col["x"], col["y"], col["z"]], axis=1), units)
    normals = None
    if {"normal_x", "normal_y", "normal_z"} <= set(fields):
        normals = np.stack([col["normal_x"], col["normal_y"], col["normal_z"]], axis=1).astype(np.float64)
    finite = _Finite(points, normals)  # organised PCDs pad with NaN
    colors = None
    if "rgb" in fields or "rgba" in fields:
        ascii_file = str(getattr(pc.metadata.data, "value", pc.metadata.data)).lower() == "ascii"
        try:
            packed = _packed_rgb(col["rgb" if "rgb" in fields else "rgba"], ascii_file)
        except CloudError as exc:
            raise CloudError(f"'{p}': {exc}") from exc
        rgb = np.stack([(packed >> 16) & 255, (packed >> 8) & 255, packed & 255], axis=1)
        colors = finite(rgb).astype(np.float64) / 255.0
    elif {"r", "g", "b"} <= set(fields):
        colors = _colors_to_unit(finite(np.stack([col["r"], col["g"], col["b"]], axis=1)))
    cloud = SurfaceCloud(points=finite(points), normals=finite(normals), colors=colors)
    return CloudFile(cloud, finite.dropped, notes=_dropped_note(finite.dropped, len(points)),
                     kept=finite.kept_rows())


def _packed_rgb(field: np.ndarray, ascii_file: bool) -> np.ndarray:
    """PCL's packed 0x00RRGGBB as uint32 from the field as stored: an integer type holds it as is; a
    float one holds its bits in binary files. In ascii files PCL's writer prints the integer itself
    ("despite the float type, store the rgb field as uint32"), while writers that bit-cast the
    float (Open3D's, struct.pack) print tiny numbers: 0x00RRGGBB read as a float32 is below 2⁻¹²⁵
    (its top byte is 0), which a printed integer never is. Those are decoded as bits; fractions
    between them and 1 are neither convention and are refused."""
    field = np.asarray(field)
    if np.issubdtype(field.dtype, np.integer):
        return field.astype(np.uint32)
    if ascii_file:
        values = np.nan_to_num(field.astype(np.float64))
        frac = values != np.round(values)
        if frac.any():
            if np.abs(values).max() >= 2.0**-125:
                raise CloudError(
                    f"its rgb field holds fractions such as {values[frac][0]:.6g}: neither PCL's packed integer nor "
                    "a bit-cast float (values below 1.2e-38); write the colours as packed integers or r, g, b fields"
                )
            return values.astype(np.float32).view(np.uint32)
        return np.clip(np.round(values), 0.0, 2.0**32 - 1).astype(np.uint32)
    with np.errstate(over="ignore", invalid="ignore"):  # an 8-byte float rgb field: only its float32 bits count
        return field.astype(np.float32).view(np.uint32)


def load_npz(path: str | Path) -> SurfaceCloud:
    """Read an ``.npz`` with ``points`` (N, 3) and optional ``normals``, ``colors``, ``target``."""
    return _read_npz(_check_file(path)).cloud


def _read_npz(p: Path, units: str = "m") -> CloudFile:
    from tactex.pointcloud.npz_check import read_npz_arrays

    data = read_npz_arrays(p)
    colors = _colors_to_unit(data["colors"]) if "colors" in data else None
    spacing = 0.0
    if "spacing" in data:
        if np.shape(data["spacing"]) != ():
            raise CloudError(f"'{p}': 'spacing' must be one number [m], got shape {np.shape(data['spacing'])}")
        spacing = float(to_metres(data["spacing"], units))
    points = to_metres(data["points"], units) if np.ndim(data["points"]) == 2 else data["points"]
    finite = _Finite(points, data.get("normals"))
    cloud = SurfaceCloud(
        points=finite(points),
        normals=finite(data.get("normals")),
        colors=finite(colors),
        target=finite(data.get("target")),
        spacing=spacing,
    )
    return CloudFile(cloud, finite.dropped, notes=_dropped_note(finite.dropped, len(points)),
                     kept=finite.kept_rows())


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


def load_cloud(path: str | Path, *, mesh_spacing_m: float = DEFAULT_MESH_SPACING_M, units: str = "m") -> SurfaceCloud:
    """Read a cloud, choosing the reader from the suffix (.ply, .pcd, .npz, .stl, .obj); points with
    NaN/inf coordinates are dropped (:func:`read_cloud` says how many)."""
    return read_cloud(path, mesh_spacing_m=mesh_spacing_m, units=units).cloud


def read_cloud(path: str | Path, *, mesh_spacing_m: float = DEFAULT_MESH_SPACING_M, units: str = "m") -> CloudFile:
    """Read a cloud file and report what reading it did (points dropped, a mesh sampled).

    Args:
        path: .ply, .pcd, .npz, .stl or .obj file.
        mesh_spacing_m: sampling spacing of a mesh's surface [m] (the voxel size of the run).
        units: the file's length unit, "m", "mm" or "in" (:mod:`tactex.pointcloud.units`): its coordinates
            (and a stored spacing) are converted to metres before they are checked.
    """
    units = check_units(units)
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix not in SUPPORTED_SUFFIXES:
        raise InputError(
            f"cannot read '{p}': unknown suffix '{p.suffix}'; supported: {', '.join(SUPPORTED_SUFFIXES)}"
        )
    p = _check_file(p)
    # A signalling NaN in float data (a damaged file's bits) makes numpy warn "invalid value
    # encountered in cast" when it is widened to float64; the point is dropped and counted by the
    # finite rule, so the warning would only add numpy's words to the CLI's output.
    with np.errstate(invalid="ignore"):
        read = _read_by_suffix(p, suffix, mesh_spacing_m, units)
    points = read.cloud.points
    extent = float(np.max(np.ptp(points, axis=0))) if len(points) else 0.0
    tiny = metre_hint(extent, units)
    if tiny:  # refused here: every later check (its colours, its size against a voxel) would point elsewhere
        raise UnitsError(f"'{p}': {tiny}")
    hint = inch_hint(extent) if units == "m" else ""
    if hint:  # a part this wide is beyond an arm's reach: more likely a file in inches
        read = replace(read, notes=(*read.notes, f"it spans {extent:.3g} m, more than a robot arm reaches; "
                                                 f"{hint}"))
    return read


def _read_by_suffix(p: Path, suffix: str, mesh_spacing_m: float, units: str) -> CloudFile:
    from tactex.pointcloud.mesh import read_mesh

    try:
        if suffix == ".ply":
            return _read_ply(p, mesh_spacing_m, units)
        if suffix == ".pcd":
            return _read_pcd(p, units)
        if suffix == ".npz":
            return _read_npz(p, units)
        return read_mesh(p, mesh_spacing_m, units)
    except (CloudError, UnitsError) as exc:
        if f"'{p}'" in str(exc):
            raise
        # the cloud's own message cannot name the file
        raise type(exc)(f"'{p}': {exc}") from exc


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
