"""A user's part (a mesh or a scan file) as a simulated object, to rehearse cleaning it before the robot
touches it (``tactex clean --object PART.stl``).

The part becomes a height-field object like the built-in ones: the top surface of its file, ray cast
straight down on a 1 mm grid (:mod:`tactex.sim.part_raster`), bilinearly interpolated, and given to
MuJoCo on the coarsest grid whose linear interpolation stays within :data:`HFIELD_TOLERANCE_M` of it
(curvature h'' costs h''·s²/8 at spacing s). What a height field cannot hold is lost, and said:
the part's vertical sides become slopes one grid cell wide, and any surface under a higher one (an
overhang, a lip, a cavity's floor seen through nothing) is replaced by the surface above it; a part
losing more than :data:`MAX_LOST_SHARE` of its upward area is refused. Whether the mesh is watertight
does not matter: only what is seen from above is kept.

Frames: the file's coordinates in its ``units``, converted to metres; the part frame has z up (the
file's +z), the part's lowest point at z = 0 and x–y centred on its bounding box. The scene places
that frame at ``position_m`` (default :data:`PART_POSITION_M`, in front of the robot, on the table).
The dirt is the file's coloured marking (red by hue and saturation, as a capture judges it) or its
stored ``target``; with neither, a scene's ``--marking`` draws one on the part's bounding square.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from tactex.errors import CloudError, ConfigError, InputError, UnitsError
from tactex.pointcloud.cloud import MAX_EXTENT_M, SurfaceCloud
from tactex.pointcloud.io import SUPPORTED_SUFFIXES
from tactex.pointcloud.units import check_units, millimetre_hint, to_metres
from tactex.sim.objects import SimObject, get_object, heightfield_object, object_names, resolve_object_name
from tactex.sim.part_raster import HeightRaster, bilinear, raster_mesh, raster_points

__all__ = ["FINE_SPACING_M", "HFIELD_TOLERANCE_M", "MAX_LOST_SHARE", "PART_POSITION_M", "PartInfo",
           "check_reach", "is_part_file", "load_part", "object_or_part", "part_info", "resolve_object_or_part"]

#: Spacing of the raster the part's surface is read on [m] (its height function between the nodes).
FINE_SPACING_M = 0.001
#: Largest raster [nodes]: a 0.8 m part at 1 mm; larger parts are read on a coarser grid.
MAX_FINE_NODES = 700_000
#: Height-field spacings tried, coarsest first [m]: contact costs grow with the cells under the pad.
HFIELD_SPACINGS_M = (0.01, 0.008, 0.006, 0.005, 0.004, 0.003, 0.002)
#: The MuJoCo height field's linear interpolation may differ from the part's raster by this much at 99 %
#: of the footprint's nodes away from its outline [m]; steep walls and creases make up the last 1 %.
HFIELD_TOLERANCE_M = 1e-4
#: A part whose height field loses more of its upward area than this is refused [-].
MAX_LOST_SHARE = 0.02
#: Where a part's frame goes by default, in the robot base frame [m]: where the built-in objects stand.
PART_POSITION_M = (0.5, 0.0, 0.0)
#: The part's surface must lie within this horizontal distance of the robot's base axis [m]: a Franka
#: reaches 0.855 m from its shoulder, and presses down with a 0.1 m tool hanging under its flange.
REACH_MAX_M = 0.8
#: ... and no nearer than this, the robot's own base [m].
REACH_MIN_M = 0.25
#: The part's top may be at most this high above the table [m] (pressing from above with the camera above).
MAX_HEIGHT_M = 0.4
#: Lowest top a part may have above its lowest point [m]: the capture cuts the table 2 mm above its top, so a
#: flatter part (a scan of a flat face, without its thickness) is not told from the table.
MIN_HEIGHT_M = 0.005
#: The part's clean colour when the file has none.
PART_RGB = (0.85, 0.85, 0.82)


def is_part_file(name: str) -> bool:
    """Whether an object name is a file path (by its suffix: a mesh or a scan), not a registry name."""
    return Path(str(name)).suffix.lower() in SUPPORTED_SUFFIXES


@dataclass(frozen=True)
class PartInfo:
    """What turning the file into a height field kept and lost.

    Attributes:
        path: the file.
        units: its length unit.
        size_m: the part's extent x, y, z [m].
        file_origin_m: where the part frame's origin lies in the file's coordinates [m]: the scene position
            that puts the part where the file has it (a scan in the robot base frame).
        hfield_spacing_m: the MuJoCo height field's grid [m].
        hfield_error_m: the height field's interpolation error at 99 % of the footprint's inner nodes [m].
        lost_share: share of the upward area (a scan: of its points) under a higher surface, lost [-].
        has_target: whether the file marks the dirt (colours or a stored target).
        target_share: share of the footprint's area that is dirt by the file [-].
    """

    path: str
    units: str
    size_m: tuple[float, float, float]
    file_origin_m: tuple[float, float, float]
    hfield_spacing_m: float
    hfield_error_m: float
    lost_share: float
    has_target: bool
    target_share: float

    def describe(self) -> str:
        """One line for the user: size, grid, what is lost."""
        sx, sy, sz = (v * 1e3 for v in self.size_m)
        dirt = "the file's marking" if self.has_target else "none in the file"
        return (f"part {Path(self.path).name}: {sx:.0f} × {sy:.0f} × {sz:.0f} mm, height field every "
                f"{self.hfield_spacing_m * 1e3:.0f} mm (within {self.hfield_error_m * 1e3:.2f} mm), "
                f"{self.lost_share:.1%} of its upward surface under overhangs lost, vertical sides become slopes "
                f"one cell wide; dirt: {dirt}")


def _fine_spacing(size_xy: np.ndarray) -> float:
    nodes = np.prod(size_xy / FINE_SPACING_M + 1)
    return FINE_SPACING_M if nodes <= MAX_FINE_NODES else float(np.sqrt(np.prod(size_xy) / MAX_FINE_NODES)) * 1.01


def _read_mesh(path: Path, units: str):
    """(vertices (V, 3) [m], faces, vertex colours, face colours, vertex target, watertight) of a mesh file,
    or None when the file holds a cloud (a PLY without faces, a PCD or NPZ)."""
    suffix = path.suffix.lower()
    if suffix == ".ply":
        from tactex.pointcloud.ply_check import read_ply

        ply = read_ply(path)
        if "face" not in ply or ply["face"].count == 0:
            return None
        vertex = ply["vertex"]
        if "target" in (vertex.data.dtype.names or ()):
            return _ply_mesh_with_target(ply, units)
    elif suffix not in (".stl", ".obj"):
        return None
    from tactex.pointcloud.mesh_load import load_mesh

    mesh, _ = load_mesh(path)
    v = to_metres(np.asarray(mesh.vertices, dtype=np.float64), units)
    vc = fc = None
    if mesh.visual.defined and mesh.visual.kind == "vertex":
        vc = np.asarray(mesh.visual.vertex_colors[:, :3], dtype=np.float64) / 255.0
    elif mesh.visual.defined and mesh.visual.kind == "face":
        fc = np.asarray(mesh.visual.face_colors[:, :3], dtype=np.float64) / 255.0
    return v, np.asarray(mesh.faces), vc, fc, None, bool(mesh.is_watertight)


def _ply_mesh_with_target(ply, units: str):
    """A PLY mesh with a per-vertex ``target`` property, read as it is stored (trimesh drops the property)."""
    v = ply["vertex"]
    names = set(v.data.dtype.names or ())
    pts = to_metres(np.stack([v["x"], v["y"], v["z"]], axis=1), units)
    faces = [np.asarray(f, dtype=np.int64) for f in ply["face"].data[ply["face"].data.dtype.names[0]]]
    tris = [f for f in faces if len(f) == 3]
    if len(tris) != len(faces):
        raise CloudError("a PLY part with a 'target' property must be triangulated (its faces have 3 vertices)")
    f = np.stack(tris)
    vc = (np.stack([v["red"], v["green"], v["blue"]], axis=1) / 255.0) if {"red", "green", "blue"} <= names else None
    return pts, f, vc, None, np.asarray(v["target"], dtype=np.float64), False


def _raster(path: Path, units: str) -> tuple[HeightRaster, np.ndarray]:
    """The part's raster and its file origin (the part frame's origin in the file's coordinates [m])."""
    mesh = _read_mesh(path, units)
    if mesh is not None:
        v, f, vc, fc, vt, watertight = mesh
        if not np.isfinite(v).all():
            raise CloudError(f"'{path}' has vertices with NaN/inf coordinates: repair the mesh")
        pts = v
    else:
        from tactex.pointcloud.io import read_cloud

        cloud: SurfaceCloud = read_cloud(path, units=units).cloud
        pts = cloud.points
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    extent = float(np.max(hi - lo))
    if extent > MAX_EXTENT_M:
        raise UnitsError(f"--object '{path}' spans {extent:.4g} m along one axis: {millimetre_hint(extent, units)}")
    origin = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]])
    size = hi - lo
    if max(size[0], size[1]) > 2 * REACH_MAX_M or size[2] > MAX_HEIGHT_M:
        raise ConfigError(f"--object '{path}' is {size[0]:.3g} × {size[1]:.3g} × {size[2]:.3g} m: too big for the "
                          f"arm's reach (at most {2 * REACH_MAX_M:g} m across and {MAX_HEIGHT_M:g} m high); "
                          "check --units or clean it in sections")
    if size[2] < MIN_HEIGHT_M:
        raise ConfigError(f"--object '{path}' rises {size[2] * 1e3:.2g} mm above its lowest point: the camera's "
                          "capture cannot tell so flat a part from the table it stands on (it keeps what is 2 mm "
                          f"or more above it); give the part with its thickness (at least {MIN_HEIGHT_M * 1e3:g} "
                          "mm: a closed mesh, or a scan that includes its sides)")
    if min(size[0], size[1]) < 0.02:
        raise ConfigError(f"--object '{path}' is {size[0] * 1e3:.3g} × {size[1] * 1e3:.3g} mm seen from above: "
                          "smaller than the sponge; check --units (a file in metres read as mm?)")
    spacing = _fine_spacing(size[:2])
    if mesh is not None:
        return raster_mesh(v - origin, f, spacing, vc, fc, vt, watertight), origin
    sub = cloud.points - origin
    nn = cloud.spacing if cloud.spacing > 0 else _scan_spacing(sub)
    return raster_points(sub, max(spacing, 2 * nn), cloud.colors,
                         cloud.target if cloud.n_target > 0 else None), origin


