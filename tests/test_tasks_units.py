"""Unit tests of the task layer: frames, paths, target re-measurement, policy, null space, recorder."""

from __future__ import annotations

import io

import numpy as np
import pytest

from tactex.control.joint_impedance import JointImpedanceParams, JointTarget, min_jerk
from tactex.control.nullspace import NullspaceParams, nullspace_projector
from tactex.errors import ConfigError, InputError, SimulationError
from tactex.pointcloud.cloud import SurfaceCloud
from tactex.pointcloud.markings import marked_cloud
from tactex.pointcloud.shapes import get_surface
from tactex.tasks.clean import CleanConfig
from tactex.tasks.progress import Progress
from tactex.tasks.raster import RasterPath, boustrophedon
from tactex.tasks.recorder import Recorder
from tactex.tasks.runner import tool_rotation_for_normal
from tactex.tasks.vision import remeasure_target
from tactex.tasks.wipe import WipeConfig, wiping_policy

TOL = 1e-9


class _StillBackend:
    """A backend that never moves, with the protocol's required methods only (no optional ``pause``)."""

    dt = 1e-3

    def __init__(self) -> None:
        from tests.test_control_common import make_state

        self._state = make_state(q=np.array([0.0, 0.0, 0.0, -1.5, 0.0, 1.8, 0.0]))

    def reset(self, seed=None):
        return self._state

    def state(self):
        return self._state

    def apply_torque(self, tau) -> None:
        assert np.isfinite(tau).all()

    def step(self):
        return self._state

    def camera_frame(self):
        return None

    def close(self) -> None:
        pass


@pytest.mark.parametrize("normal", [[0, 0, 1], [0, 1, 0], [1, 0, 0], [0.3, -0.2, 0.9]])
def test_tool_rotation_presses_along_minus_normal(normal) -> None:
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    rot = tool_rotation_for_normal(n)
    np.testing.assert_allclose(rot.T @ rot, np.eye(3), atol=TOL)
    assert np.linalg.det(rot) == pytest.approx(1.0)
    np.testing.assert_allclose(rot[:, 2], -n, atol=TOL)


def test_min_jerk_profile_endpoints_and_symmetry() -> None:
    assert min_jerk(0.0) == (0.0, 0.0)
    assert min_jerk(1.0) == (1.0, 0.0)
    assert min_jerk(0.5)[0] == pytest.approx(0.5)
    target = JointTarget(np.zeros(7), np.ones(7), t_start=1.0, duration_s=2.0)
    q, dq = target.at(3.5)
    np.testing.assert_allclose(q, 1.0)
    np.testing.assert_allclose(dq, 0.0)
    # velocity is the derivative of position (central differences)
    h = 1e-6
    fd = (target.at(1.7 + h)[0] - target.at(1.7 - h)[0]) / (2 * h)
    np.testing.assert_allclose(target.at(1.7)[1], fd, rtol=1e-6)


def test_gain_validation() -> None:
    with pytest.raises(ConfigError, match="≥ 0"):
        JointImpedanceParams(stiffness=(-1.0,) * 7)
    with pytest.raises(ConfigError, match="null-space"):
        NullspaceParams(stiffness=float("nan"))


def test_nullspace_torque_makes_no_task_wrench(rng) -> None:
    jac = rng.normal(size=(6, 7))
    n = nullspace_projector(jac, damping=1e-9)
    tau = rng.normal(size=7)
    # the wrench a torque produces at the task is f = (J Jᵀ)⁻¹ J τ; the projected torque makes none
    f = np.linalg.solve(jac @ jac.T, jac @ (n @ tau))
    np.testing.assert_allclose(f, 0.0, atol=1e-6)


def test_wiping_policy_matches_paper_and_its_derivative() -> None:
    x, _ = wiping_policy(0.0)
    np.testing.assert_allclose(x, 0.0, atol=TOL)
    t = 1.3
    x, v = wiping_policy(t)
    np.testing.assert_allclose(x, [0.04 * np.sin(2 * t), 0.04 * (np.cos(2 * t) - 1) - 0.005 * t, 0.0])
    h = 1e-6
    fd = (wiping_policy(t + h)[0] - wiping_policy(t - h)[0]) / (2 * h)
    np.testing.assert_allclose(v, fd, rtol=1e-6, atol=1e-9)


def test_raster_covers_the_cloud_and_keeps_its_speed() -> None:
    cloud = marked_cloud(get_surface("plate"), "X", 0.004)
    path = RasterPath(cloud, lane_spacing_m=0.03, max_step_m=0.004)
    path.reset()
    pts = [path.waypoints[0]]
    while not path.done:
        cmd = path.step()
        pts.append(cmd.point)
    steps = np.linalg.norm(np.diff(np.asarray(pts), axis=0), axis=1)
    assert steps.max() <= 0.004 + 1e-12
    # every cloud point lies within one lane spacing of the path
    from scipy.spatial import cKDTree

    dist, _ = cKDTree(np.asarray(pts)).query(cloud.points)
    assert dist.max() <= 0.03
    with pytest.raises(ConfigError):
        boustrophedon(cloud, 0.0, 0.004)


def test_remeasure_maps_new_dirt_onto_old_points() -> None:
    cloud = marked_cloud(get_surface("plane"), "full", 0.01)
    capture = SurfaceCloud(points=cloud.points + 0.001, target=np.where(cloud.points[:, 0] > 0, 1.0, 0.0))
    mass = remeasure_target(cloud, capture)
    np.testing.assert_array_equal(mass, (cloud.points[:, 0] > 0).astype(float))
    # points the new view does not see keep their old target
    far = SurfaceCloud(points=cloud.points[:5] + 1.0, target=np.zeros(5))
    np.testing.assert_array_equal(remeasure_target(cloud, far), cloud.target)


