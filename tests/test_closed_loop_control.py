"""Closed-loop control in the MuJoCo simulator: GA line+force, VA-UFIC alignment, passivity, faults.

Each scenario starts the robot above a surface with the backend's IK and runs the controller
behind the safety layer at 1 kHz. The VA-UFIC runs get their SurfaceEstimate from the object's
true normal at 30 Hz (the perception stage is tested on its own; here we test the controller).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import pytest

from tactex.control import (
    FRANKA_TAU_MAX,
    GaLineForceController,
    LineForceReference,
    PoseForceReference,
    SafetyLayer,
    SafetyLimits,
    UficParams,
    VaUficController,
    VaUficParams,
)
from tactex.perception.estimate import SurfaceEstimate

try:
    from tactex.robots.mujoco_backend import MujocoBackend
    from tactex.sim.scene import SceneConfig
except ImportError as exc:  # the simulator is an optional stage of the build
    pytest.skip(f"MuJoCo backend unavailable ({exc})", allow_module_level=True)

pytestmark = pytest.mark.slow

DT = 1e-3
TAU_MAX = np.asarray(FRANKA_TAU_MAX)
TAU_RATE_STEP = 1000.0 * DT
FORCE_TOL_N = 1.0
ANGLE_TOL_DEG = 3.0
OVERFORCE_MAX_S = 0.05


def _frame_with_z(z: np.ndarray, x_hint: np.ndarray) -> np.ndarray:
    z = z / np.linalg.norm(z)
    x = x_hint - (x_hint @ z) * z
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def _start(object_name: str, height_m: float, rotation: np.ndarray | None = None, **scene):
    """Backend with the TCP ``height_m`` above the object origin along its normal; tool along −n unless
    ``rotation`` is given. Returns (backend, state, object position, outward normal, tool rotation)."""
    backend = MujocoBackend(SceneConfig(object_name=object_name, **scene))
    pos, rot = backend.object_pose()
    normal = rot[:, 2].copy()
    r0 = _frame_with_z(-normal, np.array([1.0, 0.0, 0.0])) if rotation is None else rotation
    q = backend.solve_ik(pos + height_m * normal, r0)
    state = backend.reset(seed=0, q0=q)
    return backend, state, pos, normal, r0


@dataclass
class Log:
    t: list = field(default_factory=list)
    f_meas: list = field(default_factory=list)
    f_true: list = field(default_factory=list)
    angle_deg: list = field(default_factory=list)
    tau: list = field(default_factory=list)
    dq: list = field(default_factory=list)  # joint velocity [rad/s] at the tick the torque was computed for
    tel: list = field(default_factory=list)

    def arrays(self):
        return {k: np.asarray(v) for k, v in self.__dict__.items() if k != "tel"}


def _run(backend, state, ctrl, reference_at, seconds, normal, *, perturb=None, on_tick=None) -> Log:
    """Closed loop for ``seconds``; ``perturb(t, state) -> state`` corrupts what the controller sees,
    ``on_tick(k, t)`` changes the world (move the object)."""
    log = Log()
    ctrl.reset(state)
    for k in range(round(seconds / DT)):
        t = state.t
        if on_tick is not None:
            on_tick(k, t)
        seen = perturb(t, state) if perturb is not None else state
        tau = ctrl.torque(seen, reference_at(t, state))
        log.dq.append(state.dq)
        backend.apply_torque(tau)
        state = backend.step()
        log.t.append(t)
        log.f_meas.append(state.wrench_tool[2])
        log.f_true.append(backend.pad_contact()[0])
        log.angle_deg.append(np.degrees(np.arccos(np.clip(state.ee_rotation[:, 2] @ -normal, -1.0, 1.0))))
        log.tau.append(tau)
        log.tel.append(ctrl.telemetry())
    return log


def _assert_torques_safe(log: Log) -> None:
    tau = np.asarray(log.tau)
    assert np.isfinite(tau).all()
    # strictly below the robot's limits: the safety layer keeps a margin (LIMIT_MARGIN), so no command reaches them
    assert (np.abs(tau) < TAU_MAX).all()
    assert (np.abs(np.diff(tau, axis=0)) < TAU_RATE_STEP).all()


def _longest_run_above(values: np.ndarray, limit: float) -> float:
    longest = run = 0
    for above in values > limit:
        run = run + 1 if above else 0
        longest = max(longest, run)
    return longest * DT


# -- GA line + force (TEC) -------------------------------------------------------------------------

def _ga_tilted_plane_run(**scene):
    backend, state, pos, normal, r0 = _start("tilted_plane", 0.01, **scene)
    ctrl = SafetyLayer(GaLineForceController())
    direction = r0[:, 0]  # a line on the surface

    def ref(t, _s):
        return LineForceReference(pos + 0.04 * np.sin(0.8 * t) * direction, normal, 10.0)

    log = _run(backend, state, ctrl, ref, 6.0, normal)
    return log, ctrl


def test_ga_holds_10n_on_tilted_plane_while_the_agent_moves():
    """TEC's claim: tracking the line and pressing along it do not fight. Frictionless pad: the
    simulated pad hops when it slides with friction (see the next test), which is not the controller."""
    log, ctrl = _ga_tilted_plane_run(tool_friction=0.0)
    a = log.arrays()
    settled = a["t"] >= 3.0  # contact at ~0.3 s, then the force PID settles
    print(f"GA tilted plane: force error max {np.abs(a['f_meas'][settled] - 10).max():.3f} N, "
          f"angle max {a['angle_deg'][settled].max():.3f} deg")
    assert np.ptp(np.asarray(a["t"])[settled]) > 2.9
    assert np.abs(a["f_meas"][settled] - 10.0).max() <= FORCE_TOL_N
    assert np.abs(a["f_true"][settled] - 10.0).max() <= FORCE_TOL_N
    assert a["angle_deg"][settled].max() <= ANGLE_TOL_DEG
    _assert_torques_safe(log)
    assert not any(e.kind in ("force_limit", "nan_torque", "controller_fault") for e in ctrl.events)


def test_ga_holds_10n_while_sliding_with_friction():
    log, _ = _ga_tilted_plane_run()
    a = log.arrays()
    settled = a["t"] >= 3.0
    assert np.abs(a["f_true"][settled] - 10.0).max() <= FORCE_TOL_N


# -- VA-UFIC -----------------------------------------------------------------------------------------

def _truth_estimates(normal: np.ndarray, rate_hz: float = 30.0, curvature_at=lambda t: 0.0):
    """A SurfaceEstimate from the true normal, refreshed at ``rate_hz``."""
    cache = {"t": -1.0, "est": None}

    def get(t: float, state) -> SurfaceEstimate:
        if t - cache["t"] >= 1.0 / rate_hz - 1e-9:
            theta = float(np.arccos(np.clip(state.ee_rotation[:, 2] @ -normal, -1.0, 1.0)))
            cache["est"] = SurfaceEstimate(valid=True, timestamp=t, normal_world=normal.copy(),
                                           curvature=float(curvature_at(t)), theta_rad=theta)
            cache["t"] = t
        return cache["est"]

    return get


def test_va_ufic_aligns_from_out_of_contact_and_reaches_15n():
    """VA-UFIC §IV: start without contact and misaligned (tool vertical over a 15° plane)."""
    down = np.diag([1.0, -1.0, -1.0])
    backend, state, _, normal, _ = _start("tilted_plane", 0.03, rotation=down)
    ctrl = SafetyLayer(VaUficController())
    estimate = _truth_estimates(normal)
    x0 = state.ee_position.copy()

    def ref(t, s):
        return PoseForceReference(x0, down, np.array([0, 0, 15.0, 0, 0, 0]), surface=estimate(t, s))

    log = _run(backend, state, ctrl, ref, 3.0, normal)
    a = log.arrays()
    assert a["angle_deg"][0] > 14.0 and a["f_true"][0] == 0.0
    end = a["t"] >= 2.5
    print(f"VA-UFIC: final angle {a['angle_deg'][-1]:.3f} deg, force {a['f_meas'][end].mean():.2f} N")
    assert a["angle_deg"][end].max() <= 1.0
    assert np.abs(a["f_meas"][end] - 15.0).max() <= FORCE_TOL_N
    assert np.abs(a["f_true"][end] - 15.0).max() <= FORCE_TOL_N
    assert max(tel["realigning"] for tel in log.tel) == 1.0
    assert _longest_run_above(a["f_true"], 30.0) <= OVERFORCE_MAX_S
    _assert_torques_safe(log)


# -- passivity -----------------------------------------------------------------------------------------

#: Resolution of the τᵀq̇ audit [J] (runs that differ only in round-off reach 2.5e-4 J): 300× below
#: the 0.30 J the paper's literal double harvest breaks it by.
PASSIVITY_AUDIT_TOL_J = 1e-3

SMALL_TANKS = {"tank_i_x0": 1.6, "tank_i_upper": 2.0, "tank_i_lower": 1.0,
               "tank_f_x0": 1.6, "tank_f_upper": 2.0, "tank_f_lower": 1.0}


def _passivity_run(tanks_enabled: bool):
    """Wiping on a plane with stiffness driven up and down by the curvature channel and a 1 s contact
    loss (the surface drops 5 cm). Tanks are small (1.28 J, 0.28 J usable each) so the budget matters
    within a few seconds; the Table I tanks (23.5 J usable) would need a much longer run.

    The VA-UFIC law runs without the SafetyLayer here: the audit is of eq. 72–73 itself, and the
    layer's clipping, rate limit and retreat (a different controller) would change the port."""
    backend, state, pos, normal, r0 = _start("plane", 0.005)
    params = VaUficParams(tanks_enabled=tanks_enabled, rho_align_initial=1.0, **SMALL_TANKS)
    ctrl = VaUficController(params)
    curv = lambda t: 0.3 if int(t / 0.75) % 2 == 1 else 0.0  # noqa: E731 - alternating "vision" curvature
    estimate = _truth_estimates(normal, curvature_at=curv)
    x0 = state.ee_position.copy()

    def ref(t, s):
        p = x0 + r0 @ np.array([0.04 * np.sin(2 * t), 0.04 * (np.cos(2 * t) - 1), 0.0])
        return PoseForceReference(p, r0, np.array([0, 0, 15.0, 0, 0, 0]), surface=estimate(t, s))

    def world(k, t):
        if k == 2500:
            backend.move_object("object", pos - 0.05 * normal)
        if k == 3500:
            backend.move_object("object", pos)

    return _run(backend, state, ctrl, ref, 4.5, normal, on_tick=world), ctrl


