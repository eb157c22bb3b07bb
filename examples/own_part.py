"""Make a part of your own to rehearse on: a 20 × 20 cm block with a domed top (4 cm high at its peak),
a red patch of 5 cm radius on it as the dirt, written as a binary STL whose faces carry their colour
(the VisCAM/SolidView attribute bytes), in millimetres as CAD exports it. Then clean it in simulation:

    .venv/bin/python examples/own_part.py /tmp/dome_patch.stl
    .venv/bin/tactex clean --object /tmp/dome_patch.stl --units mm --out runs/own_part

(docs/own_part.md explains what the simulation keeps of a part and what it loses.)
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import trimesh


def dome_block(size_m: float = 0.2, n: int = 61) -> trimesh.Trimesh:
    """A watertight block [m], bottom at z = 0, top z = 2 cm + 2 cm·exp(−r²/(8 cm)²) on an n × n grid."""
    xs = np.linspace(-size_m / 2, size_m / 2, n)
    gx, gy = np.meshgrid(xs, xs)
    top = np.column_stack([gx.ravel(), gy.ravel(), (0.02 + 0.02 * np.exp(-(gx**2 + gy**2) / 0.08**2)).ravel()])
    bottom = top * np.array([1.0, 1.0, 0.0])
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    off = n * n
    ring = np.concatenate([idx[0, :], idx[1:, -1], idx[-1, -2::-1], idx[-2:0:-1, 0]])
    r1 = np.roll(ring, -1)
    faces = np.vstack([np.column_stack(f) for f in ((a, b, c), (a, c, d), (a + off, c + off, b + off),
                                                     (a + off, d + off, c + off), (ring, ring + off, r1),
                                                     (r1, ring + off, r1 + off))])
    mesh = trimesh.Trimesh(np.vstack([top, bottom]), faces, process=True)
    trimesh.repair.fix_normals(mesh)
    return mesh


def write_color_stl(path: Path, mesh: trimesh.Trimesh, face_rgb: np.ndarray, scale: float) -> None:
    """A binary STL, coordinates × ``scale``, each face's colour in its attribute bytes (bit 15 set, 5 bits of
    red at 10–14, green at 5–9, blue at 0–4)."""
    rgb5 = np.clip(np.rint(face_rgb * 31), 0, 31).astype(np.uint16)
    rec = np.zeros(len(mesh.faces), dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")])
    rec["n"], rec["v"] = mesh.face_normals, mesh.triangles * scale
    rec["a"] = 0x8000 | (rgb5[:, 0] << 10) | (rgb5[:, 1] << 5) | rgb5[:, 2]
    with open(path, "wb") as f:
        f.write(b"tactex example part, mm".ljust(80, b" ") + np.uint32(len(rec)).tobytes() + rec.tobytes())


def main(out: str) -> None:
    mesh = dome_block()
    c = mesh.triangles_center
    red = (mesh.face_normals[:, 2] > 0.5) & (np.hypot(c[:, 0] - 0.02, c[:, 1] + 0.01) <= 0.05)
    rgb = np.where(red[:, None], [1.0, 0.0, 0.0], [0.75, 0.75, 0.75])
    write_color_stl(Path(out), mesh, rgb, scale=1000.0)
    print(f"wrote {out}: {len(mesh.faces)} faces in mm, {red.sum()} red; now: tactex clean --object {out} --units mm "
          "--out runs/own_part")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "dome_patch.stl")