def test_recorder_and_progress() -> None:
    rec = Recorder(every=3)
    for i in range(10):
        rec.add(t=float(i), v=np.array([i, 2 * i]))
    arrays = rec.arrays()
    np.testing.assert_array_equal(arrays["t"], [0, 3, 6, 9])
    assert arrays["v"].shape == (4, 2)
    out = io.StringIO()
    bar = Progress(10.0, "unit", stream=out)
    for i in range(11):
        bar.update(float(i), x=1.0)
    bar.note("compiling")
    bar.close("done")
    text = out.getvalue()
    assert "100%" in text and "unit: done" in text and "unit: compiling\n" in text
    quiet = io.StringIO()
    Progress(10.0, "unit", stream=quiet, enabled=False).note("compiling")
    assert quiet.getvalue() == ""


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"object_name": "teapot"}, "plate"),
        ({"force_n": -1.0}, "force_n"),
        ({"baseline": "zigzag"}, "raster"),
        ({"stop_remaining": 1.5}, "stop_remaining"),
        ({"approach_force_n": 50.0}, "approach_force_n"),
        ({"keep_out_mask": "zone.npy"}, "give --cloud too"),
        ({"keep_out_channel": "purple"}, "--keep-out-channel"),
        ({"keep_out_channel": "blue", "keep_out_threshold": 1.5}, "--keep-out-threshold"),
        ({"keep_out_channel": "blue", "baseline": "raster"}, "raster baseline has no keep-out"),
        ({"approach_speed_m_s": -0.1}, "approach_speed_m_s"),
        ({"approach_slow_m": float("nan")}, "approach_slow_m"),
        ({"joint_speed_rad_s": 0.0}, "joint_speed_rad_s"),
        ({"joint_speed_rad_s": 2.5}, "over the Franka's 2.175 rad/s"),
        ({"pad_radius_m": 25.0}, "pad_radius_m = 25.0 m is over 0.2 m: it is in metres .the default 0.025 m is 25 mm"),
        ({"hover_height_m": 30.0}, "hover_height_m = 30.0 m is over 0.3 m: it is in metres"),
        ({"approach_slow_m": 10.0}, "approach_slow_m = 10.0 m is over 0.1 m"),
        ({"capture_distance_m": 450.0}, "capture_distance_m = 450.0 m is over 1 m"),
    ],
)
def test_clean_config_validation(kwargs, match) -> None:
    with pytest.raises(ConfigError, match=match):
        CleanConfig(**kwargs)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [({"force_n": 0.0}, "force_n"), ({"baseline": "pid"}, "cartesian"), ({"drift_m_s": float("nan")}, "drift"),
     # the §III sinusoid has the limits of a policy file: speed, acceleration, reach
     ({"omega_rad_s": 100.0}, "slides at up to 4.005 m/s .amplitude·ω \\+ drift., over --policy-max-speed-m-s 0.15"),
     ({"amplitude_m": 40.0}, "metres and m/s: 0.04 is 40 mm"),
     ({"amplitude_m": 0.01, "omega_rad_s": 12.0}, "accelerates at 1.44 m/s² .amplitude·ω²., over --policy-max-accel"),
     ({"object_name": "bowl"}, "leaves the bowl's surface .* from --start-y-m 0.08 .*start at --start-y-m -0.09"),
     ({"object_name": "cup"}, "leaves the cup's wall .*; make it smaller or shorten the run .--duration-s.$"),
     ({"duration_s": 200.0}, "leaves the sine_panel's surface at t = 20"),
     ],
)
def test_wipe_config_validation(kwargs, match) -> None:
    with pytest.raises(ConfigError, match=match):
        WipeConfig(**kwargs)


def test_raster_needs_normals() -> None:
    with pytest.raises(InputError, match="normals"):
        RasterPath(SurfaceCloud(points=np.random.default_rng(0).uniform(0, 0.1, (50, 3))), 0.02, 0.003)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"q_goal": np.full(7, np.nan)}, "finite q_start"),
        ({"q_goal": np.zeros(6)}, "one shape"),
        ({"duration_s": float("nan")}, "duration_s"),
        ({"duration_s": -1.0}, "duration_s"),
    ],
)
def test_joint_target_validation(kwargs, match) -> None:
    args = {"q_start": np.zeros(7), "q_goal": np.ones(7), "t_start": 0.0, "duration_s": 1.0, **kwargs}
    with pytest.raises(InputError, match=match):
        JointTarget(**args)


