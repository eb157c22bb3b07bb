"""The surface an earlier wipe explored, fed back to plan the next one (VA-UFIC §V: "the explored environment
is fed back to the library to further plan the force-motion policy").

A wipe's run folder holds ``explored.ply``: the tool's contact points (one per 3 mm voxel, world frame [m]),
each with the surface normal seen there (the wrist camera's, or the tool axis where vision had none), and
``cloud.npz``'s ``explored_curvature`` (VA-UFIC eq. 16's l_s, NaN where vision had none). A second wipe of
the same policy on the same part (:class:`ExploredSurface` in ``tactex wipe --replan-from RUN_DIR``) puts its
motion reference on that surface, so the policy's offsets follow the part's shape instead of the tangent
plane at the tool, and hands the controller the normal the reference is about to reach, so the alignment
monitor has less to correct. Where the first pass never touched, the wipe falls back to the tangent plane
and the camera.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from tactex.errors import InputError
from tactex.pointcloud.io import load_ply

__all__ = ["MIN_EXPLORED_POINTS", "ExploredSurface", "SurfacePoint"]

#: Fewest contact points a first pass must have left for a re-plan (a few centimetres of contact).
MIN_EXPLORED_POINTS = 10
#: Neighbours of the local plane fit [-].
NEIGHBOURS = 8


class SurfacePoint(NamedTuple):
    """The explored surface near a query point: the query projected on its local plane [m], that plane's unit
    normal (out of the surface, world frame), its curvature l_s [-] (NaN: unknown) and the query's distance
    along the surface to the nearest contact point [m]."""

    point_m: np.ndarray
    normal: np.ndarray
    curvature: float
    gap_m: float


class ExploredSurface:
    """Contact points with normals and curvature, and the local plane through any query point.

    Args:
        points_m: (N, 3) contact points, world frame [m].
        normals: (N, 3) unit normals out of the surface.
        curvature: (N,) l_s [-] (NaN allowed).
        spacing_m: the points' spacing [m]: the local fit's width.
        source: where they came from (messages).
        metrics: the figures of the pass that explored them (its ``metrics.json``; empty when not known).
    """

    def __init__(self, points_m: np.ndarray, normals: np.ndarray, curvature: np.ndarray, spacing_m: float,
                 source: str = "", metrics: dict | None = None) -> None:
        pts = np.asarray(points_m, dtype=float)
        nrm = np.asarray(normals, dtype=float)
        curv = np.asarray(curvature, dtype=float).reshape(-1)
        where = f" ({source})" if source else ""
        if pts.ndim != 2 or pts.shape[1] != 3 or nrm.shape != pts.shape or curv.shape != (len(pts),):
            raise InputError(f"an explored surface needs (N, 3) points, (N, 3) normals and (N,) curvatures{where}, "
                             f"got {pts.shape}, {nrm.shape}, {curv.shape}")
        length = np.linalg.norm(nrm, axis=1)
        keep = np.isfinite(pts).all(axis=1) & np.isfinite(nrm).all(axis=1) & (length > 1e-9)
        if keep.sum() < MIN_EXPLORED_POINTS:
            raise InputError(f"the explored surface{where} has {int(keep.sum())} usable contact points; a re-plan "
                             f"needs at least {MIN_EXPLORED_POINTS} (did the first pass touch the surface?)")
        if not (np.isfinite(spacing_m) and spacing_m > 0):
            raise InputError(f"spacing_m must be > 0 [m], got {spacing_m!r}")
        self.points_m, self.normals = pts[keep], nrm[keep] / length[keep, None]
        self.curvature, self.spacing_m, self.source = curv[keep], float(spacing_m), source
        self.metrics = dict(metrics or {})
        self.tree = cKDTree(self.points_m)

    def __len__(self) -> int:
        return len(self.points_m)

    @staticmethod
    def folder_problem(run_dir: str | Path) -> str:
        """Why ``run_dir`` holds no explored surface to read, or ``""``: one line, for a config check or a refusal."""
        run = Path(run_dir)
        if not run.is_dir():
            return f"--replan-from {run}: no such run folder (give the --out folder of an earlier wipe)"
        if not (run / "explored.ply").is_file():
            return (f"--replan-from {run}: no explored.ply in it: is it a wipe's run folder, and did that wipe touch "
                    "the surface?")
        return ""

    @classmethod
    def from_run(cls, run_dir: str | Path) -> ExploredSurface:
        """The explored surface of the wipe whose run folder is ``run_dir`` (``explored.ply`` and ``cloud.npz``)."""
        run = Path(run_dir)
        problem = cls.folder_problem(run)
        if problem:
            raise InputError(problem)
        ply = run / "explored.ply"
        cloud = load_ply(ply)
        if cloud.normals is None:
            raise InputError(f"--replan-from {run}: explored.ply has no normals (nx ny nz)")
        curvature = np.full(len(cloud), np.nan)
        npz = run / "cloud.npz"
        if npz.is_file():
            with np.load(npz, allow_pickle=False) as data:
                if "explored_curvature" in data.files and data["explored_curvature"].shape == (len(cloud),):
                    curvature = np.asarray(data["explored_curvature"], dtype=float)
        try:
            metrics = json.loads((run / "metrics.json").read_text(encoding="utf-8"))
        except (OSError, ValueError):
            metrics = {}  # a folder without its figures still re-plans; the comparison is then empty
        return cls(cloud.points, cloud.normals, curvature, cloud.spacing, source=str(run),
                   metrics=metrics if isinstance(metrics, dict) else {})

    @staticmethod
    def run_object(run_dir: str | Path) -> str | None:
        """The object an earlier wipe ran on (its ``config.json``), None when the folder does not say."""
        path = Path(run_dir) / "config.json"
        try:
            cfg = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None
        name = cfg.get("object_name") if isinstance(cfg, dict) else None
        return name if isinstance(name, str) else None

    def near(self, query_m: np.ndarray) -> SurfacePoint:
        """The local plane of the contact points near ``query_m`` (3,) [m]: their Gaussian-weighted mean point
        and normal (width: two spacings), and the query projected on it."""
        q = np.asarray(query_m, dtype=float)
        k = min(NEIGHBOURS, len(self))
        dist, idx = self.tree.query(q, k=k)
        sigma = 2.0 * self.spacing_m
        w = np.exp(-0.5 * ((dist - dist[0]) / sigma) ** 2)
        w /= w.sum()
        centre = w @ self.points_m[idx]
        normal = w @ self.normals[idx]
        normal /= np.linalg.norm(normal)
        on_plane = q - ((q - centre) @ normal) * normal
        curv = self.curvature[idx]
        finite = np.isfinite(curv)
        curvature = float(w[finite] @ curv[finite] / w[finite].sum()) if finite.any() else float("nan")
        gap = float(np.linalg.norm(on_plane - self.points_m[idx[0]]))
        return SurfacePoint(on_plane, normal, curvature, gap)
