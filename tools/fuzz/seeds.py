"""Small valid files, one list per fuzzed reader: the corpus each harness starts from.

Written here byte by byte (no test fixtures imported), so ``make fuzz`` needs nothing but the package.
The PLY and PCD seeds also include the first rows of the TEC clouds in ``../shared/data`` when present.
"""

from __future__ import annotations

import io
import json
import struct
from pathlib import Path

import numpy as np

#: The TEC point clouds (read-only); their first rows become PLY and PCD seeds.
SHARED_DATA = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "tactile_ergodic_control"
#: Rows of each seed cloud: enough structure for the mutator, small enough for thousands of runs a second.
N_ROWS = 24


def _points(n: int = N_ROWS, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).random((n, 3)) * 0.05


def _shared_points() -> list[np.ndarray]:
    out = []
    for ply in sorted(SHARED_DATA.glob("*.ply")) if SHARED_DATA.is_dir() else []:
        from plyfile import PlyData

        v = PlyData.read(str(ply))["vertex"].data[:N_ROWS]
        out.append(np.column_stack([v["x"], v["y"], v["z"]]).astype(np.float64))
    return out


def _ply(points: np.ndarray, fmt: str, *, colors: bool = True, faces: np.ndarray | None = None,
         comments: tuple[str, ...] = ()) -> bytes:
    n = len(points)
    props = ["double x", "double y", "double z"] + (["uchar red", "uchar green", "uchar blue"] if colors else [])
    head = ["ply", f"format {fmt} 1.0", *[f"comment {c}" for c in comments], f"element vertex {n}",
            *[f"property {p}" for p in props]]
    if faces is not None:
        head += [f"element face {len(faces)}", "property list uchar int vertex_indices"]
    head.append("end_header")
    text = ("\n".join(head) + "\n").encode("ascii")
    rgb = (np.arange(n * 3).reshape(n, 3) * 37 % 256).astype(np.uint8)
    if fmt == "ascii":
        rows = [" ".join([*(repr(float(c)) for c in p), *((str(int(c)) for c in rgb[i]) if colors else ())])
                for i, p in enumerate(points)]
        if faces is not None:
            rows += [" ".join(["3", *(str(int(i)) for i in f)]) for f in faces]
        return text + ("\n".join(rows) + "\n").encode("ascii")
    end = "<" if fmt == "binary_little_endian" else ">"
    dtype = [("x", end + "f8"), ("y", end + "f8"), ("z", end + "f8")] + (
        [("red", "u1"), ("green", "u1"), ("blue", "u1")] if colors else [])
    rec = np.empty(n, dtype=dtype)
    rec["x"], rec["y"], rec["z"] = points.T
    if colors:
        rec["red"], rec["green"], rec["blue"] = rgb.T
    body = rec.tobytes()
    if faces is not None:
        body += b"".join(struct.pack(end + "B3i", 3, *map(int, f)) for f in faces)
    return text + body


def _tetra() -> tuple[np.ndarray, np.ndarray]:
    v = np.array([[0, 0, 0], [0.05, 0, 0], [0, 0.05, 0], [0, 0, 0.05]], dtype=np.float64)
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    return v, f


def ply_seeds() -> list[bytes]:
    pts = _points()
    v, f = _tetra()
    seeds = [_ply(pts, fmt) for fmt in ("ascii", "binary_little_endian", "binary_big_endian")]
    seeds.append(_ply(pts, "binary_little_endian", colors=False, comments=("tactex spacing_m 0.003",)))
    seeds += [_ply(v, fmt, faces=f) for fmt in ("ascii", "binary_little_endian")]
    seeds.append(_ply(v, "ascii", faces=f, comments=("TextureFile missing.png",)))
    seeds += [_ply(p, "binary_little_endian") for p in _shared_points()]
    return seeds