def test_nullspace_posture_validation() -> None:
    from tactex.control.controller import Controller
    from tactex.control.nullspace import NullspacePosture
    from tactex.errors import ControllerFault
    from tests.test_control_common import make_state

    class Zero(Controller):
        def torque(self, state, reference):
            return np.zeros(7)

    with pytest.raises(InputError, match="q_posture"):
        NullspacePosture(Zero(), q_posture=np.full(7, np.nan))
    with pytest.raises(ControllerFault, match="joints"):
        NullspacePosture(Zero(), q_posture=np.zeros(3)).torque(make_state(), None)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"force_ramp_s": 0.0}, "force_ramp_s"),
        ({"contact_threshold_n": float("nan")}, "contact_threshold_n"),
        ({"seed": -1}, "seed"),
        ({"n_eigen": 0}, "and 0"),
        ({"max_normal_rate_deg_s": 0.0}, "max_normal_rate_deg_s"),
        ({"max_normal_rate_deg_s": 2000.0}, "90° or more"),
        ({"objective": "coverage"}, "clean, ergodic"),
        ({"wear_margin": 0.0}, "wear_margin"),
        ({"preston_coefficient": float("nan")}, "preston_coefficient"),
        ({"pad_radius_m": -0.01}, "pad_radius_m"),
        ({"cooling": -0.1}, "cooling"),
        ({"model_update_steps": 0}, "model_update_steps"),
        ({"model_stall_steps": 0}, "model_stall_steps"),
        ({"vision_max_steps": 0}, "vision_max_steps"),
        ({"side_capture_elevation_deg": -5.0}, "side_capture_elevation_deg"),
        ({"side_capture_elevation_deg": 80.0}, "0–75 deg"),
        ({"side_capture_elevation_deg": float("nan")}, "side_capture_elevation_deg"),
    ],
)
def test_clean_config_validation_more(kwargs, match) -> None:
    with pytest.raises(ConfigError, match=match):
        CleanConfig(**kwargs)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"start_y_m": float("nan")}, "start_y_m"),
        ({"start_tilt_deg": 80.0}, "start_tilt_deg"),
        ({"contact_threshold_n": -5.0}, "contact_threshold_n"),
        ({"amplitude_m": -0.01}, "amplitude_m"),
        ({"omega_rad_s": float("inf")}, "omega_rad_s"),
        ({"start_height_m": -0.01}, "start_height_m"),
        ({"seed": -1}, "seed"),
    ],
)
def test_wipe_config_validation_more(kwargs, match) -> None:
    with pytest.raises(ConfigError, match=match):
        WipeConfig(**kwargs)


def test_seed_must_be_non_negative_everywhere() -> None:
    from tactex.ergodic import HedacConfig
    from tactex.experiments.explore import ExploreConfig
    from tactex.sim.scene import SceneConfig

    for cls in (HedacConfig, ExploreConfig, SceneConfig):
        with pytest.raises(ConfigError, match="seed"):
            cls(seed=-1)


def test_remeasure_rejects_bad_distance() -> None:
    cloud = marked_cloud(get_surface("plane"), "full", 0.01)
    for bad in (float("nan"), -0.01, 0.0):
        with pytest.raises(InputError, match="max_distance_m"):
            remeasure_target(cloud, cloud, max_distance_m=bad)


@pytest.mark.parametrize("config_cls", [CleanConfig, WipeConfig])
@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"tool_stiffness_n_per_m": 0.0}, "tool_stiffness_n_per_m"),
        ({"tool_friction": -0.1}, "tool_friction"),
        ({"tool_friction": float("nan")}, "tool_friction"),
        ({"record_hz": 0.0}, "record_hz"),
        ({"seed": 1.5}, "seed"),
        ({"object_name": "teapot"}, "sine_panel"),
    ],
)
def test_task_world_fields_are_checked_at_the_config(config_cls, kwargs, match) -> None:
    """The world fields both tasks share (tactex.tasks.world) are checked when the task config is
    made, not when the scene is built minutes later."""
    with pytest.raises(ConfigError, match=match):
        config_cls(**kwargs)


def test_task_scene_carries_the_shared_and_the_task_fields() -> None:
    clean = CleanConfig(object_name="bowl", marking="RLI", tool_friction=0.3, seed=4, camera_width=64,
                        camera_height=48)
    scene = clean.scene()
    assert (scene.object_name, scene.marking, scene.tool_friction, scene.seed) == ("bowl", "RLI", 0.3, 4)
    assert (scene.camera_width, scene.camera_height, scene.tool_stiffness_n_per_m) == (64, 48, 2500.0)
    wipe = WipeConfig(camera_rate_hz=15.0, tool_pad_shape="cylinder", object_position=(0.4, 0.1, 0.0))
    scene = wipe.scene()
    assert (scene.object_name, scene.camera_rate_hz, scene.tool_pad_shape) == ("sine_panel", 15.0, "cylinder")
    assert scene.object_position == (0.4, 0.1, 0.0) and (scene.camera_width, scene.camera_height) == (160, 120)
    assert CleanConfig().object_name == "plate" and CleanConfig().camera_width == 320


def test_rotate_towards_turns_by_at_most_the_step_on_the_great_circle(rng) -> None:
    from tactex.geometry.so3 import rotate_towards

    for _ in range(50):
        a, b = rng.normal(size=3), rng.normal(size=3)
        a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
        full = np.arccos(np.clip(a @ b, -1.0, 1.0))
        step = rng.uniform(0.0, 1.5)
        out = rotate_towards(a, b, step)
        assert abs(np.linalg.norm(out) - 1.0) < 1e-12
        if step >= full:
            np.testing.assert_allclose(out, b, atol=1e-15)  # b, renormalised
        else:
            assert np.arccos(np.clip(out @ a, -1.0, 1.0)) == pytest.approx(step, abs=1e-9)
            assert np.arccos(np.clip(out @ b, -1.0, 1.0)) == pytest.approx(full - step, abs=1e-9)
            assert abs(np.cross(a, b) @ out) < 1e-9  # in the plane of a and b
    up = np.array([0.0, 0.0, 1.0])
    out = rotate_towards(up, -up, 0.1)  # antiparallel: some great circle, still exactly 0.1 rad
    assert np.arccos(out @ up) == pytest.approx(0.1, abs=1e-12)
    np.testing.assert_allclose(rotate_towards(2.0 * up, 3.0 * up, 0.0), up)  # lengths do not matter


@pytest.mark.parametrize(
    "args",
    [
        (np.zeros(3), np.array([0.0, 0.0, 1.0]), 0.1),
        (np.array([np.nan, 0.0, 1.0]), np.array([0.0, 0.0, 1.0]), 0.1),
        (np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0]), -0.1),
        (np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0]), float("inf")),
    ],
)
def test_rotate_towards_refuses_bad_input(args) -> None:
    from tactex.errors import InputError
    from tactex.geometry.so3 import rotate_towards

    with pytest.raises(InputError, match="rotate_towards"):
        rotate_towards(*args)


