"""Full-length closed-loop programs (issue 6): cleaning on the plate and the bowl with the raster and
no-feedback baselines, and VA-UFIC wiping (with the measured-friction compensation, and without it:
the paper's law) against the Cartesian-impedance baseline. Wiping motion errors are per axis of the
base frame, as the paper's §IV (``motion_mae_tool_*`` give the tool frame).

Quality numbers (dirt removed, force within band, force/motion errors, tank energies) and the
wall-clock real-time factor of each run are recorded under ``tasks.*``.
"""

from __future__ import annotations

from tactex.tasks.clean import CleanConfig, run_clean
from tactex.tasks.wipe import WipeConfig, run_wipe

CLEAN_OBJECTS = ("plate", "bowl")
CLEAN_METHODS = {"tactex": "", "raster": "raster", "no_feedback": "no_feedback"}
CLEAN_KEYS = ("dirt_removed_fraction", "force_within_20pct_fraction", "max_contact_force_n", "sim_time_s",
              "vision_updates", "contact_time_s", "wall_time_s", "torque_rate_clip_ticks")
WIPE_KEYS = ("force_mae_n", "force_rmse_n", "force_mae_aligned_n", "force_rmse_aligned_n", "contact_fraction",
             "contact_fraction_after_first_contact",
             "aligned_at_s", "explore_time_s", "max_force_n", "wall_time_s", "sim_time_s", "explored_points",
             "explored_normal_error_deg_median", "explored_normal_error_deg_p95",
             "explored_depth_below_surface_m_median", "explored_inclination_span_deg",
             "friction_compensation_energy_j", "torque_rate_clip_ticks")

TARGETS: dict[str, tuple[str, float]] = {}
for _obj in CLEAN_OBJECTS:
    TARGETS[f"tasks.clean.{_obj}.tactex.dirt_removed_fraction"] = (">=", 0.95)
    TARGETS[f"tasks.clean.{_obj}.tactex.force_within_20pct_fraction"] = (">=", 0.90)
    TARGETS[f"tasks.clean.{_obj}.tactex.max_contact_force_n"] = ("<=", 20.0)
    # torques smooth enough for a real arm (the safety layer's rate limiter never engages)
    TARGETS[f"tasks.clean.{_obj}.tactex.torque_rate_clip_ticks"] = ("<=", 0)
TARGETS.update({
    "tasks.wipe.va_ufic.force_mae_n": ("<=", 0.5),
    "tasks.wipe.va_ufic.torque_rate_clip_ticks": ("<=", 0),
    "tasks.wipe.va_ufic.force_rmse_n": ("<=", 1.0),
    "tasks.wipe.va_ufic.motion_mae_x_m": ("<=", 0.003),
    "tasks.wipe.va_ufic.motion_mae_y_m": ("<=", 0.003),
    "tasks.wipe.va_ufic.motion_mae_z_m": ("<=", 0.003),
    # force and motion errors count contact (and aligned) ticks only, so losing contact must not pay
    "tasks.wipe.va_ufic.contact_fraction_after_first_contact": (">=", 0.95),
    "tasks.wipe.va_ufic.tank_impedance_in_limits": (">=", 1.0),
    "tasks.wipe.va_ufic.tank_force_in_limits": (">=", 1.0),
})


def _clean(obj: str, baseline: str) -> dict:
    r = run_clean(CleanConfig(object_name=obj, baseline=baseline), progress=False)
    out = {k: r.metrics[k] for k in CLEAN_KEYS}
    out["realtime_factor"] = r.metrics["sim_time_s"] / r.metrics["wall_time_s"]
    return out


def _wipe(baseline: str, friction_compensation: bool = True) -> dict:
    r = run_wipe(WipeConfig(baseline=baseline, friction_compensation=friction_compensation), progress=False)
    m = r.metrics
    out = {k: m.get(k) for k in WIPE_KEYS}
    for i, axis in enumerate("xyz"):
        out[f"motion_mae_{axis}_m"] = m["motion_mae_m"][i]
        out[f"motion_rmse_{axis}_m"] = m["motion_rmse_m"][i]
        out[f"motion_mae_all_contact_{axis}_m"] = m["motion_mae_all_contact_m"][i]
        out[f"motion_mae_tool_{axis}_m"] = m["motion_mae_tool_m"][i]
    lo_i, hi_i = m["tank_impedance_limits_j"]
    lo_f, hi_f = m["tank_force_limits_j"]
    ti, tf = m["tank_impedance_energy_j"], m["tank_force_energy_j"]
    out["tank_impedance_energy_min_j"], out["tank_impedance_energy_max_j"] = ti["min"], ti["max"]
    out["tank_force_energy_min_j"], out["tank_force_energy_max_j"] = tf["min"], tf["max"]
    if baseline == "":
        out["tank_impedance_in_limits"] = float(lo_i - 1e-9 <= ti["min"] and ti["max"] <= hi_i + 1e-9)
        out["tank_force_in_limits"] = float(lo_f - 1e-9 <= tf["min"] and tf["max"] <= hi_f + 1e-9)
    out["realtime_factor"] = m["sim_time_s"] / m["wall_time_s"]
    return out


def run(args) -> dict:
    quick = getattr(args, "quick", False)
    clean: dict = {}
    for obj in CLEAN_OBJECTS[:1] if quick else CLEAN_OBJECTS:
        clean[obj] = {}
        for name, baseline in CLEAN_METHODS.items():
            if quick and baseline:
                continue
            print(f"   clean {obj} {name} ...", flush=True)
            clean[obj][name] = _clean(obj, baseline)
    wipe: dict = {}
    variants = {"va_ufic": ("", True), "va_ufic_no_friction_comp": ("", False), "cartesian": ("cartesian", True)}
    for name, (baseline, friction_comp) in variants.items():
        if quick and name != "va_ufic":
            continue
        print(f"   wipe {name} ...", flush=True)
        wipe[name] = _wipe(baseline, friction_comp)
    return {"tasks": {"clean": clean, "wipe": wipe}}
