"""A big synthetic scene for the 3-D page's tests: a wavy floor 6 m × 4 m with five people-sized
ellipsoids standing on it (≈ a room scan after a voxel grid, such as PCL's five_people.pcd, 240 000
points), a target on one person's head and shoulders, and a path that spirals over the floor and then
winds up around that person, on the surface throughout."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: The people's centres [m] and half-axes [m].
CENTRES = np.array([[-2.4, 0.3, 0.9], [-1.2, -0.3, 0.9], [0.0, 0.3, 0.9], [1.2, -0.3, 0.9], [2.4, 0.3, 0.9]])
AXES = np.array([0.25, 0.18, 0.85])
WAVE_M = 0.02


@dataclass(frozen=True)
class Scene:
    points: np.ndarray  # (N, 3) [m]
    normals: np.ndarray  # (N, 3) unit, outwards / up
    target: np.ndarray  # (N,) bool
    path: np.ndarray  # (T, 3) [m], on the surface


def _floor_z(xy: np.ndarray) -> np.ndarray:
    return WAVE_M * np.sin(3 * xy[:, 0]) * np.cos(2 * xy[:, 1])


def _floor_normals(xy: np.ndarray) -> np.ndarray:
    dzdx = 3 * WAVE_M * np.cos(3 * xy[:, 0]) * np.cos(2 * xy[:, 1])
    dzdy = -2 * WAVE_M * np.sin(3 * xy[:, 0]) * np.sin(2 * xy[:, 1])
    n = np.c_[-dzdx, -dzdy, np.ones(len(xy))]
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def people_scene(n: int = 240_000, seed: int = 0, path_steps: int = 20_000) -> Scene:
    """``n`` points: half on the floor, half on the five people; the path is ``path_steps`` points."""
    rng = np.random.default_rng(seed)
    n_floor = n // 2
    xy = rng.uniform([-3.0, -2.0], [3.0, 2.0], size=(n_floor, 2))
    pts, nrm = [np.c_[xy, _floor_z(xy)]], [_floor_normals(xy)]
    per = [len(c) for c in np.array_split(np.arange(n - n_floor), len(CENTRES))]
    for centre, m in zip(CENTRES, per, strict=True):
        d = rng.normal(size=(m, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        pts.append(centre + d * AXES)
        g = d / AXES  # the ellipsoid's gradient: its outward normal
        nrm.append(g / np.linalg.norm(g, axis=1, keepdims=True))
    points, normals = np.vstack(pts), np.vstack(nrm)
    target = (points[:, 2] > 1.2) & (np.abs(points[:, 0] - CENTRES[0, 0]) < 0.5)
    half = path_steps // 2
    t = np.linspace(0.05, 1.0, half)
    floor = np.c_[-1.0 + 1.6 * t * np.cos(8 * np.pi * t), 1.2 * t * np.sin(8 * np.pi * t)]
    s = np.linspace(0.0, 1.0, path_steps - half)
    u, height = 10 * np.pi * s, 0.2 + 0.7 * s  # around the first person, up to the shoulders
    w = np.sqrt(np.clip(1.0 - ((height - CENTRES[0, 2]) / AXES[2]) ** 2, 0.0, None))
    body = CENTRES[0] + np.c_[AXES[0] * w * np.cos(u), AXES[1] * w * np.sin(u), height - CENTRES[0, 2]]
    path = np.vstack([np.c_[floor, _floor_z(floor)], body])
    return Scene(points, normals, target, path)