def test_retract_lifts_straight_back_along_the_tool_axis() -> None:
    """A 5 cm lift-off moves the TCP 5 cm along −tool z (within 4 mm: one linear step), keeps the tool orientation
    (within 1°), and moves no joint more than the lift needs (a full IK solve preferring home
    postures swung the elbow and dragged the tool across a bowl)."""
    from tactex.robots import MujocoBackend
    from tactex.robots.loop import ControlLoop
    from tactex.sim import SceneConfig

    loop = ControlLoop(MujocoBackend(SceneConfig(object_name="plane")))
    loop.hold(0.05)
    start = loop.state
    p0, r0, q0 = start.ee_position.copy(), start.ee_rotation.copy(), start.q.copy()
    loop.retract(0.05, duration_s=0.4)
    loop.hold(0.3)
    end = loop.state
    np.testing.assert_allclose(end.ee_position - p0, -0.05 * r0[:, 2], atol=4e-3)
    angle = np.arccos(np.clip((np.trace(r0.T @ end.ee_rotation) - 1.0) / 2.0, -1.0, 1.0))
    assert np.degrees(angle) < 1.0
    assert np.max(np.abs(end.q - q0)) < 0.3


def test_retract_near_a_singular_posture_keeps_the_joint_limits_and_speed() -> None:
    """A stretched arm (smallest singular value ~0.05): the least-squares step grows, but the goal
    stays short of the joint-limit band and the move is slowed so that no joint exceeds the
    planner's 0.8 rad/s mean speed."""
    from tactex.control.safety import FRANKA_Q_MAX, FRANKA_Q_MIN
    from tactex.robots import MujocoBackend
    from tactex.robots.loop import ControlLoop
    from tactex.sim import SceneConfig

    loop = ControlLoop(MujocoBackend(SceneConfig(object_name="plane")))
    loop.move_joints(np.array([0.0, 0.2, 0.0, -0.08, 0.0, 0.3, 0.785]), duration_s=1.5, settle_s=0.5)
    q0 = loop.state.q.copy()
    t0 = loop.t
    loop.retract(0.05, duration_s=0.4)
    q1 = loop.state.q
    margin = loop.safety.limits.joint_limit_margin
    assert np.all(q1 >= np.minimum(np.asarray(FRANKA_Q_MIN) + margin, q0) - 0.02)
    assert np.all(q1 <= np.maximum(np.asarray(FRANKA_Q_MAX) - margin, q0) + 0.02)
    assert loop.t - t0 >= 1.875 * np.max(np.abs(q1 - q0)) / 0.8 - 0.05



def test_control_loop_resets_a_controller_once_then_resumes_it() -> None:
    """Switching back to a controller must not refill its energy tanks: the loop resets a controller
    the first time it is used and resumes it afterwards."""
    from tactex.control import VaUficController
    from tactex.robots.loop import ControlLoop

    loop = ControlLoop(_StillBackend())
    ctrl = VaUficController()
    loop.use(ctrl)
    assert ctrl.tank_i.energy == pytest.approx(24.5)
    ctrl.tank_i.energy = 3.0  # as if spent in contact
    loop.use(loop.joint)
    loop.use(ctrl)
    assert ctrl.tank_i.energy == 3.0
    fresh = VaUficController()
    fresh.tank_i.energy = 3.0
    loop.use(fresh)  # a controller new to this loop starts from its initial state
    assert fresh.tank_i.energy == pytest.approx(24.5)


def test_move_cartesian_keeps_the_tool_on_the_line() -> None:
    """A transit through IK waypoints stays within a few mm of the straight line between the poses
    (a single joint move between far postures dipped a cleaning tool 7 cm back into a bowl)."""
    from tactex.robots import MujocoBackend
    from tactex.robots.loop import ControlLoop
    from tactex.sim import SceneConfig

    loop = ControlLoop(MujocoBackend(SceneConfig(object_name="plane")))
    loop.hold(0.05)
    p0, r0 = loop.state.ee_position.copy(), loop.state.ee_rotation.copy()
    goal = p0 + np.array([-0.1, 0.15, 0.1])
    deviation = []

    def watch(state, reference, controller) -> None:
        rel = state.ee_position - p0
        axis = (goal - p0) / np.linalg.norm(goal - p0)
        deviation.append(float(np.linalg.norm(rel - (rel @ axis) * axis)))

    loop.on_tick = watch
    loop.move_cartesian(goal, r0, settle_s=0.5)
    assert np.linalg.norm(loop.state.ee_position - goal) < 3e-3
    assert max(deviation) < 0.01


def test_retract_along_a_world_direction_and_its_check() -> None:
    from tactex.robots import MujocoBackend
    from tactex.robots.loop import ControlLoop
    from tactex.sim import SceneConfig

    loop = ControlLoop(MujocoBackend(SceneConfig(object_name="plane")))
    loop.hold(0.05)
    p0 = loop.state.ee_position.copy()
    loop.retract(0.04, direction_world=np.array([0.0, 0.0, 2.0]))  # any length: normalised
    loop.hold(0.3)
    np.testing.assert_allclose(loop.state.ee_position - p0, [0.0, 0.0, 0.04], atol=4e-3)
    for bad in (np.zeros(3), np.array([np.nan, 0.0, 1.0]), np.ones(2)):
        with pytest.raises(InputError, match="direction_world"):
            loop.retract(0.04, direction_world=bad)


