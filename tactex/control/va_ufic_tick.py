"""VA-UFIC's tick from the pose error to the world wrench, as one compiled call (the ``fast`` extra).

:meth:`tactex.control.va_ufic.VaUficController.torque` on Python floats is some 150 float operations
and a dozen small method calls (the alignment monitor, ρ_align, the wrench filter, the force PI, the
damping switch, the friction feed-forward, both tanks, the re-orientation). Between a robot state
and its command each Python call costs microseconds (docs/real_robot.md), so on the real robot the
controller runs this function instead, compiled by :mod:`tactex.control.joint_kernels`: the same
operations in the same order on one float64 state vector (layout below). The Python classes stay
the reference: the tests run both on the same ticks and compare torques and states.

The state vector ``ks`` holds everything the tick changes; ``kp`` the constants. The controller
packs its objects into ``ks`` before the first compiled tick and unpacks them when Python code asks
for them (:class:`~tactex.control.va_ufic.VaUficController`).

Comparisons are written as the Python reference writes them (``a if a < b else b``, never
``min``/``max``), so that NaN takes the same branches in both.
"""

from __future__ import annotations

import math

import numpy as np

from tactex.control.compiler import compile_kernel as _jit  # this module is imported by joint_kernels.kernels()

__all__ = ["FAULT_FRICTION_DT", "FAULT_FRICTION_FORCE", "FAULT_FRICTION_RHO", "FAULT_ROTATION", "OK", "va_ufic_tick"]

# The state vector ``ks`` (indices; numba reads module-level integers as constants).
S_T_PREV = 0  # last tick's time [s]; NaN: none yet
S_W_OK = 1  # 1: the wrench filter holds a value
S_W = 2  # 6: low-passed measured wrench, tool frame [N, N·m]
S_INTEG = 8  # 6: the force PI's integral ∫f̃ per tool axis [N·s, N·m·s]
S_D = 14  # 6: D_C diagonal, tool frame
S_RHO = 20  # ρ_align
S_OFFSET = 21  # 3: position offset fed back while compliant [m]
S_ROT_D_OK = 24  # 1: R_d set
S_ROT_D = 25  # 9: R_d rows
S_RE_ON = 34  # 1: a re-orientation runs
S_RE_T0 = 35  # its start [s]
S_RE_INIT = 36  # 9: R_init rows
S_RE_LOG = 45  # 3: log(R_goal R_initᵀ)
S_TANK_I = 48  # 11: energy, delivered, harvested, has_last, last (7)
S_TANK_F = 59  # 12: the same and damping_harvested_w
S_FRIC = 71  # 11: f0, f1, started, a, a_dt, last (6)
S_RAW = 82  # 16: ρ_align, ρ_frc, C, h, θ, l_s, usable, σ_i, m_f, f_err, x̃^ee (6)
S_RAW_OK = 98  # 1: S_RAW holds a tick
S_ANCHOR_OK = 99  # 1: the tangential hold's anchor is set
S_ANCHOR = 100  # 3: where the tool touched down while compliant, world [m]
S_SIZE = 103
# offsets inside a tank's block
T_ENERGY, T_DELIVERED, T_HARVESTED, T_HAS_LAST, T_LAST, T_DAMP_HARVESTED = 0, 1, 2, 3, 4, 11

# The constants ``kp``.
P_ALPHA, P_XI, P_GAMMA, P_C_MARGIN, P_RHO_MIN, P_COMPLIANT, P_DELTA_C = 0, 1, 2, 3, 4, 5, 6
P_REALIGN_T, P_REALIGN_MIN, P_DAMP_FF = 7, 8, 9
P_K_CONST = 11  # 6
P_K_MAX_T = 17  # 6
P_D_CONTACT = 23  # 6
P_D_FREE = 29  # 6
P_CONTACT_N, P_SWITCH_S, P_TAU_W, P_KP_F, P_KI_F, P_ILIM, P_DT = 35, 36, 37, 38, 39, 40, 41
P_AXES = 42  # 6
P_TI_ON, P_TI_UP, P_TI_LOW, P_TI_BAND = 48, 49, 50, 51
P_TF_ON, P_TF_UP, P_TF_LOW, P_TF_BAND = 52, 53, 54, 55
P_FR_ON, P_FR_GAIN, P_FR_CUTOFF, P_FR_MU, P_FR_MAX = 56, 57, 58, 59, 60
P_TF_LAM_BAND = 61  # the force tank's λ ramp [W] (ForceTank.lambda_band_w)
P_HOLD = 62  # VaUficParams.tangent_hold [-]
P_FOLLOW = 63  # VaUficParams.follow_planned_rate [rad/s]
P_FOLLOW_TAU = 64  # VaUficParams.follow_planned_tau [s]
P_SIZE = 65

