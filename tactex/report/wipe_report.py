"""The run folder of a wiping run (VA-UFIC §III): the curvature profile (Fig. 2), alignment, motion,
force and tank plots (Fig. 3a–d), the explored contact points with their curvature, the policy's commanded
and executed path on the surface and its force per segment (:mod:`.policy_plots`), and the page."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from tactex.control.va_ufic import VaUficParams
from tactex.errors import InputError
from tactex.report.cloud import plot_cloud
from tactex.report.html import cloud_html
from tactex.report.policy_plots import plot_policy_force, plot_policy_path
from tactex.report.run_common import RunReport, figure, finite_rows, save_png, start_report, try_plot
from tactex.report.run_pages import add_sections, plain_page

__all__ = ["CURVATURE_COLORSCALE", "DEFAULT_TANK_LIMITS", "write_wipe_report"]

#: Curvature in both the PNG (matplotlib's coolwarm) and the page: blue low, red high.
CURVATURE_COLORSCALE = [[0.0, "rgb(59,76,192)"], [0.5, "rgb(221,221,221)"], [1.0, "rgb(180,4,38)"]]
#: VA-UFIC Table I tank limits [J], used when the run's config does not carry VaUficParams.
DEFAULT_TANK_LIMITS = {
    "impedance": (VaUficParams().tank_i_lower, VaUficParams().tank_i_upper),
    "force": (VaUficParams().tank_f_lower, VaUficParams().tank_f_upper),
}


def _tank_limits(cfg: Any, metrics: Mapping[str, Any]) -> dict[str, tuple[float, float]]:
    """(lower, upper) tank energies [J]: from the metrics (``tank_impedance_limits_j``, ``tank_force_limits_j``),
    else from VaUficParams inside the config, else VA-UFIC Table I."""
    limits = dict(DEFAULT_TANK_LIMITS)
    if "tank_impedance_limits_j" in metrics and "tank_force_limits_j" in metrics:
        lim_i, lim_f = metrics["tank_impedance_limits_j"], metrics["tank_force_limits_j"]
        return {"impedance": (float(lim_i[0]), float(lim_i[1])), "force": (float(lim_f[0]), float(lim_f[1]))}
    if dataclasses.is_dataclass(cfg):
        for f in dataclasses.fields(cfg):
            v = getattr(cfg, f.name)
            if hasattr(v, "tank_i_upper") and hasattr(v, "tank_f_upper"):
                limits = {"impedance": (float(v.tank_i_lower), float(v.tank_i_upper)),
                          "force": (float(v.tank_f_lower), float(v.tank_f_upper))}
    return limits


def _plot_profile(s: Mapping[str, np.ndarray], profile: Mapping[str, Any], path: Path) -> Path:
    fig, (ax,) = figure(height=3.0)
    y, z = np.asarray(profile["y_m"], float), np.asarray(profile["z_m"], float)
    if y.shape != z.shape or y.ndim != 1:
        raise InputError(f"profile y_m and z_m must be 1-D of equal length, got {y.shape} and {z.shape}")
    ax.plot(y, z, color="0.3", lw=2.0, label="surface")
    tcp = s["tcp_object"]
    contact = s["in_contact"] > 0.5
    ax.plot(tcp[:, 1], tcp[:, 2], color="C0", lw=0.8, alpha=0.6, label="TCP")
    ax.plot(tcp[:, 1], np.where(contact, tcp[:, 2], np.nan), color="C3", lw=1.4, label="TCP in contact")
    ax.set_xlabel("y (object frame) [m]")
    ax.set_ylabel("z (object frame) [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend(fontsize=8)
    ax.set_title("VA-UFIC Fig. 2: TCP trajectory over the surface")
    return save_png(fig, path)


def _plot_rho(s: Mapping[str, np.ndarray], path: Path) -> Path:
    fig, axes = figure(2, height=1.8)
    axes[0].plot(s["t"], s["rho_align"], color="C0")
    axes[0].set_ylabel("ρ_align [-]")
    axes[1].plot(s["t"], s["rho_frc"], color="C1")
    axes[1].set_ylabel("ρ_frc [-]")
    axes[1].set_xlabel("time [s]")
    axes[0].set_title("VA-UFIC Fig. 3a: contact alignment and force shaping")
    return save_png(fig, path)


def _plot_motion(s: Mapping[str, np.ndarray], path: Path) -> Path:
    fig, axes = figure(3, height=1.6)
    for i, ax in enumerate(axes):
        ax.plot(s["t"], s["desired"][:, i], color="C2", lw=1.4, label="desired")
        ax.plot(s["t"], s["tcp"][:, i], color="C0", lw=0.9, label="actual")
        ax.set_ylabel(f"{'xyz'[i]} [m]")
    axes[0].legend(fontsize=8, loc="upper right")
    axes[-1].set_xlabel("time [s]")
    axes[0].set_title("VA-UFIC Fig. 3b: desired vs actual motion (world frame)")
    return save_png(fig, path)


def _plot_wipe_force(s: Mapping[str, np.ndarray], path: Path) -> Path:
    fig, (ax,) = figure(height=2.6)
    ax.plot(s["t"], s["force_set_n"], color="C2", lw=1.4, label="desired")
    ax.plot(s["t"], s["force_z_n"], color="C0", lw=0.9, label="measured (tool z)")
    ax.set_ylabel("force [N]")
    ax.set_xlabel("time [s]")
    ax.legend(fontsize=8)
    ax.set_title("VA-UFIC Fig. 3c: desired vs measured force")
    return save_png(fig, path)


def _plot_tanks(s: Mapping[str, np.ndarray], limits: Mapping[str, tuple[float, float]], path: Path) -> Path:
    fig, axes = figure(2, height=1.8)
    for ax, key, name in ((axes[0], "tank_i_energy_j", "impedance"), (axes[1], "tank_f_energy_j", "force")):
        lo, hi = limits[name]
        ax.plot(s["t"], s[key], color="C0", label="energy")
        ax.axhline(lo, color="C3", ls="--", lw=1.0, label="limits")
        ax.axhline(hi, color="C3", ls="--", lw=1.0)
        ax.set_ylabel(f"{name} tank [J]")
    axes[0].legend(fontsize=8, loc="upper right")
    axes[-1].set_xlabel("time [s]")
    axes[0].set_title("VA-UFIC Fig. 3d: energy tanks")
    return save_png(fig, path)


def _policy_plots(result: Any, metrics: Mapping[str, Any], out: Path, rep: RunReport) -> None:
    """The policy's figures (:mod:`.policy_plots`) when the run recorded its segments."""
    raw, cfg = result.series, result.config
    keys = ("t", "segment", "force_set_n", "force_z_n", "in_contact", "desired", "tcp_object")
    if not all(k in raw for k in keys):
        return
    s = {k: np.asarray(raw[k], dtype=np.float64) for k in keys}
    try_plot(rep, "policy_force_png", plot_policy_force, s, metrics, out / "policy_force.png")
    if hasattr(cfg, "scene") and hasattr(cfg, "object_name"):
        scene = cfg.scene()
        pos, rot = scene.object_pose()
        try_plot(rep, "policy_path_png", plot_policy_path, s, scene.sim_object.surface, pos, rot,
                 out / "policy_path.png")