def test_task_sensor_noise_reaches_the_scene_and_is_checked() -> None:
    """`tactex wipe --seed` changed nothing: the noise it seeds was 0 and could not be set."""
    from tactex.tasks.wipe import WipeConfig

    scene = WipeConfig(ft_noise_n=0.5, ft_noise_nm=0.01, depth_noise_m=0.001, seed=7).scene()
    assert (scene.ft_noise_n, scene.ft_noise_nm, scene.depth_noise_m, scene.seed) == (0.5, 0.01, 0.001, 7)
    scene = CleanConfig(ft_noise_n=0.3).scene()
    assert scene.ft_noise_n == 0.3 and scene.marking == "X"
    for bad in ({"ft_noise_n": -1.0}, {"depth_noise_m": float("nan")}):
        with pytest.raises(ConfigError, match=next(iter(bad))):
            WipeConfig(**bad)


def test_move_cartesian_refuses_to_skip_many_waypoints_in_a_row() -> None:
    """Skipping every missed waypoint would end in the single long joint move the waypoints avoid."""
    from tactex.errors import SimulationError
    from tactex.robots import MujocoBackend
    from tactex.robots.loop import ControlLoop
    from tactex.sim import SceneConfig

    loop = ControlLoop(MujocoBackend(SceneConfig(object_name="plane")))
    loop.hold(0.05)
    p0, r0, q0 = loop.state.ee_position.copy(), loop.state.ee_rotation.copy(), loop.state.q.copy()
    solve, calls = loop.solve_pose, []

    def flaky(*args, **kwargs):
        calls.append(1)
        if len(calls) in (2, 4, 5, 6):  # one miss, then three in a row
            raise SimulationError("IK did not reach the target (test)")
        return solve(*args, **kwargs)

    loop.solve_pose = flaky
    with pytest.raises(SimulationError, match="missed 3 waypoints in a row"):
        loop.move_cartesian(p0 + np.array([0.0, 0.0, 0.2]), r0, q_goal=q0)
    assert len(calls) == 6  # the single miss was skipped; the run of three stopped it before a long jump



def test_tactex_touches_down_first_where_the_arm_gets_soonest(monkeypatch) -> None:
    """tactex's first touch-down: of candidates spread over the dirt (at most START_CANDIDATES), the one whose
    planned moves from the capture posture are the shortest, never longer than those to the dirt nearest the
    camera (where the raster starts); none without normals."""
    from dataclasses import replace

    from tactex.robots import MujocoBackend
    from tactex.robots.loop import ControlLoop
    from tactex.tasks import clean

    cfg = CleanConfig(object_name="cup", marking="X")
    scene = cfg.scene()
    cap_pos, cap_rot = clean._capture_pose(scene, cfg)
    backend = MujocoBackend(scene)
    q_capture = backend.solve_ik(cap_pos, cap_rot)
    backend.reset(q0=q_capture)
    loop = ControlLoop(backend)
    obj = marked_cloud(get_surface("cup"), "X", 0.003)
    cloud = replace(obj, points=obj.points + scene.object_pose()[0])
    targets = np.flatnonzero(cloud.target > 0)

    def move_s(p: np.ndarray) -> float:
        j = targets[int(np.argmin(np.linalg.norm(cloud.points[targets] - p, axis=1)))]
        return clean._hover_plan(loop, cloud.points[j], cloud.normals[j], q_capture, cfg.hover_height_m,
                                 q_from=q_capture)[2]

    quickest = clean._quickest_touch_down(loop, cloud, targets, q_capture, cap_pos, cfg.hover_height_m)
    assert quickest is not None
    chosen, chosen_move_s = quickest
    assert np.min(np.linalg.norm(cloud.points[targets] - chosen, axis=1)) == 0.0
    assert chosen_move_s == pytest.approx(move_s(chosen), abs=0.01)  # the duration the bound's transit counts
    # the quick search (settled IK, the waypoint only while the bound can win) picks what planning every
    # candidate with the full IK picks
    pts = cloud.points[targets]
    _, first = np.unique(np.floor(pts / clean.START_SPACING_M).astype(np.int64), axis=0, return_index=True)
    assert first.size <= clean.START_CANDIDATES  # the cup's X: no coarser grid
    full = []
    for j in np.sort(first):
        try:
            full.append((round(move_s(pts[j]), 2), float(np.linalg.norm(pts[j] - cap_pos)), int(j)))
        except SimulationError:
            pass
    assert len(full) > 5
    np.testing.assert_array_equal(chosen, pts[min(full)[2]])
    nearest_camera = cloud.points[targets[np.argmin(np.linalg.norm(cloud.points[targets] - cap_pos, axis=1))]]
    rng = np.random.default_rng(0)
    others = [nearest_camera, *cloud.points[rng.choice(targets, 8, replace=False)]]
    assert all(move_s(chosen) <= move_s(p) + 0.01 for p in others)
    assert move_s(chosen) < move_s(nearest_camera)  # from 45° above the wall the nearest dirt is its top
    calls = []
    plan = clean._hover_plan
    monkeypatch.setattr(clean.motion, "_hover_plan", lambda *a, **k: calls.append(1) or plan(*a, **k))
    monkeypatch.setattr(clean.motion, "START_CANDIDATES", 5)
    assert clean._quickest_touch_down(loop, cloud, targets, q_capture, cap_pos, cfg.hover_height_m) is not None
    assert 1 <= len(calls) <= 5
    bare = replace(cloud, normals=None)
    assert clean._quickest_touch_down(loop, bare, targets, q_capture, cap_pos, cfg.hover_height_m) is None


