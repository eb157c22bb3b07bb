"""The MuJoCo robot backend: a torque-controlled Franka with wrist F/T sensor, wiping pad and
RGB-D camera, in front of one object with dirt (see :mod:`tactex.sim`).

Timing: each :meth:`MujocoBackend.step` advances 1 ms with MuJoCo's split step (``mj_step2`` then
``mj_step1``) so that kinematics, Jacobian and mass matrix always describe the current state. The
F/T reading is the one of the step just integrated — one tick old, like a real sensor's.
"""

from __future__ import annotations

import math
import os
from collections import deque

import mujoco
import numpy as np

from tactex.control.state import RobotState
from tactex.errors import ControllerFault, InputError, MissingDependencyError, SimulationError
from tactex.perception.frame import CameraFrame
from tactex.sim.camera import RayCastCamera
from tactex.sim.camera_worker import CameraWorker
from tactex.sim.franka import ARM_BODY_PREFIX, FRANKA_HOME_Q
from tactex.sim.ft_sensor import FTSensorModel
from tactex.sim.ik import solve_site_ik
from tactex.sim.raycast import SceneRayCaster
from tactex.sim.scene import Scene, SceneConfig, build_scene

__all__ = ["MujocoBackend"]

_GL_FIX = "Set MUJOCO_GL=egl (or osmesa) for off-screen rendering, or run with a display"

_BAD = {
    int(mujoco.mjtWarning.mjWARN_BADQACC): "an unstable acceleration",
    int(mujoco.mjtWarning.mjWARN_BADQVEL): "NaN/huge joint velocities",
    int(mujoco.mjtWarning.mjWARN_BADQPOS): "NaN/huge joint positions",
}


