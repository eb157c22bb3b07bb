"""Parts a user might bring, made here (none is a built-in shape): a square block with a domed top, a
step block with an overhanging lip, written as binary STL with per-face colours (the VisCAM/SolidView
attribute bits tactex reads) or as PLY."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

RED = (1.0, 0.0, 0.0)
GREY = (0.75, 0.75, 0.75)


def dome_height(x: np.ndarray, y: np.ndarray, base_m: float = 0.02, rise_m: float = 0.02,
                width_m: float = 0.08) -> np.ndarray:
    """The dome's top [m]: a Gaussian rise on a flat-topped block (curvature radius 16 cm at its peak)."""
    return base_m + rise_m * np.exp(-(x * x + y * y) / width_m**2)


def dome_mesh(size_m: float = 0.2, n: int = 61, **kw) -> trimesh.Trimesh:
    """A watertight block size_m × size_m [m] (centred at x = y = 0, bottom at z = 0) whose top is
    :func:`dome_height` sampled on an n × n grid."""
    xs = np.linspace(-size_m / 2, size_m / 2, n)
    gx, gy = np.meshgrid(xs, xs)
    top = np.column_stack([gx.ravel(), gy.ravel(), dome_height(gx, gy, **kw).ravel()])
    bottom = top.copy()
    bottom[:, 2] = 0.0
    verts = np.vstack([top, bottom])
    idx = np.arange(n * n).reshape(n, n)
    faces = []
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    faces += [np.column_stack([a, b, c]), np.column_stack([a, c, d])]  # top, up
    off = n * n
    faces += [np.column_stack([a + off, c + off, b + off]), np.column_stack([a + off, d + off, c + off])]
    ring = np.concatenate([idx[0, :], idx[1:, -1], idx[-1, -2::-1], idx[-2:0:-1, 0]])
    r0, r1 = ring, np.roll(ring, -1)
    faces += [np.column_stack([r0, r0 + off, r1]), np.column_stack([r1, r0 + off, r1 + off])]
    mesh = trimesh.Trimesh(verts, np.vstack(faces), process=True)
    trimesh.repair.fix_normals(mesh)
    return mesh


def lip_mesh() -> trimesh.Trimesh:
    """A 20 × 20 cm, 2 cm slab with a 10 cm wide shelf 6 cm up held by a 2 cm post: the shelf hides a third of
    the slab's top (an overhang)."""
    slab = trimesh.creation.box((0.2, 0.2, 0.02))
    slab.apply_translation((0, 0, 0.01))
    post = trimesh.creation.box((0.02, 0.02, 0.04))
    post.apply_translation((0, 0, 0.04))
    shelf = trimesh.creation.box((0.12, 0.12, 0.01))
    shelf.apply_translation((0, 0, 0.065))
    return trimesh.util.concatenate([slab, post, shelf])


def patch_colors(mesh: trimesh.Trimesh, centre_xy=(0.02, -0.01), radius_m: float = 0.05) -> np.ndarray:
    """(F, 3) face colours in [0, 1]: red on the upward faces whose centroid is within ``radius_m`` of
    ``centre_xy`` [m], grey elsewhere."""
    c = mesh.triangles_center
    up = mesh.face_normals[:, 2] > 0.5
    red = up & (np.hypot(c[:, 0] - centre_xy[0], c[:, 1] - centre_xy[1]) <= radius_m)
    return np.where(red[:, None], np.array(RED), np.array(GREY))


def write_color_stl(path: Path, mesh: trimesh.Trimesh, face_rgb: np.ndarray, scale: float = 1.0) -> Path:
    """A binary STL of ``mesh`` (coordinates × ``scale``) with each face's colour in its attribute bytes:
    bit 15 set, 5 bits each of red (10–14), green (5–9) and blue (0–4)."""
    tri = np.asarray(mesh.triangles, dtype=np.float64) * scale
    rgb5 = np.clip(np.rint(np.asarray(face_rgb) * 31), 0, 31).astype(np.uint16)
    attr = (0x8000 | (rgb5[:, 0] << 10) | (rgb5[:, 1] << 5) | rgb5[:, 2]).astype(np.uint16)
    rec = np.zeros(len(tri), dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")])
    rec["n"], rec["v"], rec["a"] = mesh.face_normals, tri, attr
    with open(path, "wb") as f:
        f.write(b"tactex test part".ljust(80, b" "))
        f.write(np.uint32(len(tri)).tobytes())
        f.write(rec.tobytes())
    return Path(path)