def test_approach_speed_falls_with_the_height_above_the_captured_surface() -> None:
    """Full speed high above the surface, proportional below, nothing within approach_slow_m (the force loop's
    slow approach alone) nor under the surface."""
    from tactex.ergodic.command import ExplorationCommand
    from tactex.tasks.clean import APPROACH_GAIN_PER_S, _approach_speed

    cfg = CleanConfig(approach_speed_m_s=0.1, approach_slow_m=0.01)
    normal = np.array([0.0, -1.0, 0.0])  # a wall facing −y
    cmd = ExplorationCommand(point=np.array([0.4, 0.0, 0.05]), velocity=np.zeros(3), normal=normal,
                             tangent_u=np.array([1.0, 0.0, 0.0]), tangent_v=np.array([0.0, 0.0, 1.0]), step=0, agent=0)
    at = lambda h: _approach_speed(cmd.point + h * normal + np.array([0.003, 0.0, 0.002]), cmd, cfg)  # noqa: E731
    assert at(0.03) == pytest.approx(0.1)
    assert at(0.015) == pytest.approx(APPROACH_GAIN_PER_S * 0.005)
    assert at(0.01) == 0.0 and at(0.005) == 0.0 and at(-0.01) == 0.0
    assert _approach_speed(cmd.point + 0.03 * normal, cmd, CleanConfig(approach_speed_m_s=0.0)) == 0.0


def test_control_loop_joint_speed_sets_the_moves_duration_and_is_checked() -> None:
    from tactex.robots import MujocoBackend
    from tactex.robots.loop import ControlLoop
    from tactex.sim import SceneConfig

    backend = MujocoBackend(SceneConfig(object_name="plane"))
    slow, fast = ControlLoop(backend), ControlLoop(backend, max_joint_speed=1.6)
    goal = slow.state.q + 0.8
    assert slow.joint_move_duration(goal) == pytest.approx(1.875 * 0.8 / 0.8)
    assert fast.joint_move_duration(goal) == pytest.approx(1.875 * 0.8 / 1.6)
    assert fast.joint_move_duration(goal, max_joint_speed=0.8) == pytest.approx(slow.joint_move_duration(goal))
    with pytest.raises(InputError, match="max_joint_speed"):
        ControlLoop(backend, max_joint_speed=0.0)


def test_the_commanded_point_keeps_the_pad_above_the_table() -> None:
    """At a wall's foot the line's point rises until the pad's disc (⟂ the normal) clears the support plane; on a
    surface facing up (a plate) and higher on the wall it is left alone."""
    from tactex.tasks.clean import _pad_over_support

    wall = np.array([0.0, -1.0, 0.0])
    low = np.array([0.4, -0.04, 0.005])
    np.testing.assert_allclose(_pad_over_support(low, wall, 0.0, 0.025), [0.4, -0.04, 0.025])
    # a touch-down keeps its rim a clearance above the table: the move down to the hover undershoots
    np.testing.assert_allclose(_pad_over_support(low, wall, 0.0, 0.025, 0.005), [0.4, -0.04, 0.030])
    high = np.array([0.4, -0.04, 0.06])
    assert _pad_over_support(high, wall, 0.0, 0.025) is high
    plate = np.array([0.4, 0.0, 0.001])
    assert _pad_over_support(plate, np.array([0.0, 0.0, 1.0]), 0.0, 0.025) is plate
    tilted = np.array([0.0, -np.sin(np.radians(30.0)), np.cos(np.radians(30.0))])  # a rim at 30° from level
    np.testing.assert_allclose(_pad_over_support(plate, tilted * 2.0, 0.0, 0.025)[2], 0.025 * 0.5)


def test_pause_calls_the_backends_optional_hook_and_passes_over_a_backend_without_it() -> None:
    """ControlLoop.pause ends torque control through the backend's ``pause`` when it has one (the
    protocol's optional hook); a backend without it is one that waits, and MuJoCo's hook leaves the
    simulation where it was."""
    from tactex.robots import MujocoBackend, RobotBackend
    from tactex.robots.loop import ControlLoop
    from tactex.sim import SceneConfig

    class Pausing(_StillBackend):
        def __init__(self) -> None:
            super().__init__()
            self.pauses = 0

        def pause(self) -> None:
            self.pauses += 1

    assert isinstance(_StillBackend(), RobotBackend)  # the hook is not required by the protocol
    ControlLoop(_StillBackend()).pause()  # nothing to call: no error
    pausing = Pausing()
    ControlLoop(pausing).pause()
    assert pausing.pauses == 1

    with MujocoBackend(SceneConfig(object_name="plane")) as sim:
        assert callable(getattr(sim, "pause", None))  # the simulation states that it waits
        loop = ControlLoop(sim)
        loop.hold(0.01)
        t, q = sim.time, sim.state().q.copy()
        loop.pause()
        assert sim.time == t
        np.testing.assert_array_equal(sim.state().q, q)


def test_end_on_robot_pauses_and_names_the_error():
    """An error of ours mid-run on a robot ends torque control (pause) and becomes the run's ``aborted``;
    a link already gone (the pause fails with one of the robot's stops) is no further error."""
    from tactex.errors import RobotError, SimulationError
    from tactex.tasks.robot import end_on_robot

    class Loop:
        paused = 0

        def __init__(self, fail: bool) -> None:
            self.fail = fail

        def pause(self) -> None:
            self.paused += 1
            if self.fail:
                raise RobotError("the link is gone")

    for fail in (False, True):
        loop = Loop(fail)
        assert end_on_robot(loop, SimulationError("no hover pose within reach")) == \
            "SimulationError: no hover pose within reach"
        assert loop.paused == 1


