"""franky-sim's world with our scene: the Franka hand swapped for our wrist assembly, our table and
object added, and the wrist F/T sensors; the object's marking as the cloud a perfect scan would give.

Masses: the Franka hand is removed (its finger joints stay, as massless stubs, because franky-sim
drives them), and franky-sim's dynamics model gets no end effector (as a real arm configured with
"no end effector" in Desk: ``F_T_NE`` = identity, ``m_ee`` ≈ 0), so the arm holds still under zero
torque once the client declares the tool with ``set_load`` (the wrist assembly's mass, centre of
mass as :meth:`ToolGeometry.calibrated_mass_properties`); without it the tool's weight sags it.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

from tactex.errors import SimulationError
from tactex.sim.scene import SceneConfig
from tactex.sim.tool import tool_xml
from tactex.twin.config import TwinConfig

__all__ = ["ROBOT_PREFIX", "STUB_MASS_KG", "STUB_Z_M", "add_scene", "export_marking_cloud"]

ROBOT_PREFIX = "robot0_"  # franky-sim's name prefix of the first robot
STUB_MASS_KG = 1e-5  # each finger stub (franky-sim drives the finger joints; they must exist)
STUB_Z_M = 0.0584  # finger joint position below the flange [m]
_TOOL_CLASS = "tactex_tool"  # default class of the wrist assembly (not franky-sim's "fr3")


def export_marking_cloud(config: TwinConfig, path: str | Path, spacing_m: float = 0.003) -> Path:
    """Write the object's surface with its marking as a PLY in the robot base frame [m]: points at
    ``spacing_m``, normals, red (255, 0, 0) and ``target`` = 1 on the marking, as the TEC clouds.
    This is the cloud ``tactex clean --cloud FILE`` would get from a perfect scan of the twin."""
    from tactex.pointcloud.io import save_ply
    from tactex.pointcloud.markings import marked_cloud

    scene = config.scene_config()
    obj = scene.sim_object
    pos, rot = scene.object_pose()
    cloud = marked_cloud(obj.surface, scene.marking or obj.marking, spacing_m).transformed(rot, pos)
    return save_ply(cloud, path)


def _find_body(root: ET.Element, name: str) -> ET.Element:
    for body in root.iter("body"):
        if body.get("name") == name:
            return body
    raise SimulationError(f"franky-sim's scene has no body '{name}': this franky-sim version is not supported")


def _replace_hand(root: ET.Element, scene: SceneConfig) -> None:
    """Swap franky-sim's Franka hand for our wrist assembly on the flange (link7 + 0.107 m)."""
    link7 = _find_body(root, f"{ROBOT_PREFIX}fr3_link7")
    hand = _find_body(root, f"{ROBOT_PREFIX}hand")
    link7.remove(hand)
    # childclass: franky-sim's arm bodies carry childclass "fr3", whose joint defaults (the reflected
    # rotor inertia and gear friction of a Franka joint) the sponge's slide joint would otherwise inherit:
    # a pad ten times heavier than the sponge, held by dry friction, hops on the surface once the arm
    # stiffens. The tool takes MuJoCo's plain defaults, as in tactex's own scene; the finger stubs keep
    # their explicit class "finger".
    flange = ET.SubElement(link7, "body", name="flange", pos=hand.get("pos", "0 0 0.107"), childclass=_TOOL_CLASS)
    ET.SubElement(flange, "site", name="flange", size="0.004")
    flange.append(ET.fromstring(tool_xml(scene.tool, scene.intrinsics.fovy_deg, gravcomp=False)))
    # franky-sim drives the two finger joints (and its gripper server reads them): keep them as
    # massless stubs without geometry, turned like the hand
    stub = ET.SubElement(flange, "body", name=f"{ROBOT_PREFIX}hand", quat=hand.get("quat", "1 0 0 0"))
    for finger in hand.findall("body"):
        for child in list(finger):
            if child.tag in ("geom", "inertial"):
                finger.remove(child)
        ET.SubElement(finger, "inertial", pos="0 0 0", mass=f"{STUB_MASS_KG:g}", diaginertia="1e-9 1e-9 1e-9")
        stub.append(finger)


def add_scene(sim: Any, scene: SceneConfig) -> None:
    """Add our scene to franky-sim's MJCF before it compiles: the wrist assembly in place of the hand,
    the table, the object and the F/T sensors (``ft_force``, ``ft_torque`` at ``ft_site``)."""
    root = sim.scene
    default = root.find("default")
    if default is None:
        default = ET.SubElement(root, "default")
    tool_visual = ET.SubElement(default, "default", {"class": "tool_visual"})
    ET.SubElement(tool_visual, "geom", contype="0", conaffinity="0", group="2", density="0")
    tool_class = ET.SubElement(default, "default", {"class": _TOOL_CLASS})  # MuJoCo's defaults, see _replace_hand
    ET.SubElement(tool_class, "joint", armature="0", frictionloss="0", damping="0")
    option = root.find("option")
    if option is None:
        option = ET.SubElement(root, "option")
    option.set("cone", "elliptic")  # as our own scene: the pad's friction cone
    _replace_hand(root, scene)
    pos, rot = scene.object_pose()
    asset_xml, body_xml = scene.sim_object.mjcf("object", pos, rot)
    if asset_xml:
        asset = root.find("asset")
        if asset is None:
            asset = ET.SubElement(root, "asset")
        asset.append(ET.fromstring(asset_xml))
    world = sim.worldbody
    ET.SubElement(world, "geom", name="table", type="box", pos="0.4 0 -0.02", size="0.8 0.8 0.02",
                  rgba="0.4 0.35 0.3 1", contype="0", conaffinity="2", group="0")
    world.append(ET.fromstring(body_xml))
    sensor = ET.SubElement(root, "sensor")
    ET.SubElement(sensor, "force", name="ft_force", site="ft_site")
    ET.SubElement(sensor, "torque", name="ft_torque", site="ft_site")