def _pcd(points: np.ndarray, encoding: str, version: str = ".7") -> bytes:
    import lzf

    n = len(points)
    rgb = (np.arange(n) * 40503 % (1 << 24)).astype("<u4")
    fields = ["x", "y", "z", "rgb"]
    lines = [f"VERSION {version}", "FIELDS x y z rgb", "SIZE 4 4 4 4", "TYPE F F F U"]
    if version != ".5":
        lines += ["COUNT 1 1 1 1", f"WIDTH {n}", "HEIGHT 1"]
    if version == ".7":
        lines.append("VIEWPOINT 0 0 0 1 0 0 0")
    lines += [f"POINTS {n}", f"DATA {encoding}"]
    head = ("\n".join(lines) + "\n").encode("ascii")
    cols = [points[:, i].astype("<f4") for i in range(3)] + [rgb]
    if encoding == "ascii":
        rows = [" ".join([*(repr(float(c[i])) for c in cols[:3]), str(int(rgb[i]))]) for i in range(n)]
        return head + ("\n".join(rows) + "\n").encode("ascii")
    rec = np.empty(n, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("rgb", "<u4")])
    for name, c in zip(fields, cols, strict=True):
        rec[name] = c
    if encoding == "binary":
        return head + rec.tobytes()
    columnar = b"".join(np.ascontiguousarray(rec[name]).tobytes() for name in fields)
    packed = lzf.compress(columnar, len(columnar) + 64)  # None when it would not shrink, without room
    return head + struct.pack("<II", len(packed), len(columnar)) + packed


def pcd_seeds(encoding: str) -> list[bytes]:
    clouds = [_points(), *_shared_points()]
    return [_pcd(p, encoding, version) for p in clouds for version in (".5", ".6", ".7")]


def npz_seeds() -> list[bytes]:
    pts = _points()
    out = []
    for arrays in ({"points": pts},
                   {"points": pts, "colors": np.full((len(pts), 3), 0.5), "target": np.ones(len(pts)),
                    "spacing": np.float64(0.003)},
                   {"points": pts.astype(np.float32), "normals": np.tile([0.0, 0.0, 1.0], (len(pts), 1)),
                    "colors": np.full((len(pts), 3), 200, dtype=np.uint8)}):
        for save in (np.savez, np.savez_compressed):
            buf = io.BytesIO()
            save(buf, **arrays)
            out.append(buf.getvalue())
    return out


def _mesh(kind: str) -> bytes:
    import trimesh

    v, f = _tetra()
    mesh = trimesh.Trimesh(v, f, process=False)
    if kind == "stl_ascii":
        return trimesh.exchange.stl.export_stl_ascii(mesh).encode("ascii")
    if kind == "stl":
        return trimesh.exchange.stl.export_stl(mesh)
    if kind == "obj_colors":
        mesh.visual.vertex_colors = np.array([[200, 30, 40, 255]] * 4, dtype=np.uint8)
    text = trimesh.exchange.obj.export_obj(mesh, include_texture=False)
    return text.encode("ascii")


def obj_seeds() -> list[bytes]:
    return [_mesh("obj"), _mesh("obj_colors"),
            b"mtllib missing.mtl\nusemtl skin\nv 0 0 0\nv 0.05 0 0\nv 0 0.05 0\nvt 0 0\nvt 1 0\nvt 0 1\n"
            b"f 1/1 2/2 3/3\n"]


def stl_seeds() -> list[bytes]:
    return [_mesh("stl"), _mesh("stl_ascii")]


def hand_eye_seeds() -> list[bytes]:
    """The first byte picks the suffix (even: .npy, odd: .json); the rest is the file."""
    pose = np.eye(4)
    pose[:3, 3] = [0.0, 0.05, 0.1]
    buf = io.BytesIO()
    np.save(buf, pose)
    return [b"\x00" + buf.getvalue(), b"\x01" + json.dumps(pose.tolist()).encode()]


def study_spec_seeds() -> list[bytes]:
    return [b'task = "clean"\nseeds = 2\n\n[fixed]\nbudget_s = 30.0\n\n[grid]\ntool_friction = [0.2, 0.4]\n'
            b'baseline = ["", "raster"]\n\n[success]\nmetric = "dirt_removed_fraction"\nat_least = 0.9\n',
            b'task = "wipe"\nseeds = [0, 3]\ndraws = 2\ndraw_seed = 1\n\n[random]\n'
            b'force_n = {uniform = [5.0, 15.0]}\ncommand_delay_ticks = {integers = [0, 3]}\n']
