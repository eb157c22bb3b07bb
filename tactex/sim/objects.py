"""Objects of the simulated scene: a registry over the shared analytic surfaces.

Each :class:`SimObject` wraps a :class:`tactex.pointcloud.shapes.Surface` (the same geometry the
point-cloud side samples) with what the simulator needs: an intrinsic pose (the tilted plane is
the plane turned by 15°), a colour, a default marking, and the height-field resolution. Height
surfaces become MuJoCo height fields sampled from ``Surface.height`` on a grid; flat ones a box;
the cup wall a cylinder. Each object also has a default placement in front of the robot, where a
scene puts it unless told otherwise. Adding an object is one :func:`register_object` call.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from tactex.errors import ConfigError, InputError
from tactex.pointcloud.shapes import SURFACES, CylinderWallSurface, HeightFieldSurface, Surface
from tactex.sim.franka import _fmt
from tactex.sim.part_raster import bilinear

__all__ = [
    "OBJECTS",
    "SimObject",
    "get_object",
    "heightfield_from_image",
    "heightfield_object",
    "object_names",
    "register_object",
    "resolve_object_name",
    "rotation_from_rpy_deg",
]


def rotation_from_rpy_deg(rpy_deg) -> np.ndarray:
    """Rotation matrix R = Rz(yaw)·Ry(pitch)·Rx(roll) from (roll, pitch, yaw) [deg]."""
    r, p, y = np.deg2rad(np.asarray(rpy_deg, dtype=float).reshape(3))
    rx = np.array([[1, 0, 0], [0, np.cos(r), -np.sin(r)], [0, np.sin(r), np.cos(r)]])
    ry = np.array([[np.cos(p), 0, np.sin(p)], [0, 1, 0], [-np.sin(p), 0, np.cos(p)]])
    rz = np.array([[np.cos(y), -np.sin(y), 0], [np.sin(y), np.cos(y), 0], [0, 0, 1]])
    return rz @ ry @ rx


@dataclass(frozen=True, eq=False)
class SimObject:
    """A registered object.

    Attributes:
        name: registry name.
        surface: its analytic surface (object frame: z up, base at z = 0).
        intrinsic_rpy_deg: rotation applied before the scene pose (roll, pitch, yaw) [deg].
        lift_m: height of the object frame above the table when placed [m] (a tilted plane is
            raised so that it does not cut the table).
        rgb: clean colour in [0, 1].
        marking: default dirt pattern (a name of tactex.pointcloud.markings.MARKINGS, or a part's own mask
            function uv → (N,) bool: see tactex.sim.part).
        hfield_spacing_m: height-field grid spacing [m]. Contact cost grows with the number of grid
            cells under the pad, so it is as coarse as the curvature allows: the linear-interpolation
            error h''·s²/8 is 0.07 mm for the sine panel at 1 cm and ≤ 0.1 mm for the others at 5 mm.
        base_thickness_m: solid below z = 0 of the object frame [m].
        position_m: where a scene places the object frame by default, in the robot base frame [m]: where
            a user would put the part for a Franka, its surface to clean well inside the arm's reach.
    """

    name: str
    surface: Surface
    intrinsic_rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    lift_m: float = 0.0
    rgb: tuple[float, float, float] = (0.85, 0.85, 0.82)
    marking: str | Callable[[np.ndarray], np.ndarray] = "X"
    hfield_spacing_m: float = 0.005
    base_thickness_m: float = 0.01
    position_m: tuple[float, float, float] = (0.5, 0.0, 0.0)
    extra: dict = field(default_factory=dict)

    @property
    def kind(self) -> str:
        """'box' (flat), 'hfield' or 'cylinder'."""
        if isinstance(self.surface, CylinderWallSurface):
            return "cylinder"
        if isinstance(self.surface, HeightFieldSurface):
            _, _, z = self.surface.grid(self.hfield_spacing_m)
            return "box" if float(np.ptp(z)) < 1e-9 else "hfield"
        raise ConfigError(f"object '{self.name}': surface type {type(self.surface).__name__} has no simulator geometry")

    def heightfield(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(xs, ys, Z) with Z (ny, nx) [m]; outside a disc domain the height drops to 0 (an edge)."""
        surf = self.surface
        assert isinstance(surf, HeightFieldSurface)
        xs, ys, z = surf.grid(self.hfield_spacing_m)
        gx, gy = np.meshgrid(xs, ys)
        z = np.where(surf.inside(gx, gy), z, 0.0)
        return xs, ys, np.asarray(z, dtype=float)

    def mjcf(self, body_name: str, position: np.ndarray, rotation: np.ndarray) -> tuple[str, str]:
        """(asset XML, worldbody XML) of this object as a mocap body (movable, static in physics)."""
        from tactex.sim.franka import mat_to_quat

        rgba = f"{_fmt(self.rgb)} 1"
        common = f'contype="0" conaffinity="2" group="0" rgba="{rgba}" condim="3"'
        geom_name = f"{body_name}_geom"
        asset = ""
        kind = self.kind
        t = self.base_thickness_m
        if kind == "box":
            surf = self.surface
            assert isinstance(surf, HeightFieldSurface)
            geom = (
                f'<geom name="{geom_name}" type="box" pos="0 0 {-t / 2:.6g}"'
                f' size="{surf.size_x_m / 2:.6g} {surf.size_y_m / 2:.6g} {t / 2:.6g}" {common}/>'
            )
        elif kind == "hfield":
            xs, ys, z = self.heightfield()
            zmin, zmax = float(z.min()), float(z.max())
            # MuJoCo normalises elevation data to [0, 1]; its first row is the +y edge (checked by ray
            # casting in tests/test_sim_objects.py), so rows are given from +y down to −y.
            asset = (
                f'<hfield name="{body_name}_hf" nrow="{len(ys)}" ncol="{len(xs)}"'
                f' size="{xs[-1]:.8g} {ys[-1]:.8g} {zmax - zmin:.8g} {t:.6g}"'
                f' elevation="{_fmt(np.round(z[::-1] - zmin, 9))}"/>'
            )
            geom = f'<geom name="{geom_name}" type="hfield" hfield="{body_name}_hf" pos="0 0 {zmin:.8g}" {common}/>'
        else:
            surf = self.surface
            assert isinstance(surf, CylinderWallSurface)
            geom = (
                f'<geom name="{geom_name}" type="cylinder" pos="0 0 {surf.height_m / 2:.6g}"'
                f' size="{surf.radius_m:.6g} {surf.height_m / 2:.6g}" {common}/>'
            )
        quat = _fmt(mat_to_quat(rotation))
        body = f'<body name="{body_name}" mocap="true" pos="{_fmt(position)}" quat="{quat}">{geom}</body>'
        return asset, body