def _energy_audit(log: Log, ctrl: VaUficController) -> dict:
    """The controller's port, from what the robot received: injected(t) = ∫ τᵀq̇ dt [J] (torques sent,
    measured joint velocities; none of the tanks' own bookkeeping). Compared with what the controller
    held at the start above the tanks' lower limits plus its constant spring, and with its storage
    S_c = S_t,i + S_t,f + ½x̃ᵀK_const x̃ (eq. 46/64) over time."""
    injected = np.cumsum(np.einsum("ij,ij->i", np.asarray(log.tau), np.asarray(log.dq))) * DT
    ti, tf = ctrl.tank_i, ctrl.tank_f
    spring = np.array([tl["spring_energy_const_j"] for tl in log.tel])
    storage = np.array([tl["tank_i_energy_j"] + tl["tank_f_energy_j"] for tl in log.tel]) + spring
    storage_0 = ti.x0**2 / 2 + tf.x0**2 / 2 + spring[0]
    held = (ti.x0**2 / 2 - ti.lower) + (tf.x0**2 / 2 - tf.lower) + spring[0]
    return {"injected": injected, "held": held, "passivity_excess": injected + storage - storage_0,
            "rho": np.array([tl["rho_align"] for tl in log.tel]), "f_true": log.arrays()["f_true"]}


