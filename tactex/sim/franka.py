"""The Franka Emika Panda arm as MJCF, generated from pygafro's kinematic chain.

Kinematics (joint frames, axes, limits) and inertial parameters (mass, centre of mass, inertia
tensor at the centre of mass in link axes) are read from ``pygafro.FrankaEmikaRobot`` — the same
numbers the TEC controller uses (they are the identified parameters of Gaz et al., RA-L 2019, as
shipped in franka_description) — so MuJoCo's forward kinematics, Jacobian and mass matrix agree
with pygafro's (tests/test_sim_franka.py). Visual geometry is a set of capsules (no meshes are
shipped); the arm does not collide (only the tool does), which keeps contact detection cheap.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from tactex.errors import PYGAFRO_FIX, MissingDependencyError

__all__ = [
    "ARM_BODY_PREFIX",
    "FRANKA_HOME_Q",
    "FRANKA_TORQUE_LIMITS",
    "FrankaLink",
    "franka_arm_xml",
    "franka_links",
    "gafro_comparison_xml",
    "gafro_hand_payload",
    "gafro_robot",
    "mat_to_quat",
]

#: Typical home configuration [rad] (tool pointing down, in front of the robot).
FRANKA_HOME_Q = np.array([0.0, -np.pi / 4, 0.0, -3 * np.pi / 4, 0.0, np.pi / 2, np.pi / 4])
#: Franka joint torque limits [N·m] (datasheet).
FRANKA_TORQUE_LIMITS = np.array([87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0])
#: Flange offset along link 7's z axis [m] (panda_joint8).
FLANGE_OFFSET_M = 0.107


@dataclass(frozen=True)
class FrankaLink:
    """One moving link: its joint frame in the parent link and its inertial parameters.

    Attributes:
        name: link name (panda_link1 … panda_link7).
        joint: joint name.
        parent_T_joint: (4, 4) joint frame in the parent link frame (rotation about its z axis).
        lower, upper: joint limits [rad].
        torque_limit: [N·m]; velocity_limit: [rad/s].
        mass: [kg]; com: (3,) centre of mass in the link frame [m];
        inertia: (3, 3) inertia at the centre of mass, link axes [kg·m²].
    """

    name: str
    joint: str
    parent_T_joint: np.ndarray
    lower: float
    upper: float
    torque_limit: float
    velocity_limit: float
    mass: float
    com: np.ndarray
    inertia: np.ndarray


@lru_cache(maxsize=1)
def gafro_robot():
    """The pygafro Franka model (kept alive: its system's links are views into it)."""
    try:
        import pygafro
    except ImportError as exc:  # pragma: no cover - pygafro is a core dependency
        raise MissingDependencyError("pygafro", "", "The Franka model", fix=PYGAFRO_FIX) from exc
    return pygafro.FrankaEmikaRobot()


def _inertia_tensor(link) -> np.ndarray:
    """3×3 inertia from gafro's bivector-valued inertia: row a is the bivector of axis a
    (e23 ↔ x, e13 ↔ −y, e12 ↔ z), so I[a, :] = s_a · (e23, −e13, e12) with s = (+1, −1, +1)."""
    inertia = link.getInertia()
    rows = (inertia.getElement23(), inertia.getElement13(), inertia.getElement12())
    signs = (1.0, -1.0, 1.0)
    out = np.array([[s * mv.get_e23(), -s * mv.get_e13(), s * mv.get_e12()] for s, mv in zip(signs, rows, strict=True)])
    return 0.5 * (out + out.T)


@lru_cache(maxsize=1)
def _links_cached() -> tuple[FrankaLink, ...]:
    system = gafro_robot().getSystem()
    links = []
    for i in range(1, 8):
        joint = system.getJoint(f"panda_joint{i}")
        link = system.getLink(f"panda_link{i}")
        lim = joint.getLimits()
        links.append(
            FrankaLink(
                name=f"panda_link{i}",
                joint=f"panda_joint{i}",
                parent_T_joint=np.array(joint.getFrame().toTransformationMatrix(), dtype=float),
                lower=float(lim.positionLower),
                upper=float(lim.positionUpper),
                torque_limit=float(lim.torque),
                velocity_limit=float(lim.velocity),
                mass=float(link.getMass()),
                com=np.array(link.getCenterOfMass().toTranslationVector(), dtype=float).ravel(),
                inertia=_inertia_tensor(link),
            )
        )
    return tuple(links)


def franka_links() -> tuple[FrankaLink, ...]:
    """The seven moving links of the Franka, read from pygafro."""
    return _links_cached()


def base_link_inertial() -> tuple[float, np.ndarray, np.ndarray]:
    """Mass [kg], centre of mass (3,) [m] and inertia (3, 3) of panda_link0 (fixed base)."""
    link = gafro_robot().getSystem().getLink("panda_link0")
    com = np.array(link.getCenterOfMass().toTranslationVector(), dtype=float).ravel()
    return float(link.getMass()), com, _inertia_tensor(link)


def gafro_hand_payload(include_fingers: bool = True) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """pygafro's gripper as a rigid payload on the flange: mass [kg], centre of mass (3,) [m] and
    inertia at the centre of mass (3, 3) in flange axes, and flange_T_tcp (4, 4) of pygafro's
    end effector (fingers included, at their zero position). Used to compare with pygafro."""
    system = gafro_robot().getSystem()
    hand_joint = np.array(system.getJoint("panda_hand_joint").getFrame().toTransformationMatrix(), dtype=float)
    ee_joint = np.array(system.getJoint("panda_endeffector_joint").getFrame().toTransformationMatrix(), dtype=float)
    parts = []
    hand = system.getLink("panda_hand")
    parts.append((hand_joint, hand))
    fingers = (("panda_finger_joint1", "panda_leftfinger"), ("panda_finger_joint2", "panda_rightfinger"))
    for fj, fl in fingers if include_fingers else ():
        frame = hand_joint @ np.array(system.getJoint(fj).getFrame().toTransformationMatrix())
        parts.append((frame, system.getLink(fl)))
    total = sum(float(link.getMass()) for _, link in parts)
    coms = []
    for frame, link in parts:
        c = np.array(link.getCenterOfMass().toTranslationVector(), dtype=float).ravel()
        coms.append(frame[:3, :3] @ c + frame[:3, 3])
    com = sum(float(link.getMass()) * c for (_, link), c in zip(parts, coms, strict=True)) / total
    inertia = np.zeros((3, 3))
    for (frame, link), c in zip(parts, coms, strict=True):
        r = frame[:3, :3]
        d = c - com
        m = float(link.getMass())
        inertia += r @ _inertia_tensor(link) @ r.T + m * (d @ d * np.eye(3) - np.outer(d, d))
    return total, com, inertia, hand_joint @ ee_joint


def mat_to_quat(rot: np.ndarray) -> np.ndarray:
    """Rotation matrix → unit quaternion (w, x, y, z) (MuJoCo's convention)."""
    import mujoco

    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.asarray(rot, dtype=float).reshape(9))
    return quat