def write_wipe_report(
    result: Any, out_dir: str | Path, *, label: str | None = None, html_page: bool = True
) -> RunReport:
    """Run folder of a wiping result (VA-UFIC §III); see the module docstring for the files."""
    keys = ("t", "tcp", "desired", "force_z_n", "force_set_n", "in_contact", "rho_align", "rho_frc",
            "tank_i_energy_j", "tank_f_energy_j", "tcp_object")
    s, out, rep = start_report(result, "wipe", out_dir, label, keys)
    metrics, cfg, label = rep.metrics, result.config, rep.label

    explored = result.explored
    pts = np.asarray(explored.points if explored is not None else np.zeros((0, 3)), dtype=np.float64).reshape(-1, 3)
    curv = np.asarray(result.explored_curvature, dtype=np.float64).reshape(-1)
    if curv.shape[0] != pts.shape[0]:
        raise InputError(f"explored_curvature has {curv.shape[0]} values for {pts.shape[0]} explored points")
    contact = s["in_contact"] > 0.5
    tcp_contact = finite_rows(s["tcp"][contact])
    profile = {k: np.asarray(v, dtype=np.float64) for k, v in dict(result.profile).items()}
    np.savez_compressed(out / "cloud.npz", explored_points=pts, explored_curvature=curv, tcp_path_contact=tcp_contact,
                        **{f"profile_{k}": v for k, v in profile.items()})
    rep.files["cloud_data"] = out / "cloud.npz"
    if explored is not None and len(explored) > 0:  # what `tactex explore` loads (normals, curvature)
        from tactex.pointcloud.io import save_ply

        whole = explored if explored.n_target else explored.with_target(np.ones(len(explored)))  # all of it
        rep.files["explored_ply"] = save_ply(whole, out / "explored.ply", extra={"curvature": curv})

    try_plot(rep, "fig2_png", _plot_profile, s, profile, out / "fig2_profile.png")
    rep.files["fig3a_png"] = _plot_rho(s, out / "fig3a_alignment.png")
    rep.files["fig3b_png"] = _plot_motion(s, out / "fig3b_motion.png")
    rep.files["fig3c_png"] = _plot_wipe_force(s, out / "fig3c_force.png")
    rep.files["fig3d_png"] = _plot_tanks(s, _tank_limits(cfg, metrics), out / "fig3d_tanks.png")
    _policy_plots(result, metrics, out, rep)
    if len(pts):
        try_plot(rep, "explored_png", plot_cloud, pts, {"curvature l_s [-]": curv}, out / "explored.png",
                  trajectory=tcp_contact if len(tcp_contact) else None,
                  title=f"{label}: explored contact points, curvature l_s (VA-UFIC eq. 16)",
                  cmaps={"curvature l_s [-]": "coolwarm"})
    else:
        rep.notes.append("no explored points (the tool never touched the surface): no curvature plot")
    if html_page:
        title = f"tactex wipe — {label}"
        if len(pts):
            page = cloud_html(pts, {"curvature l_s [-]": curv}, out / "report.html",
                              trajectory=tcp_contact if len(tcp_contact) else None,
                              colorscales={"curvature l_s [-]": CURVATURE_COLORSCALE}, title=title,
                              normals=explored.normals if explored is not None else None)
        else:
            page = plain_page(out / "report.html", title)
        rep.files["html"] = add_sections(page, rep, title)
    return rep