def test_the_wipes_approach_gives_up_past_the_expected_surface():
    """Without contact the approach gives up once the TCP is start_height_m + approach_depth_m past the start
    along the start tool axis; a contact ends the search for good."""
    from types import SimpleNamespace

    from tactex.tasks.wipe import WipeConfig, _Approach

    cfg = WipeConfig(start_height_m=0.015, approach_depth_m=0.03)
    axis = np.array([0.0, 0.0, -1.0])  # the tool points down
    approach = _Approach(cfg, np.zeros(3), axis)

    def state(z: float, fz: float = 0.0):
        return SimpleNamespace(ee_position=np.array([0.01, 0.0, z]), wrench_tool=np.array([0.0, 0.0, fz, 0, 0, 0]))

    assert not approach.gave_up(state(-0.044))
    assert approach.gave_up(state(-0.046)) and "45 mm" in approach.message()
    assert not approach.gave_up(state(-0.05, fz=2.0)) and not approach.searching
    with pytest.raises(ConfigError, match="approach_depth_m"):
        WipeConfig(approach_depth_m=-0.01)


def test_the_clean_explorer_config_is_nested_and_follows_the_options() -> None:
    """CleanConfig.explorer is CLEAN_EXPLORER (a robot in contact: no hops, no edge braking, the ergodic source)
    with the options of the same names; max_velocity bounds the acceleration too; a replace() remakes it."""
    from dataclasses import replace

    from tactex.tasks.clean import CLEAN_EXPLORER

    cfg = CleanConfig(alpha=5.0, cooling=0.1, max_velocity=0.5, agent_radius_m=0.03, seed=3)
    ex = cfg.explorer
    assert (ex.alpha, ex.cooling, ex.max_velocity, ex.max_acceleration, ex.agent_radius_m, ex.seed) == (
        5.0, 0.1, 0.5, 0.5, 0.03, 3)
    assert (ex.max_bridge_voxels, ex.edge_braking, ex.source_mode) == (0.0, False, "ergodic")
    assert CleanConfig().explorer == replace(CLEAN_EXPLORER, seed=0)
    assert replace(cfg, alpha=7.0).explorer.alpha == 7.0


def test_a_tick_after_a_pause_starts_torque_control_again_on_a_fresh_state():
    # a real robot's backend while torque control is paused: the state it holds is from before the pause; the
    # loop's next tick must read a fresh one (starting torque control) before it computes a command on it
    from tactex.control.joint_impedance import JointTarget
    from tactex.robots import MujocoBackend
    from tactex.robots.loop import ControlLoop
    from tactex.sim import SceneConfig

    class Paused(MujocoBackend):
        torque_paused = True
        torque_restart = None

        def step(self):
            if self.torque_paused:
                self.torque_paused, self.torque_restart = False, np.zeros(7)
            return super().step()

    backend = Paused(SceneConfig(object_name="plate"))
    try:
        loop = ControlLoop(backend)
        stale_t = loop.state.t
        seen = []
        loop.joint.torque = (lambda inner: lambda s, r: (seen.append(s.t), inner(s, r))[1])(loop.joint.torque)
        loop.use(loop.joint)
        q = loop.state.q.copy()
        loop.tick(JointTarget(q, q, loop.t, 0.0))
        assert not backend.torque_paused and seen and seen[0] > stale_t  # computed on the state read after it
    finally:
        backend.close()


@pytest.mark.parametrize("from_speed", [True, False])
def test_a_lift_off_from_an_arm_in_fast_motion_brakes_it_without_a_torque_rate_clip(monkeypatch, from_speed):
    # another controller turns joints 1 and 3 against each other at about 1.3 rad/s (as a null-space motion can,
    # with the tool on its line), then the lift-off's joint move takes over: started at the measured speed it
    # brakes that motion along its trajectory; started at rest its damping would brake it at once, steps of
    # torque the rate limit clips
    from tactex.control.joint_impedance import JointImpedanceController, JointTarget
    from tactex.robots import MujocoBackend
    from tactex.robots.loop import ControlLoop
    from tactex.sim import SceneConfig

    backend = MujocoBackend(SceneConfig(object_name="plate"))
    try:
        loop = ControlLoop(backend)
        if not from_speed:
            monkeypatch.setattr(loop, "_dq_from", lambda: None)
        loop.use(JointImpedanceController())
        swing = np.array([0.35, 0.0, -0.35, 0.0, 0.0, 0.0, 0.0])
        target = JointTarget(loop.state.q.copy(), loop.state.q + swing, loop.t, 0.5)
        for _ in range(250):
            loop.tick(target)
        assert np.abs(loop.state.dq[[0, 2]]).min() > 1.2
        loop.retract(0.05)
        clips = loop.safety.counts.get("torque_rate_limit", 0)
        if from_speed:
            assert clips == 0
            assert np.abs(loop.state.dq).max() < 0.05  # and brought to rest within the lift
        else:
            assert clips > 10
    finally:
        backend.close()