OBJECTS: dict[str, SimObject] = {}


def register_object(obj: SimObject, *, replace: bool = False) -> SimObject:
    """Add ``obj`` to the registry (``replace=True`` to overwrite an existing name)."""
    if not isinstance(obj, SimObject):
        raise InputError(f"register_object expects a SimObject, got {type(obj).__name__}")
    if obj.name in OBJECTS and not replace:
        raise ConfigError(f"object '{obj.name}' is already registered; pass replace=True to overwrite it")
    obj.kind  # noqa: B018 - validates that the surface has a simulator geometry
    pos = np.asarray(obj.position_m, dtype=float)
    if pos.shape != (3,) or not np.isfinite(pos).all():
        raise ConfigError(f"object '{obj.name}': position_m must be 3 finite numbers [m], got {obj.position_m!r}")
    OBJECTS[obj.name] = obj
    return obj


def object_names() -> list[str]:
    return sorted(OBJECTS)


def resolve_object_name(name: str) -> str:
    """The registered name of object ``name``, in any case ('Plate' → 'plate'); the error lists them (a part's
    file is resolved by :func:`tactex.sim.part.resolve_object_or_part`)."""
    found = {n.lower(): n for n in OBJECTS}.get(str(name).lower())
    if found is None:
        raise ConfigError(f"unknown object '{name}'; registered objects: {', '.join(object_names())}, or a part's "
                          "file (.stl/.obj/.ply/.pcd/.npz)")
    return found


def get_object(name: str) -> SimObject:
    """A registered object by name, in any case; the error lists the valid names."""
    return OBJECTS[resolve_object_name(name)]