class MujocoBackend:
    """:class:`~tactex.robots.backend.RobotBackend` on a MuJoCo scene.

    ``apply_torque`` takes torques without gravity (the backend adds g(q), as the Franka firmware
    does; ``SceneConfig.gravity_compensation=False`` turns that off) and clips them to the Franka
    torque limits. ``camera_frame`` returns a new frame when one is due at ``camera_rate_hz``, else
    None; ``render_depth`` captures one now.
    """

    n_joints = 7

    def __init__(self, config: SceneConfig | None = None) -> None:
        self.config = config or SceneConfig()
        self.scene: Scene = build_scene(self.config)
        self.model = self.scene.model
        self.data = mujoco.MjData(self.model)
        self._fk_data: mujoco.MjData | None = None  # tcp_pose's scratch state
        self._link_geoms: np.ndarray | None = None  # the arm's capsule geoms (link_capsules)
        self.dt = float(self.model.opt.timestep)
        ids = self.scene.ids
        self._ids = ids
        self._qadr = self.scene.arm_qpos
        self._dadr = self.scene.arm_dof
        # the arm comes first in the model: slices are much cheaper than fancy indexing at 1 kHz
        if not (np.array_equal(self._qadr, np.arange(7)) and np.array_equal(self._dadr, np.arange(7))):
            raise SimulationError("the arm joints must be the first 7 of the scene model")
        self._limits = self.scene.torque_limits
        self._neg_limits = -self._limits
        # the Jacobian rows [linear; angular] in one buffer: mj_jacSite writes both halves in place
        self._jac = np.zeros((6, self.model.nv))
        self._jacp, self._jacr = self._jac[:3], self._jac[3:]
        self._mfull = np.zeros((self.model.nv, self.model.nv))
        self._pad_vel = np.zeros(6)
        self._cache_views()
        tool = self.config.tool
        mass, com = tool.calibrated_mass_properties()
        # the F/T's calibration is made with the tool as it is (tool_mass_scale mis-sets the robot's load only)
        self.ft_sensor = FTSensorModel(
            mass * self.config.tool_mass_scale, com, tool.tcp_offset_m, bias=self.config.ft_bias,
            noise_n=self.config.ft_noise_n, noise_nm=self.config.ft_noise_nm, cutoff_hz=self.config.ft_cutoff_hz,
            dt_s=self.dt, gravity=self.model.opt.gravity.copy(),
        )
        self.camera = RayCastCamera(
            self.model, ids["camera"], self.config.intrinsics, self.config.depth_noise_m,
            method=self.config.camera_raycast, caster=SceneRayCaster(self.scene.sim_object),
        )
        self._renderer = None
        self._viewer = None
        self._worker: CameraWorker | None = None
        if self.config.camera_worker:
            self._worker = CameraWorker(self.camera, self.scene.dirt, self._object_rgb,
                                        timeout_s=self.config.camera_worker_timeout_s)
        self._pending: CameraFrame | None = None
        self._pending_ready_t = 0.0
        self._state: RobotState | None = None
        self._last_contact: tuple[float, np.ndarray | None] = (0.0, None)
        self._pad_bottom = tool.pad_thickness_m / 2 if tool.pad_shape == "cylinder" else None
        self._sample_ticks = int(self.config.contact_sample_ticks)
        self._tick = 0
        self.reset(self.config.seed)

    # -- protocol -------------------------------------------------------------------------------
    def reset(self, seed: int | None = None, q0: np.ndarray | None = None) -> RobotState:
        """Robot at ``q0`` (default home) at rest, object at its configured pose, dirt restored."""
        q = FRANKA_HOME_Q if q0 is None else self._check_q(q0, "q0")
        m, d = self.model, self.data
        mujoco.mj_resetData(m, d)
        d.qpos[self._qadr] = q
        pos, rot = self.config.object_pose()
        self._set_object_pose(pos, rot)
        self._seed = int(self.config.seed if seed is None else seed)
        self._rng = np.random.default_rng(self._seed)
        self._pending = None
        if self._worker is not None:
            self._worker.discard()  # a frame of the previous episode
        self._frame_index = 0
        self._tau = np.zeros(self.n_joints)
        # commands on their way to the joints, oldest first (SceneConfig.command_delay_ticks of them)
        self._in_flight = deque(np.zeros(self.n_joints) for _ in range(int(self.config.command_delay_ticks)))
        self.scene.dirt.reset()
        self._tick = 0
        self._last_contact = (0.0, None)
        self.ft_sensor.reset()
        self._next_camera_t = 0.0
        self._sum_check = bool(m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_AUTORESET)
        mujoco.mj_forward(m, d)
        self._check_finite("reset", 0.0)
        self._after_tick()
        return self.state()

    def state(self) -> RobotState:
        """The current state (computed once per tick)."""
        if self._state is None:
            self._state = self._make_state()
        return self._state

    def apply_torque(self, tau: np.ndarray) -> None:
        """Command joint torques (7,) [N·m] without gravity; clipped to the torque limits.

        With ``SceneConfig.command_delay_ticks`` = d the command acts d control periods later (the
        ``step`` applies the command of d steps before; zeros first): a real Franka applies the
        torque computed from state k during cycle k + 1, not k."""
        t = np.asarray(tau, dtype=float)
        if t.shape != (self.n_joints,):
            raise ControllerFault(f"torque command must have shape ({self.n_joints},), got {t.shape}")
        # one sum is finite iff every term is (a finite overflow is clipped below anyway); a sum over a
        # list is several times cheaper than a numpy reduction of seven numbers
        if not math.isfinite(sum(t.tolist())) and not np.isfinite(t).all():
            raise ControllerFault(f"torque command holds NaN/inf: {t.tolist()}; refusing to send it to the robot")
        self._tau = np.minimum(np.maximum(t, self._neg_limits), self._limits)  # np.clip's wrapper costs more

    def step(self) -> RobotState:
        """Advance one control period with the last commanded torque; returns the new state."""
        m, d = self.model, self.data
        if self._in_flight:  # the command delay: this step's command joins the queue, the oldest acts
            self._in_flight.append(self._tau)
            self._v_ctrl[:] = self._in_flight.popleft()
        else:
            self._v_ctrl[:] = self._tau
        if not self._gravity_comp:
            np.negative(self._v_gravcomp, out=self._v_applied)
        t_next = d.time + self.dt
        mujoco.mj_step2(m, d)
        self._tick += 1
        if self._tick % self._sample_ticks == 0:
            self._wipe()
        mujoco.mj_step1(m, d)
        if d.time + 0.5 * self.dt < t_next or self._sum_check:  # else MuJoCo's own checks passed
            self._check_finite("step", t_next)
        self._after_tick()
        self._state = self._make_state()
        return self._state

    def pause(self) -> None:
        """Wall-clock work between two ticks is coming: nothing to do, simulated time waits for it
        (the :class:`~tactex.robots.backend.RobotBackend` protocol's optional hook)."""

    def camera_frame(self) -> CameraFrame | None:
        """A new RGB-D frame when one is due, else None.

        Frames are exposed at ``camera_rate_hz`` and delivered ``camera_latency_s`` later (like a real
        camera; ``CameraFrame.timestamp`` is the exposure time). The frame is rendered at exposure
        (not in a worker thread: its GIL hand-overs with the 1 kHz loop cost more than the rendering
        they would overlap). With ``SceneConfig.camera_worker`` a worker process renders it instead and the frame
        is delivered at the next exposure (one frame period after its timestamp; the frames equal
        those of ``camera_latency_s`` = one period in process). Noise is seeded per frame, so runs
        are reproducible.
        """
        now = self.data.time + 1e-9
        due = now >= self._next_camera_t
        if not due and self._pending is None:
            return None  # most ticks
        if self._worker is not None:
            return self._worker_frame(now)
        frame = None
        # a frame is delivered once its latency has passed, or at the latest when the next is exposed
        if self._pending is not None and (now >= self._pending_ready_t or due):
            frame = self._pending
            self._pending = None
        if due:
            period = 1.0 / self.config.camera_rate_hz
            exposure_t = self._next_camera_t
            while self._next_camera_t <= now:
                self._next_camera_t += period
            latency = self.config.camera_latency_s
            if latency <= 0.0:
                return self.render_depth()
            self._pending = self.render_depth()
            self._pending_ready_t = exposure_t + latency
        return frame

    def _frame_rng(self) -> np.random.Generator | None:
        """The next frame's noise generator, seeded by (seed, frame index): runs are reproducible. None
        without depth noise (seeding one costs about as much as shading a frame)."""
        self._frame_index += 1
        if self.camera.depth_noise_m <= 0:
            return None
        return np.random.default_rng([self._seed, self._frame_index])

    def _worker_frame(self, now: float) -> CameraFrame | None:
        """With ``camera_worker``, at an exposure tick: collect the frame exposed one period ago (waiting
        for the worker if it is late: the episode does not depend on the machine's speed) and hand
        the worker this one's snapshot, the same a synchronous capture would render now."""
        assert self._worker is not None
        frame = self._worker.collect() if self._worker.busy else None
        period = 1.0 / self.config.camera_rate_hz
        while self._next_camera_t <= now:
            self._next_camera_t += period
        world_T_cam, obj_pos, obj_rot = self.camera.snapshot(self.data, self._ids["object_body"])
        self._frame_index += 1
        self._worker.submit(world_T_cam, obj_pos, obj_rot, self.time, self.scene.dirt.level, self._seed,
                            self._frame_index, self.camera.depth_noise_m > 0)
        return frame

    @property
    def camera_worker(self) -> CameraWorker | None:
        """The camera worker process (``SceneConfig.camera_worker``), else None."""
        return self._worker

    def __enter__(self) -> MujocoBackend:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Release the GL renderer, the viewer and the camera worker process."""
        if self._worker is not None:
            self._worker.close()
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        if self._viewer is not None:
            self._viewer.close()
            self._viewer = None

    # -- extras ---------------------------------------------------------------------------------
    @property
    def time(self) -> float:
        return float(self.data.time)

    @property
    def dirt(self):
        """The :class:`~tactex.sim.dirt.DirtField` of the object."""
        return self.scene.dirt

    def dirt_remaining(self) -> float:
        """Ground-truth fraction of the initial dirt still on the object."""
        return self.scene.dirt.remaining_fraction()

    def render_depth(self) -> CameraFrame:
        """Capture an RGB-D frame now (ray cast), synchronously."""
        return self.camera.capture(
            self.data, self.time, dirt=self.scene.dirt, object_geom=self._ids["object_geom"],
            object_body=self._ids["object_body"], object_rgb=self._object_rgb, table_geom=self._ids["table_geom"],
            rng=self._frame_rng(),
        )

    def object_pose(self, name: str | None = None) -> tuple[np.ndarray, np.ndarray]:
        """World position [m] and rotation of the object frame."""
        self._check_object_name(name)
        b = self._ids["object_body"]
        return self.data.xpos[b].copy(), self.data.xmat[b].reshape(3, 3).copy()

    def move_object(self, name: str, position: np.ndarray, rotation: np.ndarray | None = None) -> None:
        """Move the object (its frame origin to ``position`` [m], orientation ``rotation``), e.g. to
        simulate a surface that was bumped; the robot and the dirt are untouched."""
        self._check_object_name(name)
        pos = np.asarray(position, dtype=float).reshape(-1)
        if pos.shape != (3,) or not np.isfinite(pos).all():
            raise InputError(f"object position must be 3 finite numbers [m], got {position!r}")
        rot = self.object_pose()[1] if rotation is None else np.asarray(rotation, dtype=float)
        if rot.shape != (3, 3) or not np.allclose(rot @ rot.T, np.eye(3), atol=1e-6) or np.linalg.det(rot) < 0:
            raise InputError(f"object rotation must be a 3×3 rotation matrix, got {rotation!r}")
        self._set_object_pose(pos, rot)
        mujoco.mj_step1(self.model, self.data)
        self._state = None

    def pad_contact(self) -> tuple[float, np.ndarray | None]:
        """Ground truth, sampled every ``contact_sample_ticks`` steps: magnitude of the net normal
        contact force on the pad [N] and the centre of its footprint on the object in the world [m]
        (the force-weighted contact point when it touches something else; None without contact)."""
        return self._last_contact

    def solve_ik(self, position_world: np.ndarray, rotation_world: np.ndarray | None = None,
                 q_init: np.ndarray | None = None, q_posture: np.ndarray | None = None, *,
                 settled_step_rad: float | None = None, max_iter: int = 500) -> np.ndarray:
        """Joint positions (7,) putting the TCP at ``position_world`` [m] with tool orientation
        ``rotation_world`` (3×3, optional), by damped least squares from ``q_init`` (default: the
        current q), preferring postures near ``q_posture`` (default: home). Does not move the robot.
        ``settled_step_rad`` [rad], ``max_iter``: see :func:`~tactex.sim.ik.solve_site_ik` (the defaults: the
        full search)."""
        q_start = self.data.qpos[self._qadr].copy() if q_init is None else self._check_q(q_init, "q_init")
        posture = FRANKA_HOME_Q if q_posture is None else self._check_q(q_posture, "q_posture")
        return solve_site_ik(
            self.model, self._ids["tcp"], self._qadr, self._dadr, position_world, rotation_world, q_start, posture,
            settled_step_rad=settled_step_rad, max_iter=max_iter,
        )

    def _fk(self, q: np.ndarray) -> mujoco.MjData:
        """A scratch copy of the state with the arm at joint positions ``q`` (7,) [rad] and its kinematics."""
        if self._fk_data is None:
            self._fk_data = mujoco.MjData(self.model)
        d = self._fk_data
        d.qpos[self._qadr] = self._check_q(q, "q")
        mujoco.mj_kinematics(self.model, d)
        return d

    def tcp_pose(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The TCP's position (3,) [m] and orientation (3, 3) in the world at joint positions ``q`` (7,) [rad], on
        the model's kinematics (the robot does not move; a scratch copy of the state)."""
        d = self._fk(q)
        site = self._ids["tcp"]
        return d.site_xpos[site].copy(), d.site_xmat[site].reshape(3, 3).copy()

    def link_capsules(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The arm's links at joint positions ``q`` (7,) [rad] as the model's capsules (an approximation of the
        Panda's shape, :mod:`tactex.sim.franka`): their axes' ends (K, 2, 3) [m] in the world and their radii (K,)
        [m]. The tool on the flange is not among them."""
        if self._link_geoms is None:
            m = self.model
            self._link_geoms = np.array([
                g for g in range(m.ngeom) if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_CAPSULE
                and (mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, int(m.geom_bodyid[g])) or "").startswith(
                    ARM_BODY_PREFIX)], dtype=int)
        d, ids = self._fk(q), self._link_geoms
        centre = d.geom_xpos[ids]
        half = (d.geom_xmat[ids].reshape(-1, 3, 3)[:, :, 2] * self.model.geom_size[ids, 1:2])
        return np.stack([centre - half, centre + half], axis=1), self.model.geom_size[ids, 0].copy()

    def render_rgb(self, width: int = 640, height: int = 480, camera: str | int = -1) -> np.ndarray:
        """An OpenGL image (H, W, 3) uint8 of the scene (needs MUJOCO_GL=egl/osmesa/glfw)."""
        backend_gl = os.environ.get("MUJOCO_GL", "").lower()
        has_display = bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
        # Without an offscreen back-end, MuJoCo falls back to GLFW, which needs a display; a failed GLFW
        # start leaves it half-initialised and the next attempt aborts the process in C++.
        if backend_gl == "disable" or (backend_gl not in ("egl", "osmesa") and not has_display):
            raise MissingDependencyError("OpenGL context", "", "GL rendering", fix=_GL_FIX)
        try:
            if self._renderer is None or (self._renderer.width, self._renderer.height) != (width, height):
                if self._renderer is not None:
                    self._renderer.close()
                self._renderer = mujoco.Renderer(self.model, height, width)
            self._renderer.update_scene(self.data, camera=camera)
            return self._renderer.render().copy()
        except Exception as exc:  # GL back-ends fail in many ways without a GPU/display
            self._renderer = None
            raise MissingDependencyError("working OpenGL context", "", f"GL rendering ({exc})", fix=_GL_FIX) from exc

    def launch_viewer(self):
        """Open MuJoCo's passive viewer (needs a display); call ``viewer.sync()`` after steps."""
        if not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY"):
            raise MissingDependencyError(
                "display", "", "The interactive viewer",
                fix="DISPLAY is not set: run it in a desktop session or with X forwarding",
            )
        import mujoco.viewer

        self._viewer = mujoco.viewer.launch_passive(self.model, self.data)
        return self._viewer

    # -- internals ------------------------------------------------------------------------------
    def _check_q(self, q, label: str) -> np.ndarray:
        q = np.asarray(q, dtype=float).reshape(-1)
        if q.shape != (self.n_joints,) or not np.isfinite(q).all():
            raise InputError(f"{label} must be {self.n_joints} finite joint angles [rad], got {q.tolist()}")
        return q

    def _check_object_name(self, name: str | None) -> None:
        if name is not None and name not in ("object", self.scene.sim_object.name):
            raise InputError(f"no object named '{name}' in this scene; it holds '{self.scene.sim_object.name}'")

    def _set_object_pose(self, pos: np.ndarray, rot: np.ndarray) -> None:
        mid = self._ids["object_mocap"]
        self.data.mocap_pos[mid] = pos
        quat = np.zeros(4)
        mujoco.mju_mat2Quat(quat, np.asarray(rot, dtype=float).reshape(9))
        self.data.mocap_quat[mid] = quat

    def _check_finite(self, where: str, t: float) -> None:
        d = self.data
        # MuJoCo checks qpos, qvel (mj_step1) and qacc (mj_step2) for NaN, inf and |x| > 1e10 and, with
        # auto-reset on, resets the data itself: the clock jumps back to 0, so the clock and its warnings
        # are the evidence; without auto-reset (read at reset) the joint states are summed
        if d.time + 0.5 * self.dt >= t and (not self._sum_check or math.isfinite(
                sum(self._v_qpos.tolist()) + sum(self._v_qvel.tolist()))):
            return
        bad = [what for code, what in _BAD.items() if d.warning[code].number > 0]
        raise SimulationError(
            f"the simulation diverged at t = {t:.4f} s ({where}): MuJoCo reported "
            f"{', '.join(bad) or 'NaN/inf joint states'}. Hint: lower the controller gains or the tool "
            "stiffness, or check the commanded torques."
        )

    def _cache_views(self) -> None:
        """Numpy views of the MjData fields read every tick: MuJoCo never reallocates them, and building
        a view costs about a microsecond each time (this runs at 1 kHz)."""
        d, ids = self.data, self._ids
        self._v_ctrl, self._v_applied, self._v_gravcomp = d.ctrl, d.qfrc_applied, d.qfrc_gravcomp
        self._v_qpos, self._v_qvel = d.qpos, d.qvel
        self._v_q, self._v_dq = d.qpos[:7], d.qvel[:7]
        self._v_grav7, self._v_bias7, self._v_act7 = d.qfrc_gravcomp[:7], d.qfrc_bias[:7], d.qfrc_actuator[:7]
        a, b = ids["ft_force_adr"], ids["ft_torque_adr"]
        self._v_ft_force, self._v_ft_torque = d.sensordata[a:a + 3], d.sensordata[b:b + 3]
        self._v_ft_rot = d.site_xmat[ids["ft_site"]].reshape(3, 3)
        self._v_tcp_pos, self._v_tcp_rot = d.site_xpos[ids["tcp"]], d.site_xmat[ids["tcp"]].reshape(3, 3)
        self._mass7 = self._mfull[:7, :7]
        self._jac7 = self._jac[:, :7]
        # the weight the robot's gravity compensation misses (a tool heavier or lighter than its load setting:
        # gravcomp below or above 1): its bodies and their uncompensated mass [kg]
        m = self.model
        self._unmodelled = [(b, (1.0 - float(m.body_gravcomp[b])) * float(m.body_mass[b])) for b in range(m.nbody)
                            if m.body_gravcomp[b] != 1.0 and m.body_gravcomp[b] != 0.0]
        self._jac_com = np.zeros((3, m.nv))
        self._tcp = ids["tcp"]
        self._force_threshold = self.scene.dirt.params.force_threshold_n
        self._object_rgb = np.asarray(self.scene.sim_object.rgb, dtype=float)
        self._pad_geom, self._object_geom, self._pad_body = ids["pad_geom"], ids["object_geom"], ids["pad_body"]
        self._v_pad_pos, self._v_pad_rot = d.xpos[self._pad_body], d.xmat[self._pad_body].reshape(3, 3)
        b = ids["object_body"]
        self._v_obj_pos, self._v_obj_rot = d.xpos[b], d.xmat[b].reshape(3, 3)
        self._gravity_comp = bool(self.config.gravity_compensation)

    def _after_tick(self) -> None:
        # a fresh array each tick: shared by the state
        self._wrench = self.ft_sensor.measure(self._v_ft_force, self._v_ft_torque, self._v_ft_rot, self._rng)
        self._state = None

    def _pad_contacts(self) -> tuple[float, list | None, float, list | None, list | None]:
        """Pad contacts of the last step: total normal force [N] and force-weighted point (world),
        and the same for the object only, with its mean normal (pointing from the surface to the pad);
        points and normal as lists of 3 floats."""
        d = self.data
        if d.ncon == 0:
            return 0.0, None, 0.0, None, None
        # a handful of contacts: plain Python on lists beats numpy's per-call overhead here
        con = d.contact
        adr = con.efc_address.tolist()
        efc = d.efc_force.tolist()
        pad, obj = self._pad_geom, self._object_geom
        pos = frame = None
        # force-weighted sums of the contact points and normals as scalars (the normal, the first row of
        # the contact frame, points from geom1 to geom2): all contacts, and on the object alone
        f_all = f_obj = 0.0
        pax = pay = paz = nax = nay = naz = 0.0
        pox = poy = poz = nox = noy = noz = 0.0
        for i, (g1, g2) in enumerate(con.geom.tolist()):
            if (g1 != pad and g2 != pad) or adr[i] < 0:
                continue
            fn = efc[adr[i]]  # elliptic cones: the first row of a contact is its normal force
            if fn <= 0:
                continue
            if pos is None:
                pos, frame = con.pos.tolist(), con.frame.tolist()
            px, py, pz = pos[i]
            fs = fn if g2 == pad else -fn
            wx, wy, wz = fn * px, fn * py, fn * pz
            nx, ny, nz = frame[i][0] * fs, frame[i][1] * fs, frame[i][2] * fs
            f_all += fn
            pax += wx
            pay += wy
            paz += wz
            nax += nx
            nay += ny
            naz += nz
            if g1 == obj or g2 == obj:
                f_obj += fn
                pox += wx
                poy += wy
                poz += wz
                nox += nx
                noy += ny
                noz += nz
        if f_all == 0.0:
            return 0.0, None, 0.0, None, None
        # report the magnitude of the net normal force (contacts on neighbouring facets of a height
        # field push in slightly different directions; their magnitudes do not add up)
        total = math.sqrt(nax ** 2 + nay ** 2 + naz ** 2)
        point = [pax / f_all, pay / f_all, paz / f_all]
        if f_obj == 0.0:
            return total, point, 0.0, None, None
        norm = math.sqrt(nox ** 2 + noy ** 2 + noz ** 2)
        return total, point, f_obj, [pox / f_obj, poy / f_obj, poz / f_obj], [nox / norm, noy / norm, noz / norm]

    def _wipe(self) -> None:
        """Contact ground truth and Preston wear, sampled every ``contact_sample_ticks`` ticks (the
        pad moves well under a millimetre meanwhile; the wear of the whole period is applied)."""
        total, point, force, point_w, normal = self._pad_contacts()
        if point_w is None:
            self._last_contact = (total, None if point is None else np.array(point))
            return
        # plain floats: this runs every few ticks, and a dozen numpy calls on 3-vectors cost more
        nx, ny, nz = normal
        if self._pad_bottom is not None:
            # flat sponge: the footprint is the pad disc, centred under the pad whatever contact
            # points the collider reports (a tilted disc touches at its rim)
            px, py, pz = self._v_pad_pos.tolist()
            ax, ay, az = self._v_pad_rot[:, 2].tolist()
            b = self._pad_bottom
            cx, cy, cz = px + ax * b, py + ay * b, pz + az * b
            h = (point_w[0] - cx) * nx + (point_w[1] - cy) * ny + (point_w[2] - cz) * nz
            point_w = [cx + h * nx, cy + h * ny, cz + h * nz]
        self._last_contact = (total, np.array(point_w))
        if force <= self._force_threshold:
            return
        mujoco.mj_objectVelocity(self.model, self.data, mujoco.mjtObj.mjOBJ_BODY, self._pad_body, self._pad_vel, 0)
        _, _, _, vx, vy, vz = self._pad_vel.tolist()  # world-frame linear velocity of the pad centre
        vn = vx * nx + vy * ny + vz * nz  # (the object is at rest)
        slip = math.sqrt(max(vx * vx + vy * vy + vz * vz - vn * vn, 0.0))
        if slip > 0.0:
            ox, oy, oz = self._v_obj_pos.tolist()
            dx, dy, dz = point_w[0] - ox, point_w[1] - oy, point_w[2] - oz
            r = self._v_obj_rot.tolist()
            point_obj = [dx * r[0][j] + dy * r[1][j] + dz * r[2][j] for j in range(3)]  # (p − o)·R
            self.scene.dirt.apply_wear(point_obj, force * slip * self.dt * self._sample_ticks)

    def _make_state(self) -> RobotState:
        m, d = self.model, self.data
        mujoco.mj_jacSite(m, d, self._jacp, self._jacr, self._tcp)
        mujoco.mj_fullM(m, d, self._mfull)
        # fresh arrays (controllers may keep a state); every numpy call here costs about a microsecond,
        # so there is exactly one per array, and the state is built positionally (no keyword dict)
        jac = self._jac7.copy()
        dq = self._v_dq.copy()
        gravity = self._v_grav7.copy()
        tau = np.add(self._v_act7, gravity) if self._gravity_comp else self._v_act7.copy()
        wrench = self._wrench
        # q and dq were checked after the step (everything kinematic follows from them); the torques
        # and the sensor reading are checked here: one sum is finite iff every term is
        if not math.isfinite(sum(tau.tolist()) + sum(wrench.tolist())):
            raise SimulationError(f"non-finite robot state at t = {d.time:.4f} s; hint: the simulation diverged")
        # (t, q, dq, tau_measured, ee_position, ee_rotation, ee_twist, jacobian, mass_matrix, coriolis,
        # gravity, wrench_tool)
        coriolis = np.subtract(self._v_bias7, gravity)
        if self._unmodelled:
            coriolis -= self._unmodelled_gravity()
        return RobotState(d.time, self._v_q.copy(), dq, tau, self._v_tcp_pos.copy(), self._v_tcp_rot.copy(),
                          np.dot(jac, dq), jac, self._mass7.copy(), coriolis, gravity, wrench)

    def _unmodelled_gravity(self) -> np.ndarray:
        """(7,) [N·m] the gravity torque of the weight the robot does not compensate. A robot's model knows
        only the load it was told: its Coriolis vector holds no part of the tool's true weight, which acts on
        the arm as a disturbance its controllers must meet (MuJoCo's bias force holds all of it)."""
        m, d, jac = self.model, self.data, self._jac_com
        g = m.opt.gravity
        out = np.zeros(7)
        for body, mass in self._unmodelled:
            mujoco.mj_jacBodyCom(m, d, jac, None, body)
            out -= mass * (jac[:, :7].T @ g)
        return out