def test_tanks_bound_the_injected_energy_and_disabling_them_violates_it():
    on, off = (_energy_audit(*_passivity_run(enabled)) for enabled in (True, False))
    for label, a in (("on ", on), ("off", off)):
        print(f"tanks {label}: injected max {a['injected'].max():.3f} J (final {a['injected'][-1]:+.3f} J), "
              f"held {a['held']:.3f} J, passivity excess max {a['passivity_excess'].max():+.2e} J")
    assert on["rho"].max() - on["rho"].min() > 0.5  # the stiffness really varied
    print(f"contact lost for {np.sum(on['f_true'][2500:3500] == 0.0) * DT:.3f} s of the 1 s drop")
    assert np.sum(on["f_true"][2500:3500] == 0.0) * DT > 0.1  # and contact was really lost
    # passive: the robot never got more than the tanks and the spring held, at any instant ...
    assert (on["injected"] <= on["held"] + 1e-9).all()
    # ... and the storage balance holds: what the port delivered plus what the storage gained never
    # exceeds zero. The paper's literal eq. 39/57 (both tanks harvest ẋᵀDẋ) broke this by 0.30 J here.
    # The tanks account for ẋᵀf while the robot receives the latency-shaped M (M + h·B)⁻¹Jᵀf; at the
    # re-contact after the drop the two differ by up to ~2.5e-4 J, depending on the run's round-off
    # (1e-13 relative changes of the wrench move it between 0 and that).
    assert on["passivity_excess"].max() <= PASSIVITY_AUDIT_TOL_J
    # the same run without tanks injects energy the controller never held
    assert off["injected"].max() > off["held"] + 0.1


# -- faults --------------------------------------------------------------------------------------------

def _ga_fault_run(perturb=None, on_tick=None, seconds=4.0, scene_object="plane"):
    backend, state, pos, normal, _ = _start(scene_object, 0.005)
    ctrl = SafetyLayer(GaLineForceController(), SafetyLimits(max_contact_force=20.0))
    ref = lambda t, s: LineForceReference(pos, normal, 10.0)  # noqa: E731 - faults need no sliding
    log = _run(backend, state, ctrl, ref, seconds, normal, perturb=perturb,
               on_tick=(lambda k, t: on_tick(backend, pos, normal, k)) if on_tick else None)
    return log, ctrl