@pytest.mark.parametrize("at", [1, 3, 20, 100])
@pytest.mark.parametrize("frozen", [True, False], ids=["frozen", "runs-on"])
def test_a_joint_move_across_lost_cycles_neither_steps_its_command_nor_ends_early(at: int, frozen: bool):
    # the robot's clock jumps 16 ms between two commands `at` ticks into a joint move: franka-sim repeats a frozen
    # state meanwhile, a robot and the twin run on under the last command. The commands go on without a
    # torque-rate clip (on the robot's clock alone the target would step by up to 1.5 N·m; held back by the
    # whole gap after the arm ran on, the command would step back by the arm's progress), the target is held back
    # by the whole gap less a period where the arm stood still and by less the further it went along the move,
    # and the move runs until its target's clock reaches the end
    from tactex.robots import MujocoBackend
    from tactex.robots.loop import ControlLoop
    from tactex.sim import SceneConfig

    class Stalling(MujocoBackend):
        ticks = -1  # counted from the move's first command

        def step(self):
            if self.ticks >= 0:
                self.ticks += 1
            if self.ticks == at:
                if frozen:
                    self.data.time += 0.015
                else:
                    for _ in range(15):
                        super().step()
            return super().step()

    backend = Stalling(SceneConfig(object_name="plate", camera_width=8, camera_height=8))
    try:
        loop = ControlLoop(backend)
        q_goal = loop.state.q + np.array([0.0, 0.15, 0.0, -0.15, 0.0, 0.1, 0.0])
        t0 = loop.t
        backend.ticks = 0
        loop.move_joints(q_goal, duration_s=0.5, settle_s=0.0)
        assert loop.safety.counts.get("torque_rate_limit", 0) == 0
        lag = loop.joint.lag_s
        if frozen:
            assert lag == pytest.approx(0.015, abs=1e-6)
        else:
            assert 0.0 <= lag <= 0.015 + 1e-9
        if not frozen and at == 100:  # mid-move the arm went most of the gap's way along it
            assert lag < 0.005
        assert loop.t >= t0 + 0.5 + lag - 1e-9
    finally:
        backend.close()


def test_a_far_wrist_bend_from_low_over_the_object_goes_up_to_the_capture_posture_first() -> None:
    """A joint move that starts away from the capture posture (after a lift-off) and bends the wrist (joints 5, 6)
    by more than LOW_MOVE_MAX_JOINT_RAD goes through the capture posture, and says how much longer that takes;
    from the capture posture, or turning only the base, the last joint or the wrist a little, it goes direct."""
    from types import SimpleNamespace

    from tactex.robots.loop import ControlLoop
    from tactex.tasks.clean import motion

    q_capture = np.array([0.0, -0.3, 0.0, -2.2, 0.0, 1.9, 0.8])
    low = q_capture + np.array([0.4, 0.6, 0.1, -0.3, -0.8, 1.5, 0.2])  # the arm down at the object, wrist bent

    def loop_at(q: np.ndarray):
        state = SimpleNamespace(q=np.asarray(q, dtype=float))
        fake = SimpleNamespace(state=state, max_joint_speed=1.5)
        fake.joint_move_duration = lambda q_goal, max_joint_speed=None, q_from=None, min_duration_s=0.5: (
            ControlLoop.joint_move_duration(fake, q_goal, max_joint_speed, q_from, min_duration_s))
        return fake

    bend = np.zeros(7)
    bend[5] = motion.LOW_MOVE_MAX_JOINT_RAD + 0.2
    detour = motion._detour_via_capture(loop_at(low), low + bend, q_capture)
    assert detour is not None and detour > 0.0
    loop = loop_at(low)
    direct = loop.joint_move_duration(low + bend)
    via = loop.joint_move_duration(q_capture) + loop.joint_move_duration(low + bend, q_from=q_capture)
    assert detour == pytest.approx(via - direct)
    for turn in ([1.5, 0, 0, 0, 0, 0, 0], [0, 0, 0, 0, 0, 0, 2.0], [0, 0, 0, 0, 0.5, -0.5, 0]):
        assert motion._detour_via_capture(loop_at(low), low + np.array(turn), q_capture) is None, turn
    near_capture = q_capture + 0.01
    assert motion._detour_via_capture(loop_at(near_capture), near_capture + bend, q_capture) is None


def test_a_joint_move_that_brings_the_pad_near_the_surface_on_its_way_is_found():
    """passes_near samples the move's straight line in joint space on the backend's kinematics (MuJoCo's model, as
    the robot's IK uses): a surface a centimetre under the pad's path halfway is near, one 5 cm under it is not, nor
    one 2 cm under the move's ends, and a backend without kinematics says no."""
    from types import SimpleNamespace

    from scipy.spatial import cKDTree

    from tactex.robots.mujoco_backend import MujocoBackend
    from tactex.sim.franka import FRANKA_HOME_Q
    from tactex.tasks.clean import motion

    backend = MujocoBackend()
    loop = SimpleNamespace(tcp_pose=backend.tcp_pose)
    q_from = np.asarray(FRANKA_HOME_Q, dtype=float)
    q_to = q_from + np.array([1.2, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])  # the base turns: the tool sweeps an arc
    mid, _ = backend.tcp_pose(0.5 * (q_from + q_to))
    ends = [backend.tcp_pose(q)[0] for q in (q_from, q_to)]
    grid = np.stack(np.meshgrid(np.linspace(-0.02, 0.02, 9), np.linspace(-0.02, 0.02, 9)), -1).reshape(-1, 2)

    def patch_under(p: np.ndarray, depth_m: float) -> np.ndarray:
        return np.column_stack([p[0] + grid[:, 0], p[1] + grid[:, 1], np.full(len(grid), p[2] - depth_m)])

    near = cKDTree(patch_under(mid, 0.01))
    assert motion.passes_near(loop, q_from, q_to, near, pad_radius_m=0.025)
    assert not motion.passes_near(loop, q_from, q_to, cKDTree(patch_under(mid, 0.05)), pad_radius_m=0.025)
    # surface 2 cm under the move's ends only (a hover is 3 cm above it, a lift-off 5 cm): clear
    at_ends = cKDTree(np.vstack([patch_under(e, 0.02) for e in ends]))
    assert not motion.passes_near(loop, q_from, q_to, at_ends, pad_radius_m=0.0)
    assert not motion.passes_near(SimpleNamespace(tcp_pose=lambda q: None), q_from, q_to, near, pad_radius_m=0.025)
    # the pose is the model's own: the TCP where MuJoCo's forward kinematics puts it
    backend.reset(q0=q_to)
    np.testing.assert_allclose(backend.tcp_pose(q_to)[0], backend.state().ee_position, atol=1e-9)
