"""The wrist assembly on the flange: 6-axis F/T sensor, tool body with the RGB-D camera, and a
compliant wiping pad (sponge) whose tip is the tool centre point (TCP).

Compliance is physical: the pad is a light body on a slide joint along the tool axis with a
spring of ``stiffness`` [N/m] and a damper. (MuJoCo soft contacts are acceleration-based, so their
force per metre depends on the effective mass at the contact and on how many contact points a
height field produces; a spring in series with a stiffer contact gives the configured N/m whatever
the contact count.) The pad geom has contact priority, so its solref/solimp and friction govern
every pad contact. Its impedance is 0.7, not ~1: with a near-hard contact, a sliding light pad
chatters (MuJoCo's elliptic friction cone pushes a sliding contact apart, the pad leaves the
surface for one tick and the preloaded spring slams it back), which a 0.7 impedance damps out.
The contact then adds ~5 % compliance on a flat contact: 15 N compress the 10 kN/m sponge by
1.50 mm and the contact by ~0.08 mm (effective ≈ 9.5 kN/m).

Frames: the tool frame is the flange frame turned by −45° about z (like the Franka hand), so at
the home pose tool x = world x and tool z points down; the sensor frame has the tool's axes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tactex.sim.franka import _fmt, mat_to_quat

__all__ = ["TOOL_SITE_NAMES", "ToolGeometry", "flange_R_tool", "tool_xml"]

#: Names of the MJCF elements the backend looks up.
TOOL_SITE_NAMES = {
    "ft_site": "ft_site",
    "tcp": "tcp",
    "tool_body": "ft_sensor",
    "pad_body": "pad",
    "pad_geom": "pad",
    "pad_joint": "pad_slide",
    "camera": "wrist_camera",
    "payload_body": "payload",
}


def flange_R_tool() -> np.ndarray:
    """Rotation of the tool (and sensor) frame in the flange frame: −45° about z."""
    c, s = np.cos(-np.pi / 4), np.sin(-np.pi / 4)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class ToolGeometry:
    """Dimensions and masses of the wrist assembly (TEC: Bota SensONE + 3-D printed part with a
    RealSense and a sponge; values are typical, not measured).

    Attributes:
        sensor_height_m: F/T sensor thickness [m]; sensor_mass_kg [kg].
        body_length_m: adapter between sensor and pad [m]; body_mass_kg (adapter + camera) [kg].
        pad_thickness_m, pad_radius_m: sponge size [m]; pad_mass_kg [kg].
        pad_shape: "cylinder" (flat sponge) or "sphere" (rounded tip of radius pad_radius_m).
        stiffness_n_per_m: sponge stiffness along the tool axis [N/m].
        damping_ratio: sponge damping as a fraction of critical damping [-].
        max_compression_m: travel before the pad bottoms out on the holder [m].
        friction: Coulomb friction coefficient pad–surface [-].
        camera_offset_m: camera position in the tool frame, measured from the flange [m].
        payload_mass_kg: an extra mass hung at the TCP that the F/T calibration does not know [kg].
    """

    sensor_height_m: float = 0.025
    sensor_mass_kg: float = 0.1
    body_length_m: float = 0.105
    body_mass_kg: float = 0.3
    pad_thickness_m: float = 0.03
    pad_radius_m: float = 0.025
    pad_mass_kg: float = 0.02
    pad_shape: str = "cylinder"
    stiffness_n_per_m: float = 10000.0
    damping_ratio: float = 0.7
    max_compression_m: float = 0.015
    friction: float = 0.4
    camera_offset_m: tuple[float, float, float] = (-0.07, 0.0, 0.04)
    payload_mass_kg: float = 0.0

    @property
    def tcp_offset_m(self) -> float:
        """Distance flange → TCP (uncompressed pad tip) along the tool axis [m]."""
        return self.sensor_height_m + self.body_length_m + self.pad_thickness_m

    @property
    def pad_damping(self) -> float:
        """Sponge damper [N·s/m]."""
        return 2.0 * self.damping_ratio * float(np.sqrt(self.stiffness_n_per_m * self.pad_mass_kg))

    def calibrated_mass_properties(self) -> tuple[float, np.ndarray]:
        """Mass [kg] and centre of mass in the sensor frame [m] of everything below the sensor's
        measuring plane that the calibration compensates (tool body + pad, not the payload)."""
        # The sensor's own mass sits above its measuring plane (at the flange side) in practice, but
        # here the whole sensor body is below the site, so it is part of the compensated load.
        parts = [
            (self.sensor_mass_kg, np.array([0.0, 0.0, self.sensor_height_m / 2])),
            (self.body_mass_kg, np.array([0.0, 0.0, self.sensor_height_m + self.body_length_m / 2])),
            (self.pad_mass_kg, np.array([0.0, 0.0, self.tcp_offset_m - self.pad_thickness_m / 2])),
        ]
        mass = sum(m for m, _ in parts)
        com = sum(m * c for m, c in parts) / mass
        return mass, com


def _cylinder_inertia(mass: float, radius: float, length: float) -> np.ndarray:
    ixx = mass * (3 * radius**2 + length**2) / 12
    return np.array([ixx, ixx, mass * radius**2 / 2])


def tool_xml(geom: ToolGeometry, camera_fovy_deg: float, *, gravcomp: bool = True) -> str:
    """MJCF of the wrist assembly, to be placed inside the flange body."""
    gc = ' gravcomp="1"' if gravcomp else ""
    quat = _fmt(mat_to_quat(flange_R_tool()))
    sh, bl, pt, pr = geom.sensor_height_m, geom.body_length_m, geom.pad_thickness_m, geom.pad_radius_m
    si = _cylinder_inertia(geom.sensor_mass_kg, 0.04, sh)
    bi = _cylinder_inertia(geom.body_mass_kg, 0.035, bl)
    pi = _cylinder_inertia(geom.pad_mass_kg, pr, pt)
    cx, cy, cz = geom.camera_offset_m
    # MuJoCo cameras look along their −z with y up; the camera looks along the tool z axis.
    cam_quat = _fmt(mat_to_quat(np.diag([1.0, -1.0, -1.0])))
    pad_center = sh + bl + pt / 2
    if geom.pad_shape == "cylinder":
        pad_geom = f'type="cylinder" size="{pr:.6g} {pt / 2:.6g}"'
    elif geom.pad_shape == "sphere":
        pad_geom = f'type="sphere" size="{pr:.6g}" pos="0 0 {pt / 2 - pr:.6g}"'
    else:  # validated by SceneConfig
        raise ValueError(geom.pad_shape)
    payload = ""
    if geom.payload_mass_kg > 0:
        payload = (
            f'<body name="payload" pos="0 0 {geom.tcp_offset_m + 0.02:.6g}"{gc}>'
            f'<inertial pos="0 0 0" mass="{geom.payload_mass_kg:.6g}" diaginertia="1e-5 1e-5 1e-5"/>'
            f'<geom class="tool_visual" type="sphere" size="0.015" rgba="0.2 0.2 0.2 1"/></body>'
        )
    return (
        f'<body name="ft_sensor" quat="{quat}"{gc}>'
        f'<inertial pos="0 0 {sh / 2:.6g}" mass="{geom.sensor_mass_kg:.6g}" diaginertia="{_fmt(si)}"/>'
        f'<site name="ft_site" size="0.006" rgba="1 1 0 1"/>'
        f'<geom class="tool_visual" type="cylinder" pos="0 0 {sh / 2:.6g}" size="0.04 {sh / 2:.6g}"'
        ' rgba="0.6 0.6 0.65 1"/>'
        f'<body name="tool_body" pos="0 0 {sh:.6g}"{gc}>'
        f'<inertial pos="0 0 {bl / 2:.6g}" mass="{geom.body_mass_kg:.6g}" diaginertia="{_fmt(bi)}"/>'
        f'<geom class="tool_visual" type="cylinder" pos="0 0 {bl / 2:.6g}" size="0.02 {bl / 2:.6g}"'
        ' rgba="0.9 0.9 0.9 1"/>'
        f'<geom class="tool_visual" type="box" pos="{cx:.6g} {cy:.6g} {cz - sh:.6g}" size="0.0125 0.045 0.0125"'
        ' rgba="0.15 0.15 0.15 1"/>'
        f'</body>'
        f'<camera name="wrist_camera" pos="{cx:.6g} {cy:.6g} {cz:.6g}" quat="{cam_quat}" fovy="{camera_fovy_deg:.8g}"/>'
        f'<site name="tcp" pos="0 0 {geom.tcp_offset_m:.6g}" size="0.004" rgba="1 0 0 1"/>'
        f'<body name="pad" pos="0 0 {pad_center:.6g}"{gc}>'
        f'<joint name="pad_slide" type="slide" axis="0 0 1" range="{-geom.max_compression_m:.6g} 0.002"'
        f' stiffness="{geom.stiffness_n_per_m:.8g}" damping="{geom.pad_damping:.8g}"/>'
        f'<inertial pos="0 0 0" mass="{geom.pad_mass_kg:.6g}" diaginertia="{_fmt(pi)}"/>'
        f'<geom name="pad" {pad_geom} friction="{geom.friction:.6g} 0.005 0.0001" contype="2" conaffinity="0"'
        f' condim="3" priority="1" solref="0.002 1" solimp="0.7 0.7 0.001" group="1" rgba="0.95 0.8 0.2 1"/>'
        f"</body>{payload}</body>"
    )
