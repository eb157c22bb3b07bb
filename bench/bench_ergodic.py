"""HEDAC exploration on the TEC clouds: time per step and coverage residual vs path length.

Clouds: bun270_X, cup_X, plate_shapes after 3 mm voxels, target = red ≥ 1.0, basis n_K = 200
built with 40 Laplacian neighbours (the authors' ``nb_boundary_neighbors``: the bunny is one
connected object). Agent radius 7.5 mm (15 mm on the plate), α = 10, Table II limits.

* ``ergodic.<cloud>.step_time_median_s``: one full step (neighbours, fit, projection, coverage,
  source, diffusion, gradient, agent), median over ``STEPS_TIMED`` steps from the first start, as
  the explorer runs by default: compiled by numba when the ``fast`` extra is installed
  (``step_kernel`` says which ran, ``compiled_share`` the share of steps the compiled step took; the rest
  fell back to numpy). ``step_time_median_numpy_s`` is the same steps with ``compiled=False``.
* ``ergodic.<cloud>.residual_at_path_m``: coverage residual (the authors' metric) when the agent
  has travelled 0.5 / 1 / 2 m, on the surface plus through the air of its relocations (issue 18;
  ``relocations_per_start`` counts them), mean of the ten starts ``*_x0_arr_10.npz``;
  ``ratio_to_authors`` divides by the authors' released implementation (issue 2's figures);
  ``residual_at_1m_per_start`` the ten values behind the mean at 1 m.
* ``ergodic.<cloud>.parked_share``: share of steps after which the agent is less than 2 voxels
  from where it was 20 steps earlier (an agent oscillating in place: path without coverage).
* ``ergodic.<cloud>.start_gap_voxels``: per start, the widest scan gap [voxels] on the best way
  from the start to the target over the cloud (single linkage; None beyond 10 voxels). An agent
  that stays within ``max_off_cloud_voxels`` voxels of the cloud crosses at most 2·max_off_cloud_voxels, and
  only where the far side lies along its tangent plane (bunny start 9: 14.9 mm, 61° out of it).
* ``ergodic.<cloud>.variants.<name>.*``: the same quality figures with one choice changed:
  ``eq2_domain`` normalises the coverage over the whole cloud (eq. 2 literally, instead of over
  the target's support), ``no_hops`` never hops a scan hole (``max_bridge_voxels = 0``), ``cooling``
  adds a heat loss in the form of eq. 4's −u term, β = 0.05 per step (``HedacConfig.cooling``, a
  tuned value, off by default).
* ``ergodic.<cloud>.realized_accel_over_limit_share`` / ``realized_accel_max_ratio``: the agent's
  realised tangential velocity change per step, |v_k − transport(v_k−1)|, over a_max·dt: the
  commands keep the limit exactly; the landing on a curved patch and slides along scan edges can
  exceed it (reported, not a target). Every step counts, hops included (they keep the limit too);
  the first starts from rest. ``realized_accel_max_ratio_off_edges`` leaves out the steps that
  started at a scan edge (the explorer's own test), ``scan_edge_step_share`` is their share.
* ``ergodic.<cloud>.max_off_cloud_mm`` / ``max_off_cloud_walking_mm`` / ``mean_step_mm``: the
  agent's largest distance to the nearest cloud point (with and without the hops across scan
  holes, where it is on the chord between the two sides) and its mean step (the speed limit is
  one voxel = 3 mm per step); ``hops_per_start`` the hops each start took.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from tactex.ergodic import HedacConfig, HedacExplorer, transport
from tactex.ergodic.explorer import EDGE_OFFSET
from tactex.ergodic.relocation import RelocationCommand
from tactex.pointcloud import load_ply, target_from_channel, voxel_down_sample
from tactex.spectral import build_basis

DATA = Path(os.environ.get("TACTEX_SHARED_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))
DATA = DATA / "tactile_ergodic_control"
CLOUDS = ("bun270_X", "cup_X", "plate_shapes")
PATHS_M = (0.5, 1.0, 2.0)
MAX_STEPS = 3000  # a start that never reaches 2 m (stuck) is scored where it stands
STEPS_TIMED = 1000
#: Reference, not measured here: the coverage residual of the authors' released implementation at
#: 0.5 / 1 / 2 m of path, mean of the ten starts, as quoted in the issue (measured by its author on
#: this kind of machine). The ratio_to_authors figures compare against these quoted values.
AUTHORS = {
    "bun270_X": (0.28, 0.15, 0.12),
    "cup_X": (0.18, 0.18, 0.18),
    "plate_shapes": (0.49, 0.20, 0.04),
}
VARIANTS = {
    "eq2_domain": {"coverage_normalization": "domain"},
    "no_hops": {"max_bridge_voxels": 0.0},
    "cooling": {"cooling": 0.05},
}
PARK_WINDOW = 20  # steps
PARK_VOXELS = 2.0  # closer than this to the position PARK_WINDOW steps earlier = parked
GAP_VOXELS = (1.5, 2.0, 2.5, 3.0, 3.5, 4.0, 5.0, 6.0, 8.0, 10.0)

TARGETS = {f"ergodic.{c}.step_time_median_s": ("<=", 0.2e-3) for c in CLOUDS}
for _c in CLOUDS:
    for _p in ("0.5", "1"):
        TARGETS[f"ergodic.{_c}.ratio_to_authors.{_p}"] = ("<=", 0.8)


def _load(name: str):
    cloud = target_from_channel(voxel_down_sample(load_ply(DATA / f"{name}.ply"), 0.003), "red", 1.0)
    with np.load(DATA / f"{name}_x0_arr_10.npz", allow_pickle=False) as z:
        x0 = np.array(z["x0_arr"], dtype=float)
    return cloud, x0


def _residual_vs_path(ex: HedacExplorer, x0: np.ndarray) -> dict:
    """One start: the residual at each of PATHS_M, the largest distances off the cloud [m] (all
    steps, walking steps), the mean step [m], the parked share, and the realised acceleration of
    each step: |v_k − transport(v_k−1)| of the tangential velocities over a_max·dt, and whether the
    step started at a scan edge."""
    prev = ex.reset(x0)[0]
    marks = list(PATHS_M)
    out: list[float] = []
    off = [0.0, 0.0]  # all steps, walking steps only
    track = [ex.positions[0]]
    a_dt = ex.config.max_acceleration * ex.spacing / ex.config.step_duration_s
    v_prev = np.zeros(3)
    accel, at_edge = [], []
    while marks and ex.step_count < MAX_STEPS:
        hopping = ex.hopping(0)
        cmd = ex.step()
        track.append(cmd.point)
        if isinstance(cmd, RelocationCommand):  # a flight, not a step of the walk: it lands at rest
            v_prev, prev = np.zeros(3), cmd
        else:
            v = cmd.velocity - float(cmd.velocity @ cmd.normal) * cmd.normal
            accel.append(float(np.linalg.norm(v - transport(v_prev, cmd.normal))) / a_dt)
            at_edge.append(_at_scan_edge(ex, prev))
            v_prev, prev = v, cmd
        if ex.step_count % 5 == 0 or hopping or ex.hopping(0):
            dist = float(ex._tree.query(cmd.point)[0])
            off[0] = max(off[0], dist)
            if not (hopping or ex.hopping(0)):
                off[1] = max(off[1], dist)
        while marks and ex.total_path_length >= marks[0]:
            out.append(ex.coverage_residual())
            marks.pop(0)
    out += [ex.coverage_residual()] * len(marks)
    t = np.asarray(track)
    moved = np.linalg.norm(t[PARK_WINDOW:] - t[:-PARK_WINDOW], axis=1)
    parked = float((moved < PARK_VOXELS * ex.spacing).mean()) if moved.size else 0.0
    return {"residual": out, "off": off, "mean_step": ex.path_length / max(ex.step_count, 1), "parked": parked,
            "accel": np.asarray(accel), "at_edge": np.asarray(at_edge, dtype=bool)}


def _at_scan_edge(ex: HedacExplorer, cmd) -> bool:
    """The explorer's scan-edge test at a command's point: the centroid of its n_N nearest cloud
    points, on the tangent plane, lies more than EDGE_OFFSET neighbourhood radii from it."""
    d = ex.cloud.points[ex._tree.query(cmd.point, k=ex.config.n_neighbors_fit)[1]] - cmd.point
    uv = np.c_[d @ cmd.tangent_u, d @ cmd.tangent_v].mean(axis=0)
    return bool(np.linalg.norm(uv) > EDGE_OFFSET * np.sqrt((d * d).sum(axis=1).max()))


def _start_gaps(cloud, starts: np.ndarray) -> list[float | None]:
    """Per start, the smallest link length [voxels] of GAP_VOXELS joining it to the target."""
    tree = cKDTree(cloud.points)
    first = tree.query(starts)[1]
    target = cloud.target > 0
    gaps: list[float | None] = [None] * len(starts)
    for g in GAP_VOXELS:
        pairs = tree.query_pairs(g * cloud.spacing, output_type="ndarray")
        n = len(cloud)
        graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
        labels = connected_components(graph, directed=False)[1]
        with_target = np.zeros(labels.max() + 1, dtype=bool)
        with_target[labels[target]] = True
        for i, j in enumerate(first):
            if gaps[i] is None and with_target[labels[j]]:
                gaps[i] = g
        if all(v is not None for v in gaps):
            break
    return gaps


def _quality(ex: HedacExplorer, starts: np.ndarray, name: str) -> dict:
    runs, hops, relocations = [], [], []
    for x in starts:
        runs.append(_residual_vs_path(ex, x))
        hops.append(ex.bridges_taken)
        relocations.append(len(ex.relocations))
    rows = [r["residual"] for r in runs]
    mean = np.mean(rows, axis=0)
    res = {f"{p:g}": float(v) for p, v in zip(PATHS_M, mean, strict=True)}
    ratio = {f"{p:g}": float(v / a) for p, v, a in zip(PATHS_M, mean, AUTHORS[name], strict=True)}
    accel = np.concatenate([r["accel"] for r in runs])
    edge = np.concatenate([r["at_edge"] for r in runs])
    return {
        "residual_at_path_m": res,
        "ratio_to_authors": ratio,
        "residual_at_1m_per_start": [round(float(r[1]), 4) for r in rows],
        "parked_share": float(np.mean([r["parked"] for r in runs])),
        "max_off_cloud_mm": 1e3 * max(r["off"][0] for r in runs),
        "max_off_cloud_walking_mm": 1e3 * max(r["off"][1] for r in runs),
        "mean_step_mm": 1e3 * float(np.mean([r["mean_step"] for r in runs])),
        "hops_per_start": hops,
        "relocations_per_start": relocations,
        "realized_accel_over_limit_share": float((accel > 1.0 + 1e-6).mean()),
        "realized_accel_max_ratio": float(accel.max()),
        "realized_accel_max_ratio_off_edges": float(accel[~edge].max()) if (~edge).any() else 0.0,
        "scan_edge_step_share": float(edge.mean()),
    }


def _step_times(ex: HedacExplorer, x0: np.ndarray, steps: int) -> np.ndarray:
    """Wall time [s] of each of ``steps`` steps from x0 (the explorer is built, and its compiled
    step made or loaded, before the first)."""
    ex.reset(x0)
    times = np.empty(steps)
    for k in range(steps):
        t0 = time.perf_counter()
        ex.step()
        times[k] = time.perf_counter() - t0
    return times


def run(args) -> dict:
    if not DATA.is_dir():
        print(f"   skipped: {DATA} not found (the TEC clouds live in ../shared/data)")
        return {"ergodic": {"skipped": f"{DATA} not found"}}
    quick = bool(getattr(args, "quick", False))
    out: dict = {}
    table = []
    for name in CLOUDS:
        cloud, x0 = _load(name)
        basis = build_basis(cloud, n_eigen=200, n_neighbors=40, cache=False)
        radius = 0.015 if name.startswith("plate") else 0.0075
        ex = HedacExplorer(cloud, basis, HedacConfig(agent_radius_m=radius))
        n_timed = STEPS_TIMED // (4 if quick else 1)
        times = _step_times(ex, x0[0], n_timed)
        numpy_times = _step_times(ex.with_config(compiled=False), x0[0], n_timed)
        starts = x0[:3] if quick else x0
        res = {
            "step_time_median_s": float(np.median(times)),
            "step_time_p90_s": float(np.percentile(times, 90)),
            "step_kernel": "numba" if ex.compiled_steps else "numpy",
            "compiled_share": ex.compiled_steps / n_timed,
            "step_time_median_numpy_s": float(np.median(numpy_times)),
        }
        res.update(_quality(ex, starts, name))
        res["start_gap_voxels"] = _start_gaps(cloud, starts)
        res["variants"] = {
            label: _quality(HedacExplorer(cloud, basis, HedacConfig(agent_radius_m=radius, **change)), starts, name)
            for label, change in VARIANTS.items()
        }
        out[name] = res
        for label, r in (("default", res), *res["variants"].items()):
            row = (r["residual_at_path_m"], r["ratio_to_authors"], AUTHORS[name], r["parked_share"])
            table.append((name, label, *row))
    print(f"   {'cloud':13s} {'setting':10s} residual at 0.5/1/2 m     authors            ratio            parked")
    for name, label, r, q, a, parked in table:
        vals = "/".join(f"{v:.3f}" for v in r.values())
        ratios = "/".join(f"{v:.2f}" for v in q.values())
        print(f"   {name:13s} {label:10s} {vals:24s} {'/'.join(f'{v:.2f}' for v in a):18s} {ratios:16s} {parked:.2f}")
    print(f"   {'cloud':13s} step median: default (which step, share compiled)   numpy")
    for name, r in out.items():
        print(f"   {name:13s} {r['step_time_median_s'] * 1e3:.3f} ms ({r['step_kernel']}, {r['compiled_share']:.0%})"
              f"{'':22s} {r['step_time_median_numpy_s'] * 1e3:.3f} ms")
    return {"ergodic": out}