OK = 0
FAULT_FRICTION_FORCE = 1  # the friction feed-forward got a non-finite measured force
FAULT_FRICTION_RHO = 2  # ... a ρ_align outside [0, 1]
FAULT_FRICTION_DT = 3  # ... a tick period ≤ 0
FAULT_ROTATION = 4  # a re-orientation would start from a non-finite tool rotation


@_jit
def _valve(energy, lower, band):
    if energy <= lower:
        return 0.0
    if band <= 0.0 or energy >= lower + band:
        return 1.0
    return 0.5 * (1.0 - math.cos(math.pi * (energy - lower) / band))


@_jit
def _gate(energy, upper, band):
    if energy >= upper:
        return 0.0
    if band <= 0.0 or energy <= upper - band:
        return 1.0
    return 0.5 * (1.0 + math.cos(math.pi * (energy - (upper - band)) / band))


@_jit
def _commit(ks, b, on, upper, lower, demand_w, valve, harvest_w, gate, lam, dt):
    """EnergyTank._commit on the tank block at ``ks[b:]``."""
    if on and demand_w > 0.0 and valve > 0.0:
        room = ks[b] - lower
        if valve * demand_w * dt > room:
            valve = room / (demand_w * dt)
            valve = valve if valve > 0.0 else 0.0
    port = valve * demand_w
    harvest = harvest_w if harvest_w > 0.0 else 0.0
    if harvest > 0.0:
        room = (upper - ks[b]) / dt
        room = room if room > 0.0 else 0.0
        harvest = room if room < harvest else harvest
    energy = ks[b] + dt * (harvest - port)
    top = upper if upper > ks[b] else ks[b]
    ks[b] = top if energy > top else energy
    ks[b + 1] += dt * port
    ks[b + 2] += dt * harvest
    ks[b + 3] = 1.0
    last = b + 4
    ks[last], ks[last + 1], ks[last + 2], ks[last + 3] = port, -port, harvest, valve
    ks[last + 4], ks[last + 5], ks[last + 6] = gate, lam, ks[b]
    return valve


@_jit
def _rows_tn(a, b):
    """Aᵀ·B of two row-major 3×3 blocks (9-vectors) into a new 9-vector."""
    out = np.empty(9)
    for i in range(3):
        for j in range(3):
            out[3 * i + j] = a[i] * b[j] + a[3 + i] * b[3 + j] + a[6 + i] * b[6 + j]
    return out


@_jit
def _rows_nn(a, b):
    """A·B of two row-major 3×3 blocks (9-vectors) into a new 9-vector."""
    out = np.empty(9)
    for i in range(3):
        for j in range(3):
            out[3 * i + j] = a[3 * i] * b[j] + a[3 * i + 1] * b[3 + j] + a[3 * i + 2] * b[6 + j]
    return out


@_jit
def _log_rows(r):
    """:func:`tactex.geometry.so3.log_so3_rows` on a row-major 9-vector."""
    cos_a = 0.5 * (r[0] + r[4] + r[8] - 1.0)
    cos_a = cos_a if cos_a < 1.0 else 1.0
    cos_a = cos_a if cos_a > -1.0 else -1.0
    wx, wy, wz = r[7] - r[5], r[2] - r[6], r[3] - r[1]
    sin_a = 0.5 * math.sqrt(wx * wx + wy * wy + wz * wz)
    angle = math.atan2(sin_a, cos_a)
    if angle < 1e-9:
        return 0.5 * wx, 0.5 * wy, 0.5 * wz
    if math.pi - angle > 1e-6:
        f = angle / (2.0 * sin_a)
        return wx * f, wy * f, wz * f
    # near π: the axis from the symmetric part (tactex.geometry.so3._log_near_pi)
    col = 0
    best = -math.inf
    for i in range(3):
        d = r[4 * i] - cos_a
        if d > best:
            best, col = d, i
    s0 = 0.5 * (r[col] + r[3 * col]) - (cos_a if col == 0 else 0.0)
    s1 = 0.5 * (r[3 + col] + r[3 * col + 1]) - (cos_a if col == 1 else 0.0)
    s2 = 0.5 * (r[6 + col] + r[3 * col + 2]) - (cos_a if col == 2 else 0.0)
    scale = math.sqrt(best if best > 1e-12 else 1e-12)
    a0, a1, a2 = s0 / scale, s1 / scale, s2 / scale
    if wx * a0 + wy * a1 + wz * a2 < 0.0:
        a0, a1, a2 = -a0, -a1, -a2
    n = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
    return a0 / n * angle, a1 / n * angle, a2 / n * angle