def _fmt(values) -> str:
    return " ".join(f"{float(v):.10g}" for v in np.ravel(values))


def _inertial_xml(mass: float, com: np.ndarray, inertia: np.ndarray) -> str:
    i = inertia
    full = [i[0, 0], i[1, 1], i[2, 2], i[0, 1], i[0, 2], i[1, 2]]
    return f'<inertial pos="{_fmt(com)}" mass="{mass:.10g}" fullinertia="{_fmt(full)}"/>'


#: The arm's bodies' names begin so (panda_link0 … panda_link7); the tool's bodies on the flange do not.
ARM_BODY_PREFIX = "panda_link"

# Capsules approximating the link shapes (link-frame end points [m], radius [m]): drawn, and the arm's shape in
# the transit check (tactex.tasks.transit); they do not collide in the simulation.
_VISUALS: dict[str, list[tuple[tuple[float, ...], float]]] = {
    "panda_link0": [((0.0, 0.0, 0.0, 0.0, 0.0, 0.25), 0.07)],
    "panda_link1": [((0.0, 0.0, -0.19, 0.0, 0.0, 0.0), 0.06)],
    "panda_link2": [((0.0, 0.0, 0.0, 0.0, -0.2, 0.0), 0.06)],
    "panda_link3": [((0.0, 0.0, -0.12, 0.0, 0.0, 0.0), 0.06), ((0.0, 0.0, 0.0, 0.0825, 0.0, 0.0), 0.055)],
    "panda_link4": [((0.0, 0.0, 0.0, -0.0825, 0.1, 0.0), 0.055)],
    "panda_link5": [((0.0, 0.0, -0.25, 0.0, 0.0, 0.0), 0.05), ((0.0, 0.08, -0.08, 0.0, 0.0, 0.0), 0.04)],
    "panda_link6": [((0.0, 0.0, 0.0, 0.088, 0.0, 0.0), 0.045)],
    "panda_link7": [((0.0, 0.0, 0.0, 0.0, 0.0, 0.107), 0.04)],
}