def _scan_spacing(points: np.ndarray) -> float:
    from scipy.spatial import cKDTree

    d = cKDTree(points).query(points[:: max(1, len(points) // 2000)], k=2)[0][:, 1]
    return float(np.median(d))


def _dirt_mask(raster: HeightRaster, path: Path) -> np.ndarray | None:
    """(ny, nx) True where the file marks dirt: its stored target > 0, else its red marking (by hue and
    saturation, the rule of ``tactex clean --cloud``); None when the file marks nothing."""
    if raster.target is not None and (raster.target[raster.footprint] > 0).any():
        return (raster.target >= 0.5) & raster.footprint
    if raster.colors is None:
        return None
    from tactex.pointcloud.target import color_mask

    red = color_mask(raster.colors.reshape(-1, 3), "red").reshape(raster.footprint.shape) & raster.footprint
    return red if red.any() else None


def _interpolation_error(raster: HeightRaster, spacing_m: float) -> float:
    """The 99th percentile of |height field − raster| [m] over the footprint's nodes at least two height-field
    cells in from its outline, for a MuJoCo grid of ``spacing_m``."""
    from scipy import ndimage

    xs, ys, z = raster.xs, raster.ys, raster.z
    nx = max(2, int(np.ceil((xs[-1] - xs[0]) / spacing_m)) + 1)
    ny = max(2, int(np.ceil((ys[-1] - ys[0]) / spacing_m)) + 1)
    cx, cy = np.linspace(xs[0], xs[-1], nx), np.linspace(ys[0], ys[-1], ny)
    gx, gy = np.meshgrid(cx, cy)
    coarse = bilinear(xs, ys, z, gx, gy)
    fx, fy = np.meshgrid(xs, ys)
    err = np.abs(bilinear(cx, cy, coarse, fx, fy) - z)
    inner = ndimage.binary_erosion(raster.footprint, iterations=int(np.ceil(2 * spacing_m / raster.spacing_m)))
    return float(np.percentile(err[inner], 99)) if inner.any() else 0.0


def _hfield_spacing(raster: HeightRaster) -> tuple[float, float]:
    """The coarsest spacing of :data:`HFIELD_SPACINGS_M` within :data:`HFIELD_TOLERANCE_M`, and its error."""
    err = 0.0
    for s in HFIELD_SPACINGS_M:
        s = max(s, raster.spacing_m)
        err = _interpolation_error(raster, s)
        if err <= HFIELD_TOLERANCE_M:
            return s, err
    return s, err


def _nearest_mask(raster: HeightRaster, mask: np.ndarray):
    """A marking function uv → (N,) reading ``mask`` (ny, nx) at the node nearest each point of the part's
    bounding square (uv = (x / size_x + 1/2, y / size_y + 1/2), as a height field's uv)."""
    nx, ny = len(raster.xs), len(raster.ys)

    def marking(uv: np.ndarray) -> np.ndarray:
        uv = np.asarray(uv, dtype=float)
        c = np.clip(np.rint(uv[:, 0] * (nx - 1)).astype(np.int64), 0, nx - 1)
        r = np.clip(np.rint(uv[:, 1] * (ny - 1)).astype(np.int64), 0, ny - 1)
        return mask[r, c]

    return marking


@lru_cache(maxsize=8)
def _load(path: str, units: str, mtime_ns: int) -> tuple[SimObject, PartInfo]:
    p = Path(path)
    raster, origin = _raster(p, units)
    if raster.lost_share > MAX_LOST_SHARE:
        raise ConfigError(
            f"--object '{p}': {raster.lost_share:.1%} of its upward surface lies under a higher one (an overhang, a "
            f"lip, a cavity) and a height field would lose it (at most {MAX_LOST_SHARE:.0%}): turn the part so that "
            "the side to clean faces +z in the file, or remove what overhangs it")
    spacing, err = _hfield_spacing(raster)
    mask = _dirt_mask(raster, p)
    xs, ys, z = raster.xs, raster.ys, raster.z
    size_x, size_y = float(xs[-1] - xs[0]), float(ys[-1] - ys[0])
    # a part covering its whole bounding square stands on a solid of its lowest top height (a flat slab is then
    # a box, whose top MuJoCo puts at the frame's z = 0)
    lift = float(z.min()) if raster.footprint.all() else 0.0
    z = z - lift

    def height(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return bilinear(xs, ys, z, x, y)

    info = PartInfo(path, units, (size_x, size_y, float(z.max()) + lift), tuple(float(v) for v in origin), spacing, err,
                    raster.lost_share, mask is not None,
                    0.0 if mask is None else float(mask.sum() / max(raster.footprint.sum(), 1)))
    marking = _nearest_mask(raster, np.zeros_like(raster.footprint) if mask is None else mask)
    obj = heightfield_object(path, height, size_x, size_y, marking=marking, hfield_spacing_m=spacing,
                             rgb=PART_RGB, position_m=PART_POSITION_M, lift_m=lift, base_thickness_m=max(lift, 0.01),
                             extra={"part": info})
    return obj, info


def load_part(path: str | Path, units: str = "m") -> SimObject:
    """The simulated object of the part file ``path`` (.stl/.obj/.ply mesh, or a .ply/.pcd/.npz scan) whose
    coordinates are in ``units``; its :class:`PartInfo` is ``obj.extra['part']``. The same file (unchanged)
    and units give the same object.

    Raises:
        InputError: the file is missing or unreadable, in the wrong units, too big, or loses more than
            :data:`MAX_LOST_SHARE` of its upward surface to overhangs.
    """
    units = check_units(units)
    p = Path(path).expanduser()
    if not p.is_file():
        raise InputError(f"--object '{path}' is not a file (give a part's .stl/.obj/.ply mesh or a .ply/.pcd/.npz "
                         "scan, or a built-in object's name)")
    return _load(str(p.resolve()), units, p.stat().st_mtime_ns)[0]


def resolve_object_or_part(name: str) -> str:
    """A built-in object's registered name (in any case), or a part file's absolute path (a name with a mesh or
    scan suffix, :func:`is_part_file`); the error says which is missing."""
    if not is_part_file(name):
        return resolve_object_name(name)
    p = Path(str(name)).expanduser()
    if not p.is_file():
        raise ConfigError(f"--object '{name}' is not a file (give a part's .stl/.obj/.ply mesh or a .ply/.pcd/.npz "
                          f"scan, or one of the objects {', '.join(object_names())})")
    return str(p.resolve())


def object_or_part(name: str, units: str = "m") -> SimObject:
    """The built-in object ``name``, or the part in the file ``name`` read in ``units`` (:func:`load_part`)."""
    return load_part(name, units) if is_part_file(name) else get_object(name)


def part_info(obj: SimObject) -> PartInfo | None:
    """A part's :class:`PartInfo`, None for a built-in object."""
    info = obj.extra.get("part") if isinstance(obj.extra, dict) else None
    return info if isinstance(info, PartInfo) else None


def check_reach(obj: SimObject, position_m, rotation: np.ndarray) -> None:
    """Refuse a part whose surface, placed at ``position_m`` [m] turned by ``rotation`` (robot base frame),
    is not all within the arm's reach: :data:`REACH_MIN_M`–:data:`REACH_MAX_M` from the base's axis."""
    info = part_info(obj)
    if info is None:  # a built-in object: its centre at least (the door spans more than the reach allows)
        r = float(np.hypot(*np.asarray(position_m, dtype=float)[:2]))
        if not REACH_MIN_M <= r <= REACH_MAX_M:
            raise ConfigError(
                f"--object {obj.name} at {np.round(np.asarray(position_m, float), 3).tolist()} m stands {r:.2f} m "
                f"from the robot's base axis: beyond the arm's reach ({REACH_MIN_M:g}–{REACH_MAX_M:g} m); move "
                "it with --object-position")
        return
    xs, ys, _ = obj.heightfield()
    gx, gy = np.meshgrid(xs, ys)
    corners = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])
    world = np.asarray(position_m, dtype=float) + corners @ np.asarray(rotation, dtype=float).T
    r = np.hypot(world[:, 0], world[:, 1])
    if r.max() > REACH_MAX_M or r.min() < REACH_MIN_M:
        raise ConfigError(
            f"--object '{Path(info.path).name}' at {np.round(np.asarray(position_m, float), 3).tolist()} m spans "
            f"{r.min():.2f}–{r.max():.2f} m from the robot's base axis: beyond the arm's reach "
            f"({REACH_MIN_M:g}–{REACH_MAX_M:g} m); move it with --object-position or clean it in sections")