@_jit
def _exp_rows(x, y, z):
    """:func:`tactex.geometry.so3.exp_so3_rows` as a row-major 9-vector."""
    out = np.empty(9)
    angle = math.sqrt(x * x + y * y + z * z)
    if angle < 1e-12:
        out[0], out[1], out[2] = 1.0, -z, y
        out[3], out[4], out[5] = z, 1.0, -x
        out[6], out[7], out[8] = -y, x, 1.0
        return out
    x, y, z = x / angle, y / angle, z / angle
    s = math.sin(angle)
    c = 1.0 - math.cos(angle)
    cxy, cxz, cyz = c * x * y, c * x * z, c * y * z
    out[0], out[1], out[2] = 1.0 - c * (y * y + z * z), cxy - s * z, cxz + s * y
    out[3], out[4], out[5] = cxy + s * z, 1.0 - c * (x * x + z * z), cyz - s * x
    out[6], out[7], out[8] = cxz - s * y, cyz + s * x, 1.0 - c * (x * x + y * y)
    return out


@_jit
def _spring_energy(kp, rot_d, rl):
    """½ x̃ᵀK_const x̃ of the rotational part [J] (VaUficController._rotational_spring_energy)."""
    e3, e4, e5 = _log_rows(_rows_tn(rot_d, rl))
    k3, k4, k5 = -kp[P_K_CONST + 3], -kp[P_K_CONST + 4], -kp[P_K_CONST + 5]
    return -0.5 * (k3 * e3 * e3 + k4 * e4 * e4 + k5 * e5 * e5)


@_jit
def _withdraw(ks, kp, energy_j):
    """EnergyTank.withdraw on the impedance tank."""
    if not energy_j > 0.0:
        return energy_j == 0.0
    b = S_TANK_I
    if kp[P_TI_ON] != 0.0 and ks[b] - energy_j < kp[P_TI_LOW]:
        return False
    ks[b] -= energy_j
    ks[b + 1] += energy_j
    return True


@_jit
def _advance_realign(ks, kp, t, dt, rl):
    """VaUficController._advance_realign."""
    t0 = ks[S_RE_T0]
    lx, ly, lz = ks[S_RE_LOG], ks[S_RE_LOG + 1], ks[S_RE_LOG + 2]
    zeta = (t - t0) / kp[P_REALIGN_T]
    zeta = zeta if zeta < 1.0 else 1.0
    rot_new = _rows_nn(_exp_rows(zeta * lx, zeta * ly, zeta * lz), ks[S_RE_INIT:S_RE_INIT + 9])
    rot_d = ks[S_ROT_D:S_ROT_D + 9]
    cost = _spring_energy(kp, rot_new, rl) - _spring_energy(kp, rot_d, rl)
    if cost > 0.0 and not _withdraw(ks, kp, cost):
        ks[S_RE_T0] = t0 + dt
        return
    rot_d[:] = rot_new
    if zeta >= 1.0:
        ks[S_RE_ON] = 0.0


@_jit
def _goal_log(ks, rl, zx, zy, zz):
    """log(R_goal R_dᵀ) with R_goal = desired_rotation_from_normal(``rl``, z_des) for the rows ``rl``."""
    nz = math.sqrt(zx * zx + zy * zy + zz * zz)
    zx, zy, zz = zx / nz, zy / nz, zz / nz
    rx0 = rl[0] - (rl[0] * zx + rl[3] * zy + rl[6] * zz) * zx
    rx1 = rl[3] - (rl[0] * zx + rl[3] * zy + rl[6] * zz) * zy
    rx2 = rl[6] - (rl[0] * zx + rl[3] * zy + rl[6] * zz) * zz
    n = math.sqrt(rx0 * rx0 + rx1 * rx1 + rx2 * rx2)
    if n < 1e-6:  # the current x-axis along the normal: the current y-axis, crossed with the normal
        y0 = rl[1] - (rl[1] * zx + rl[4] * zy + rl[7] * zz) * zx
        y1 = rl[4] - (rl[1] * zx + rl[4] * zy + rl[7] * zz) * zy
        y2 = rl[7] - (rl[1] * zx + rl[4] * zy + rl[7] * zz) * zz
        rx0, rx1, rx2 = y1 * zz - y2 * zy, y2 * zx - y0 * zz, y0 * zy - y1 * zx
        n = math.sqrt(rx0 * rx0 + rx1 * rx1 + rx2 * rx2)
    rx0, rx1, rx2 = rx0 / n, rx1 / n, rx2 / n
    ry0, ry1, ry2 = zy * rx2 - zz * rx1, zz * rx0 - zx * rx2, zx * rx1 - zy * rx0
    goal = np.empty(9)
    goal[0], goal[1], goal[2] = rx0, ry0, zx
    goal[3], goal[4], goal[5] = rx1, ry1, zy
    goal[6], goal[7], goal[8] = rx2, ry2, zz
    rd = ks[S_ROT_D:S_ROT_D + 9]
    g_rdt = np.empty(9)  # R_goal R_dᵀ
    for i in range(3):
        for j in range(3):
            g_rdt[3 * i + j] = (goal[3 * i] * rd[3 * j] + goal[3 * i + 1] * rd[3 * j + 1]
                                + goal[3 * i + 2] * rd[3 * j + 2])
    return _log_rows(g_rdt)