def _assert_fault_handled(log: Log, set_point: float = 10.0) -> None:
    _assert_torques_safe(log)
    a = log.arrays()
    assert _longest_run_above(a["f_true"], 2.0 * set_point) <= OVERFORCE_MAX_S


def test_fault_nan_wrench():
    def perturb(t, s):
        return replace(s, wrench_tool=np.full(6, np.nan)) if 2.0 <= t < 2.05 else s

    log, ctrl = _ga_fault_run(perturb)
    _assert_fault_handled(log)
    assert ctrl.counts.get("nan_wrench", 0) == 50


def test_fault_force_spike():
    def perturb(t, s):
        return replace(s, wrench_tool=s.wrench_tool + np.array([0, 0, 100.0, 0, 0, 0])) if 2.0 <= t < 2.003 else s

    log, _ = _ga_fault_run(perturb)
    _assert_fault_handled(log)
    a = log.arrays()
    assert np.abs(a["f_true"][a["t"] >= 3.5] - 10.0).max() <= FORCE_TOL_N  # recovered


def test_fault_sustained_overforce_trips_the_retreat():
    def perturb(t, s):
        return replace(s, wrench_tool=s.wrench_tool + np.array([0, 0, 100.0, 0, 0, 0])) if 2.0 <= t < 2.05 else s

    log, ctrl = _ga_fault_run(perturb)
    _assert_fault_handled(log)
    kinds = [e.kind for e in ctrl.events]
    assert "force_limit" in kinds and "retreat_end" in kinds


def test_fault_contact_loss():
    """The surface drops 5 cm: contact is lost, the force loop (integrator frozen in free flight)
    approaches at K_p·F / D_z ≈ 0.1 m/s and presses again without an over-force."""
    def world(backend, pos, normal, k):
        if k == 2000:
            backend.move_object("object", pos - 0.05 * normal)

    log, _ = _ga_fault_run(on_tick=world)
    _assert_fault_handled(log)
    a = log.arrays()
    lost = (a["t"] > 2.0) & (a["f_true"] == 0.0)
    assert lost.sum() * DT > 0.1  # contact really lost for a while
    assert a["f_true"][-1] > 5.0  # and found again


def _ramp_object(backend, pos, normal, k, start, offset, ticks):
    if start <= k <= start + ticks:
        backend.move_object("object", pos + offset * normal * ((k - start) / ticks if ticks else 1.0))


@pytest.mark.parametrize(("offset", "ticks"), [(-0.02, 0), (0.02, 200)], ids=["drops_2cm", "rises_2cm_in_200ms"])
def test_fault_surface_jumps_2cm(offset, ticks):
    """A 2 cm step of the surface: away from the tool at once, or towards it within 0.2 s. A faster
    rise cannot stay under 2× for 50 ms by yielding alone: accelerating the arm's ~5 kg apparent
    mass to the surface's speed v takes 5·v N·s, i.e. 20 N for 50 ms at 0.2 m/s, on top of the
    preload; a teleport would put the rigid plate through the 15 mm pad."""
    log, _ = _ga_fault_run(on_tick=lambda b, p, n, k: _ramp_object(b, p, n, k, 2000, offset, ticks), seconds=7.0)
    _assert_fault_handled(log)
    a = log.arrays()
    assert np.abs(a["f_true"][a["t"] >= 6.0] - 10.0).max() <= FORCE_TOL_N  # recovered


def test_fault_va_ufic_surface_jump_and_nan():
    backend, state, pos, normal, r0 = _start("plane", 0.005)
    ctrl = SafetyLayer(VaUficController(VaUficParams(ufic=UficParams())), SafetyLimits(max_contact_force=30.0))
    estimate = _truth_estimates(normal)
    x0 = state.ee_position.copy()
    ref = lambda t, s: PoseForceReference(x0, r0, np.array([0, 0, 15.0, 0, 0, 0]), surface=estimate(t, s))  # noqa: E731

    def perturb(t, s):
        return replace(s, wrench_tool=np.full(6, np.nan)) if 1.5 <= t < 1.52 else s

    log = _run(backend, state, ctrl, ref, 4.0, normal, perturb=perturb,
               on_tick=lambda k, t: _ramp_object(backend, pos, normal, k, 2000, 0.02, 200))
    _assert_fault_handled(log, set_point=15.0)
    assert ctrl.counts.get("nan_wrench", 0) == 20