def _visual_xml(link: str) -> str:
    return "".join(
        f'<geom class="arm_visual" type="capsule" fromto="{_fmt(ft)}" size="{r}"/>' for ft, r in _VISUALS.get(link, [])
    )


def franka_arm_xml(
    flange_children: str,
    *,
    base_position: np.ndarray | None = None,
    joint_damping: float = 0.0,
    joint_frictionloss: float = 0.0,
    armature: float = 0.0,
    gravcomp: bool = True,
) -> str:
    """MJCF of the arm (panda_link0 … panda_link7) with ``flange_children`` (MJCF of the bodies
    fixed on the flange: F/T sensor, tool) inserted at the flange frame.

    Args:
        flange_children: MJCF text placed inside a body at the flange (link 7, z + 0.107 m).
        base_position: (3,) robot base in the world [m] (default origin).
        joint_damping: viscous joint damping [N·m·s/rad].
        joint_frictionloss: dry joint friction [N·m].
        armature: reflected rotor inertia added on each joint [kg·m²].
        gravcomp: the firmware's gravity compensation (MuJoCo body ``gravcomp``) for the arm.
    """
    base = np.zeros(3) if base_position is None else np.asarray(base_position, dtype=float)
    gc = ' gravcomp="1"' if gravcomp else ""
    m0, c0, i0 = base_link_inertial()
    head = f'<body name="panda_link0" pos="{_fmt(base)}">{_inertial_xml(m0, c0, i0)}{_visual_xml("panda_link0")}'
    body = ""
    tail = "</body>"
    for link in franka_links():
        t = link.parent_T_joint
        body += (
            f'<body name="{link.name}" pos="{_fmt(t[:3, 3])}" quat="{_fmt(mat_to_quat(t[:3, :3]))}"{gc}>'
            f'<joint name="{link.joint}" type="hinge" axis="0 0 1" range="{link.lower:.10g} {link.upper:.10g}"'
            f' damping="{joint_damping:.10g}" frictionloss="{joint_frictionloss:.10g}" armature="{armature:.10g}"/>'
            f"{_inertial_xml(link.mass, link.com, link.inertia)}{_visual_xml(link.name)}"
        )
        tail = "</body>" + tail
    flange = (
        f'<body name="flange" pos="0 0 {FLANGE_OFFSET_M}"{gc}><site name="flange" size="0.005"/>'
        f"{flange_children}</body>"
    )
    return head + body + flange + tail


def gafro_comparison_xml(*, include_fingers: bool = True) -> str:
    """MJCF of the bare arm carrying pygafro's gripper as a rigid payload, with a site ``ee`` at
    pygafro's end effector: the model whose kinematics and dynamics must equal pygafro's."""
    mass, com, inertia, flange_t_ee = gafro_hand_payload(include_fingers=include_fingers)
    children = (
        f'<body name="hand">{_inertial_xml(mass, com, inertia)}'
        f'<site name="ee" pos="{_fmt(flange_t_ee[:3, 3])}" quat="{_fmt(mat_to_quat(flange_t_ee[:3, :3]))}"/></body>'
    )
    arm = franka_arm_xml(children, gravcomp=False)
    return (
        '<mujoco model="franka_gafro"><compiler angle="radian" autolimits="true"/>'
        '<option timestep="0.001" gravity="0 0 -9.81"/>'
        '<default><default class="arm_visual"><geom contype="0" conaffinity="0" density="0"/></default></default>'
        f"<worldbody>{arm}</worldbody></mujoco>"
    )