@_jit
def _start_realign(ks, rl, zx, zy, zz, t):
    """desired_rotation_from_normal(R, z_des) and log(R_goal R_dᵀ): a re-orientation from R_d."""
    wx, wy, wz = _goal_log(ks, rl, zx, zy, zz)
    rd = ks[S_ROT_D:S_ROT_D + 9]
    ks[S_RE_ON] = 1.0
    ks[S_RE_T0] = t
    ks[S_RE_INIT:S_RE_INIT + 9] = rd
    ks[S_RE_LOG], ks[S_RE_LOG + 1], ks[S_RE_LOG + 2] = wx, wy, wz


@_jit
def _begin(ks, kp, t, rot, ref_rot):
    """The tick's period dt [s] (UficController._dt) and the tool rotation as a row-major 9-vector; R_d set
    from the reference on the first tick, and a re-orientation in progress advanced."""
    tp = ks[S_T_PREV]
    dt = t - tp if (not math.isnan(tp)) and 0.0 < t - tp < 0.1 else kp[P_DT]
    ks[S_T_PREV] = t
    rl = np.empty(9)
    for i in range(3):
        for j in range(3):
            rl[3 * i + j] = rot[i, j]
    if ks[S_ROT_D_OK] == 0.0:
        for i in range(3):
            for j in range(3):
                ks[S_ROT_D + 3 * i + j] = ref_rot[i, j]
        ks[S_ROT_D_OK] = 1.0
    if ks[S_RE_ON] != 0.0:
        _advance_realign(ks, kp, t, dt, rl)
    return dt, rl


@_jit
def _surface(surf_ok, normal, curvature, r02, r12, r22):
    """The surface estimate (VaUficController._surface): (usable, θ [rad], l_s, the unit inward normal z)."""
    usable, theta, ls, zx, zy, zz = False, 0.0, 0.0, 0.0, 0.0, 0.0
    if surf_ok != 0.0:
        nx, ny, nz = normal[0], normal[1], normal[2]
        ls = curvature
        norm = math.sqrt(nx * nx + ny * ny + nz * nz)
        if not (math.isfinite(norm) and math.isfinite(ls)) or norm < 1e-9:
            ls = 0.0
        else:
            usable = True
            zx, zy, zz = -nx / norm, -ny / norm, -nz / norm
            cos_t = r02 * zx + r12 * zy + r22 * zz
            cos_t = cos_t if cos_t < 1.0 else 1.0  # max(-1, min(1, ·)) as Python evaluates it, NaN included
            cos_t = cos_t if cos_t > -1.0 else -1.0
            theta = math.acos(cos_t)
    return usable, theta, ls, zx, zy, zz


@_jit
def _filter_wrench(ks, kp, dt, wrench):
    """The low-passed measured wrench, tool frame (UficController._wrench_filtered), kept in ``ks``."""
    wm = np.empty(6)
    if ks[S_W_OK] != 0.0:
        a = dt / (dt + kp[P_TAU_W])
        for i in range(6):
            x = ks[S_W + i]
            wm[i] = x + a * (wrench[i] - x)
    else:
        for i in range(6):
            wm[i] = wrench[i]
    ks[S_W:S_W + 6] = wm
    ks[S_W_OK] = 1.0
    return wm


@_jit
def _alignment(ks, kp, dt, wm, e0, e1, e2, e3, e4, e5, theta, ls):
    """Eq. 17-21: the alignment cost C, h and the new ρ_align (kept in ``ks``)."""
    tactile = wm[0] * e0 + wm[1] * e1 + wm[2] * e2 + wm[3] * e3 + wm[4] * e4 + wm[5] * e5
    c = kp[P_ALPHA] * abs(tactile) + kp[P_XI] * abs(theta) + kp[P_GAMMA] * abs(ls)
    h = 1.0 - c / kp[P_C_MARGIN]
    rho_prev = ks[S_RHO]
    rho = h * rho_prev + kp[P_RHO_MIN]
    if rho_prev >= 1.0:
        rate = 0.0 if 0.0 < rho else rho
    elif rho_prev <= 0.0:
        rate = 0.0 if 0.0 > rho else rho
    else:
        rate = rho
    rho_new = rho_prev + dt * rate
    rho_new = rho_new if rho_new > 0.0 else 0.0
    rho_align = rho_new if rho_new < 1.0 else 1.0
    ks[S_RHO] = rho_align
    return c, h, rho_align