def heightfield_object(
    name: str,
    height: Callable[[np.ndarray, np.ndarray], np.ndarray],
    size_x_m: float,
    size_y_m: float,
    *,
    radius_m: float | None = None,
    **kw,
) -> SimObject:
    """A height-field object z = height(x, y) [m] over size_x × size_y [m] (not registered)."""
    for label, v in (("size_x_m", size_x_m), ("size_y_m", size_y_m)):
        if not (np.isfinite(v) and 0 < v <= 5.0):
            raise ConfigError(f"{label} must be in (0, 5] m, got {v}")
    z = np.asarray(height(np.zeros(3), np.zeros(3)), dtype=float)
    if z.shape != (3,) or not np.isfinite(z).all():
        raise InputError(f"height function of '{name}' must be vectorised and finite; got {z!r} for 3 zeros")
    return SimObject(name, HeightFieldSurface(name, size_x_m, size_y_m, height, radius_m=radius_m), **kw)


def heightfield_from_image(
    name: str, image: np.ndarray, size_x_m: float, size_y_m: float, max_height_m: float, **kw
) -> SimObject:
    """A height-field object from a grey image (H, W) (row 0 = +y edge, as images are stored):
    brightness in [0, 1] (or 0..255) maps linearly to [0, max_height_m] [m], bilinearly interpolated."""
    img = np.asarray(image, dtype=float)
    if img.ndim != 2 or min(img.shape) < 2 or not np.isfinite(img).all():
        raise InputError(f"height image must be a finite 2-D array of at least 2×2, got shape {img.shape}")
    if img.max() > 1.0:
        img = img / 255.0
    if not (np.isfinite(max_height_m) and 0 < max_height_m <= 1.0):
        raise ConfigError(f"max_height_m must be in (0, 1] m, got {max_height_m}")
    rows, cols = img.shape
    flipped = img[::-1] * max_height_m  # row 0 → −y
    xs = np.linspace(-size_x_m / 2, size_x_m / 2, cols)
    ys = np.linspace(-size_y_m / 2, size_y_m / 2, rows)

    def height(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return bilinear(xs, ys, flipped, x, y)

    return heightfield_object(name, height, size_x_m, size_y_m, **kw)


def _bumps_height(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    # Two Gaussian bumps, asymmetric in x and y (also used to check the height-field orientation).
    return 0.015 * np.exp(-((x - 0.03) ** 2 + y**2) / 0.04**2) + 0.01 * np.exp(
        -((x + 0.05) ** 2 + (y + 0.04) ** 2) / 0.03**2
    )


def _register_builtins() -> None:
    register_object(SimObject("plane", SURFACES["plane"], lift_m=0.01, marking="blobs"))
    register_object(SimObject("tilted_plane", SURFACES["plane"], intrinsic_rpy_deg=(15.0, 0.0, 0.0), lift_m=0.05,
                              marking="blobs"))
    register_object(SimObject("sine_panel", SURFACES["sine_panel"], rgb=(0.8, 0.8, 0.78), marking="full",
                              hfield_spacing_m=0.01))
    register_object(SimObject("plate", SURFACES["plate"], rgb=(0.95, 0.95, 0.92), marking="shapes"))
    register_object(SimObject("bowl", SURFACES["bowl"], rgb=(0.75, 0.82, 0.9), marking="RLI"))
    # The cup 8 cm nearer than the others: at 0.5 m the far side of its marked wall (pressed back towards the
    # robot's base) is at the edge of the arm's reach, where the wrist sits beyond the cup near j2/j4's limits
    register_object(SimObject("cup", SURFACES["cup"], rgb=(0.9, 0.9, 0.95), marking="X", position_m=(0.42, 0.0, 0.0)))
    register_object(heightfield_object("bumps", _bumps_height, 0.24, 0.24, marking="blobs"))
    # The large parts: a door (0.4 × 0.6 m, long side across the robot so every corner is within reach at
    # the default 0.5 m) and a hull patch; gently curved, so a 1 cm height field interpolates them to < 0.02 mm.
    register_object(SimObject("door", SURFACES["door"], rgb=(0.55, 0.6, 0.7), marking="X", hfield_spacing_m=0.01))
    register_object(SimObject("hull", SURFACES["hull"], rgb=(0.9, 0.88, 0.8), marking="blobs", hfield_spacing_m=0.01))


_register_builtins()
