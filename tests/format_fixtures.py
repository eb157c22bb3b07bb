"""Small public-format files written here, byte by byte, for the format tests: PCD headers of PCL's
versions .5, .6 and .7 in ascii, binary and binary_compressed; meshes (PLY with faces, STL, OBJ);
and a camera-like coloured cloud (white table, beige board, red marker)."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

PCD_VERSIONS = (".5", ".6", ".7")
PCD_ENCODINGS = ("ascii", "binary", "binary_compressed")

#: Colours as a camera sees them under room light (8-bit RGB), with per-point noise added.
WHITE = (238, 236, 230)
BEIGE = (222, 200, 160)
RED = (190, 42, 48)


def pcd_bytes(points: np.ndarray, version: str, encoding: str, rgb: np.ndarray | None = None) -> bytes:
    """A PCD file as PCL writes it at ``version``: .5 has no WIDTH/HEIGHT/VIEWPOINT (and here no
    COUNT), .6 no VIEWPOINT, .7 everything. ``rgb`` (N, 3) uint8 is packed into a float field as
    PCL does (the bits of 0x00RRGGBB)."""
    n = len(points)
    fields, sizes, types = ["x", "y", "z"], ["4", "4", "4"], ["F", "F", "F"]
    cols = [points[:, i].astype("<f4") for i in range(3)]
    if rgb is not None:
        packed = (rgb[:, 0].astype(np.uint32) << 16) | (rgb[:, 1].astype(np.uint32) << 8) | rgb[:, 2].astype(np.uint32)
        fields.append("rgb")
        sizes.append("4")
        types.append("F")
        cols.append(packed.astype("<u4").view("<f4"))
    lines = [f"# .PCD v{version} - Point Cloud Data file format", f"VERSION {version}", f"FIELDS {' '.join(fields)}",
             f"SIZE {' '.join(sizes)}", f"TYPE {' '.join(types)}"]
    if version != ".5":
        lines += [f"COUNT {' '.join('1' for _ in fields)}", f"WIDTH {n}", "HEIGHT 1"]
    if version == ".7":
        lines.append("VIEWPOINT 0 0 0 1 0 0 0")
    lines += [f"POINTS {n}", f"DATA {encoding}"]
    head = ("\n".join(lines) + "\n").encode("ascii")
    if encoding == "ascii":
        rows = []
        for i in range(n):
            values = [repr(float(c[i])) for c in cols[:3]]
            if rgb is not None:  # PCL prints the packed integer in ascii files
                values.append(str(int(cols[3][i : i + 1].view("<u4")[0])))
            rows.append(" ".join(values))
        return head + ("\n".join(rows) + "\n").encode("ascii")
    record = np.empty(n, dtype=[(f, "<f4") for f in fields])
    for f, c in zip(fields, cols, strict=True):
        record[f] = c
    if encoding == "binary":
        return head + record.tobytes()
    import lzf

    columnar = b"".join(np.ascontiguousarray(record[f]).tobytes() for f in fields)  # field after field
    packed_data = lzf.compress(columnar)
    return head + struct.pack("<II", len(packed_data), len(columnar)) + packed_data


def write_pcd(path: Path, points: np.ndarray, version: str, encoding: str, rgb: np.ndarray | None = None) -> Path:
    path.write_bytes(pcd_bytes(points, version, encoding, rgb))
    return path


def bumpy_patch(n_side: int = 20, size_m: float = 0.06, seed: int = 0) -> np.ndarray:
    """A gently curved square patch of n_side² points [m]."""
    g = np.linspace(0.0, size_m, n_side)
    x, y = np.meshgrid(g, g)
    z = 0.005 * np.sin(x / size_m * np.pi) + 1e-4 * np.random.default_rng(seed).standard_normal(x.shape)
    return np.column_stack([x.ravel(), y.ravel(), z.ravel()])


def camera_like_cloud(spacing_m: float = 0.002, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A 0.2 m × 0.2 m table seen by a camera: white table, a beige board on its left half, a red
    marker stroke (8 mm wide) across the board and the table, colour noise of σ = 6 levels, and a few
    NaN points as an organised cloud pads them. Returns points (N, 3) [m], rgb (N, 3) uint8 and the
    mask of the red stroke."""
    rng = np.random.default_rng(seed)
    g = np.arange(0.0, 0.2, spacing_m)
    x, y = np.meshgrid(g, g)
    pts = np.column_stack([x.ravel(), y.ravel(), 0.4 + 0.0005 * rng.standard_normal(x.size)])
    rgb = np.tile(np.array(WHITE, dtype=float), (len(pts), 1))
    board = pts[:, 0] < 0.1
    rgb[board] = BEIGE
    red = np.abs(pts[:, 1] - 0.1) < 0.004
    rgb[red] = RED
    rgb = np.clip(rgb + 6.0 * rng.standard_normal(rgb.shape), 0, 255).astype(np.uint8)
    nan = rng.choice(len(pts), 25, replace=False)
    pts[nan] = np.nan
    return pts, rgb, red


def box_mesh(extent_m: float = 0.08, colored: bool = False):
    """A trimesh box of edge ``extent_m`` [m]; with ``colored``, vertex colours red on its top four
    corners and white on the bottom ones."""
    import trimesh

    mesh = trimesh.creation.box(extents=(extent_m, extent_m, extent_m))
    if colored:
        top = mesh.vertices[:, 2] > 0
        colors = np.where(top[:, None], [200, 30, 40, 255], [240, 240, 240, 255]).astype(np.uint8)
        mesh.visual.vertex_colors = colors
    return mesh