@_jit
def _tilt(rd, zx, zy, zz):
    """The angle [rad] between R_d's z axis (rows ``rd``) and the unit vector z (VaUficController._tilt)."""
    cos_tilt = rd[2] * zx + rd[5] * zy + rd[8] * zz
    cos_tilt = cos_tilt if cos_tilt < 1.0 else 1.0
    cos_tilt = cos_tilt if cos_tilt > -1.0 else -1.0
    return math.acos(cos_tilt)


@_jit
def _follow_planned(ks, kp, dt, rl, zx, zy, zz):
    """VaUficController._follow_planned: R_d turned toward the planned inward normal z at
    min(follow_planned_rate, tilt / follow_planned_tau), the spring's extra energy paid from the impedance tank."""
    rd = ks[S_ROT_D:S_ROT_D + 9]
    if _tilt(rd, zx, zy, zz) < 0.5 * kp[P_REALIGN_MIN]:
        return
    wx, wy, wz = _goal_log(ks, rd, zx, zy, zz)  # reads its base rows only: R_d itself
    angle = math.sqrt(wx * wx + wy * wy + wz * wz)
    rate, tau = kp[P_FOLLOW], kp[P_FOLLOW_TAU]
    if tau > 0.0 and angle < rate * tau:
        rate = angle / tau
    step = rate * dt / angle if angle > 1e-12 else 1.0
    step = step if step < 1.0 else 1.0
    rot_new = _rows_nn(_exp_rows(step * wx, step * wy, step * wz), rd)
    cost = _spring_energy(kp, rot_new, rl) - _spring_energy(kp, rd, rl)
    if cost > 0.0 and not _withdraw(ks, kp, cost):
        return
    rd[:] = rot_new


@_jit
def _tangent_hold(ks, kp, rl, px, py, pz, fz, rho_align):
    """The tangential hold (VaUficParams.tangent_hold): (its share now, the anchor spring's tool x and y
    force [N]); the anchor set at the first compliant tick in contact, cleared otherwise."""
    hold = kp[P_HOLD] if fz >= kp[P_CONTACT_N] else 0.0
    a0 = 0.0
    a1 = 0.0
    if rho_align <= kp[P_COMPLIANT] and hold > 0.0:
        if ks[S_ANCHOR_OK] == 0.0:
            ks[S_ANCHOR_OK] = 1.0
            ks[S_ANCHOR], ks[S_ANCHOR + 1], ks[S_ANCHOR + 2] = px, py, pz
        qx, qy, qz = px - ks[S_ANCHOR], py - ks[S_ANCHOR + 1], pz - ks[S_ANCHOR + 2]
        a0 = -hold * kp[P_K_MAX_T] * (rl[0] * qx + rl[3] * qy + rl[6] * qz)
        a1 = -hold * kp[P_K_MAX_T + 1] * (rl[1] * qx + rl[4] * qy + rl[7] * qz)
    else:
        ks[S_ANCHOR_OK] = 0.0
    return hold, a0, a1


@_jit
def _go_compliant(ks, kp, rl, ox, oy, oz, usable, zx, zy, zz, t):
    """Compliant (ρ_align low): the position offset ``o`` [m] fed back, and a re-orientation to the surface
    normal started when the tool is tilted from it. Returns OK or FAULT_ROTATION."""
    ks[S_OFFSET], ks[S_OFFSET + 1], ks[S_OFFSET + 2] = ox, oy, oz
    if usable and ks[S_RE_ON] == 0.0:
        rd = ks[S_ROT_D:S_ROT_D + 9]
        if _tilt(rd, zx, zy, zz) > kp[P_REALIGN_MIN]:
            for x in rl:  # desired_rotation_from_normal refuses a non-finite rotation
                if not math.isfinite(x):
                    return FAULT_ROTATION
            _start_realign(ks, rl, zx, zy, zz, t)
    return OK


@_jit
def _force_shaping(kp, ref_wrench, e0, e1, e2, e3, e4, e5):
    """Eq. 30: ρ_frc, the force's share by the position error along the tool axis."""
    wd0, wd1, wd2 = ref_wrench[0], ref_wrench[1], ref_wrench[2]
    wd3, wd4, wd5 = ref_wrench[3], ref_wrench[4], ref_wrench[5]
    if wd0 * e0 + wd1 * e1 + wd2 * e2 + wd3 * e3 + wd4 * e4 + wd5 * e5 <= 0.0:
        return 1.0
    if 0.0 < e2 <= kp[P_DELTA_C]:
        return 0.5 * (1.0 + math.cos(math.pi * e2 / kp[P_DELTA_C]))
    return 0.0


@_jit
def _select_damping(ks, kp, dt, fz):
    """D_C (UficController._select_damping) for the filtered normal force ``fz`` [N], kept in ``ks``."""
    tgt = P_D_CONTACT if fz >= kp[P_CONTACT_N] else P_D_FREE
    tau_s = kp[P_SWITCH_S]
    if tau_s <= 0:
        dz_new = kp[tgt + 2]
    else:
        dz_new = ks[S_D + 2] + dt / (dt + tau_s) * (kp[tgt + 2] - ks[S_D + 2])
    for i in range(6):
        ks[S_D + i] = kp[tgt + i]
    ks[S_D + 2] = dz_new


@_jit
def _force_wrench(ks, kp, dt, rho_frc, ref_wrench, wm):
    """Eq. 10-12 (UficController.force_wrench_tool): the shaped force PI's wrench, tool frame (6,)."""
    integrate = rho_frc > 1e-3
    kpf, kif, lim = kp[P_KP_F], kp[P_KI_F], kp[P_ILIM]
    ff = np.empty(6)
    for i in range(6):
        fd = ref_wrench[i]
        err = kp[P_AXES + i] * (fd - wm[i])
        if integrate:
            s = ks[S_INTEG + i] + err * dt
            ks[S_INTEG + i] = lim if s > lim else (-lim if s < -lim else s)
        ff[i] = rho_frc * (fd + kpf * err + kif * ks[S_INTEG + i])
    return ff


@_jit
def _friction(ks, kp, dt, rho_align, wrench):
    """FrictionCompensator.wrench_tool: (OK or a FAULT_FRICTION_* code, its in-plane force w0, w1 [N])."""
    fx, fy, fz = wrench[0], wrench[1], wrench[2]
    if not (math.isfinite(fx) and math.isfinite(fy) and math.isfinite(fz)):
        return FAULT_FRICTION_FORCE, 0.0, 0.0
    if not (math.isfinite(rho_align) and 0.0 <= rho_align <= 1.0):
        return FAULT_FRICTION_RHO, 0.0, 0.0
    if not (math.isfinite(dt) and dt > 0):
        return FAULT_FRICTION_DT, 0.0, 0.0
    fb = S_FRIC
    if ks[fb + 2] != 0.0:
        if dt != ks[fb + 4]:
            ks[fb + 3] = 1.0 - math.exp(-2.0 * math.pi * kp[P_FR_CUTOFF] * dt)
            ks[fb + 4] = dt
        a = ks[fb + 3]
        g0, g1 = ks[fb], ks[fb + 1]
        g0, g1 = g0 + a * (fx - g0), g1 + a * (fy - g1)
    else:
        g0, g1 = fx, fy
        ks[fb + 2] = 1.0
    ks[fb], ks[fb + 1] = g0, g1
    mu_fz = kp[P_FR_MU] * (0.0 if 0.0 > fz else fz)  # max(fz, 0.0)
    bound = mu_fz if mu_fz < kp[P_FR_MAX] else kp[P_FR_MAX]  # min(max_force, ·)
    mag = math.hypot(g0, g1)
    if mag > 0.0:
        ratio = bound / mag
        sat = ratio if ratio < 1.0 else 1.0  # min(1.0, ·)
    else:
        sat = 0.0
    scale = kp[P_FR_GAIN] * rho_align * sat
    w0, w1 = scale * g0, scale * g1
    ks[fb + 5], ks[fb + 6] = w0, w1
    ks[fb + 7] = ks[fb + 8] = ks[fb + 9] = ks[fb + 10] = 0.0
    return OK, w0, w1


@_jit
def _force_tank(ks, kp, dt, p_force, p_damp):
    """The force tank (ForceTank.step) on the force port's power ``p_force`` and the damping's ``p_damp`` [W]:
    the force's modulation m_f."""
    bf = S_TANK_F
    gate = _gate(ks[bf], kp[P_TF_UP], kp[P_TF_BAND])
    ks[bf + T_DAMP_HARVESTED] = 0.0
    tf_on = kp[P_TF_ON] != 0.0
    if p_force < 0.0:
        band = kp[P_TF_LAM_BAND]
        lam = 1.0 if band <= 0.0 or p_force <= -band else -p_force / band
        if lam >= 1.0:
            m_f = 1.0
        else:
            valve = 1.0 if not tf_on else _valve(ks[bf], kp[P_TF_LOW], kp[P_TF_BAND])
            m_f = lam + valve * (1.0 - lam)
        damping = 0.0 if 0.0 > p_damp else p_damp
        dissipated = damping - m_f * p_force
        _commit(ks, bf, tf_on, kp[P_TF_UP], kp[P_TF_LOW], 0.0, 0.0, gate * dissipated, gate, lam, dt)
        ks[bf + T_DAMP_HARVESTED] = ks[bf + T_LAST + 2] * damping / dissipated if dissipated > 0.0 else 0.0
    else:
        valve = 1.0 if not tf_on else _valve(ks[bf], kp[P_TF_LOW], kp[P_TF_BAND])
        m_f = _commit(ks, bf, tf_on, kp[P_TF_UP], kp[P_TF_LOW], p_force, valve, 0.0, gate, 0.0, dt)
    return m_f


@_jit
def _impedance_tank(ks, kp, dt, p_port, p_damp):
    """The impedance tank (ImpedanceTank.step) on the variable stiffness's port power ``p_port`` [W]: its
    valve σ_i."""
    bi = S_TANK_I
    ti_on = kp[P_TI_ON] != 0.0
    gate_i = _gate(ks[bi], kp[P_TI_UP], kp[P_TI_BAND])
    valve_i = 1.0 if not ti_on else _valve(ks[bi], kp[P_TI_LOW], kp[P_TI_BAND])
    spring_power = -p_port  # ImpedanceTank.step's argument; its demand is minus that
    return _commit(ks, bi, ti_on, kp[P_TI_UP], kp[P_TI_LOW], -spring_power, valve_i,
                   gate_i * (p_damp - ks[S_TANK_F + T_DAMP_HARVESTED]), gate_i, 1.0, dt)


def va_ufic_tick(ks, kp, t, rot, pos, twist, wrench, ref_pos, ref_rot, ref_wrench, ref_twist,
                 surf_ok, normal, curvature, f_world):
    """One VA-UFIC tick: updates ``ks`` and writes the world wrench [N, N·m] to ``f_world`` (6,).

    Args:
        ks: (S_SIZE,) the state vector. kp: (P_SIZE,) the constants.
        t: the state's time [s]. rot: (3, 3) world_R_tool. pos: (3,) TCP [m]. twist: (6,) TCP twist,
        world [m/s, rad/s]. wrench: (6,) measured wrench, tool frame [N, N·m].
        ref_pos, ref_rot, ref_wrench, ref_twist: the reference's (3,), (3, 3), (6,) tool frame, (6,) world.
        surf_ok: 1.0 when the surface estimate is valid and fresh (its normal and curvature are then
        checked here as in VaUficController._surface), 2.0 when it is besides planned (SurfaceEstimate.planned).
        normal: (3,) its outward normal, world.
        curvature: its l_s [-].

    Returns:
        OK, or a FAULT_* code (the Python reference raises ControllerFault there); the state is then
        changed as far as the reference's would be when it raises.
    """
    dt, rl = _begin(ks, kp, t, rot, ref_rot)
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = rl[0], rl[1], rl[2], rl[3], rl[4], rl[5], rl[6], rl[7], rl[8]
    px, py, pz = pos[0], pos[1], pos[2]
    dx, dy, dz = ref_pos[0], ref_pos[1], ref_pos[2]
    ox, oy, oz = ks[S_OFFSET], ks[S_OFFSET + 1], ks[S_OFFSET + 2]
    ex, ey, ez = px - dx - ox, py - dy - oy, pz - dz - oz
    e0, e1, e2 = r00 * ex + r10 * ey + r20 * ez, r01 * ex + r11 * ey + r21 * ez, r02 * ex + r12 * ey + r22 * ez
    e3, e4, e5 = _log_rows(_rows_tn(ks[S_ROT_D:S_ROT_D + 9], rl))
    usable, theta, ls, zx, zy, zz = _surface(surf_ok, normal, curvature, r02, r12, r22)
    wm = _filter_wrench(ks, kp, dt, wrench)
    c, h, rho_align = _alignment(ks, kp, dt, wm, e0, e1, e2, e3, e4, e5, theta, ls)
    hold, a0, a1 = _tangent_hold(ks, kp, rl, px, py, pz, wm[2], rho_align)
    if rho_align <= kp[P_COMPLIANT]:
        e0 = e1 = e2 = 0.0
        code = _go_compliant(ks, kp, rl, px - dx, py - dy, pz - dz, usable, zx, zy, zz, t)
        if code != OK:
            return code
    elif usable and kp[P_FOLLOW] > 0.0 and ks[S_RE_ON] == 0.0 and surf_ok == 2.0:
        _follow_planned(ks, kp, dt, rl, zx, zy, zz)
    rho_frc = _force_shaping(kp, ref_wrench, e0, e1, e2, e3, e4, e5)

    vx, vy, vz, wx, wy, wz = twist[0], twist[1], twist[2], twist[3], twist[4], twist[5]
    x0, x1, x2 = r00 * vx + r10 * vy + r20 * vz, r01 * vx + r11 * vy + r21 * vz, r02 * vx + r12 * vy + r22 * vz
    x3, x4, x5 = r00 * wx + r10 * wy + r20 * wz, r01 * wx + r11 * wy + r21 * wz, r02 * wx + r12 * wy + r22 * wz
    _select_damping(ks, kp, dt, wm[2])
    d0, d1, d2, d3, d4, d5 = ks[S_D], ks[S_D + 1], ks[S_D + 2], ks[S_D + 3], ks[S_D + 4], ks[S_D + 5]
    dx0, dx1, dx2, dx3, dx4, dx5 = d0 * x0, d1 * x1, d2 * x2, d3 * x3, d4 * x4, d5 * x5
    ff = _force_wrench(ks, kp, dt, rho_frc, ref_wrench, wm)
    f0, f1, f2, f3, f4, f5 = ff[0], ff[1], ff[2], ff[3], ff[4], ff[5]

    # the variable stiffness's port wrench, and the damping feed-forward of the reference's twist
    neg_rho = -rho_align
    neg_t = -hold if rho_align < hold else neg_rho  # the hold's floor in the tangent plane
    km = P_K_MAX_T
    p0, p1, p2 = neg_t * kp[km] * e0 + a0, neg_t * kp[km + 1] * e1 + a1, neg_rho * kp[km + 2] * e2
    p3, p4, p5 = neg_rho * kp[km + 3] * e3, neg_rho * kp[km + 4] * e4, neg_rho * kp[km + 5] * e5
    if kp[P_DAMP_FF] != 0.0:
        ux, uy, uz, qx, qy, qz = ref_twist[0], ref_twist[1], ref_twist[2], ref_twist[3], ref_twist[4], ref_twist[5]
        p0 += d0 * (r00 * ux + r10 * uy + r20 * uz)
        p1 += d1 * (r01 * ux + r11 * uy + r21 * uz)
        p2 += d2 * (r02 * ux + r12 * uy + r22 * uz)
        p3 += d3 * (r00 * qx + r10 * qy + r20 * qz)
        p4 += d4 * (r01 * qx + r11 * qy + r21 * qz)
        p5 += d5 * (r02 * qx + r12 * qy + r22 * qz)
    if kp[P_FR_ON] != 0.0:
        code, w0, w1 = _friction(ks, kp, dt, rho_align, wrench)
        if code != OK:
            return code
        p0, p1, p2, p3, p4, p5 = p0 + w0, p1 + w1, p2 + 0.0, p3 + 0.0, p4 + 0.0, p5 + 0.0

    p_damp = x0 * dx0 + x1 * dx1 + x2 * dx2 + x3 * dx3 + x4 * dx4 + x5 * dx5
    p_force = x0 * f0 + x1 * f1 + x2 * f2 + x3 * f3 + x4 * f4 + x5 * f5
    m_f = _force_tank(ks, kp, dt, p_force, p_damp)
    p_port = x0 * p0 + x1 * p1 + x2 * p2 + x3 * p3 + x4 * p4 + x5 * p5
    sigma_i = _impedance_tank(ks, kp, dt, p_port, p_damp)

    kc = P_K_CONST
    g0 = -kp[kc] * e0 - dx0 + sigma_i * p0 + m_f * f0
    g1 = -kp[kc + 1] * e1 - dx1 + sigma_i * p1 + m_f * f1
    g2 = -kp[kc + 2] * e2 - dx2 + sigma_i * p2 + m_f * f2
    g3 = -kp[kc + 3] * e3 - dx3 + sigma_i * p3 + m_f * f3
    g4 = -kp[kc + 4] * e4 - dx4 + sigma_i * p4 + m_f * f4
    g5 = -kp[kc + 5] * e5 - dx5 + sigma_i * p5 + m_f * f5

    r = S_RAW
    ks[r], ks[r + 1], ks[r + 2], ks[r + 3], ks[r + 4], ks[r + 5] = rho_align, rho_frc, c, h, theta, ls
    ks[r + 6], ks[r + 7], ks[r + 8], ks[r + 9] = 1.0 if usable else 0.0, sigma_i, m_f, ref_wrench[2] - wm[2]
    ks[r + 10], ks[r + 11], ks[r + 12], ks[r + 13], ks[r + 14], ks[r + 15] = e0, e1, e2, e3, e4, e5
    ks[S_RAW_OK] = 1.0
    f_world[0] = r00 * g0 + r01 * g1 + r02 * g2
    f_world[1] = r10 * g0 + r11 * g1 + r12 * g2
    f_world[2] = r20 * g0 + r21 * g1 + r22 * g2
    f_world[3] = r00 * g3 + r01 * g4 + r02 * g5
    f_world[4] = r10 * g3 + r11 * g4 + r12 * g5
    f_world[5] = r20 * g3 + r21 * g4 + r22 * g5
    return OK
