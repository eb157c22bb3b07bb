"""Meshes as clouds: a PLY with faces, STL or OBJ sampled on its surface (trimesh).

CAD parts come as meshes whose vertices are a few corners: a 2 m cube is 8 points. The explorer
needs the surface, so the faces are sampled uniformly by area (``trimesh.sample.sample_surface``,
:data:`SAMPLES_PER_CELL` points per spacing² of area), then one sample is kept per voxel of the run
(the voxel grid of :func:`tactex.pointcloud.voxel_down_sample`). A kept sample, unlike a voxel mean,
stays on the surface at edges and corners. Vertex or face colours are carried to the samples;
normals are those of the sampled faces. Such a cloud is already at the voxel spacing: it is not
voxel-filtered again.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from tactex.errors import CloudError, UnitsError
from tactex.pointcloud.cloud import MAX_EXTENT_M, CloudFile, SurfaceCloud
from tactex.pointcloud.units import inch_hint, millimetre_hint, to_metres

__all__ = ["MAX_MESH_POINTS", "SAMPLES_PER_CELL", "read_mesh", "sample_mesh"]

#: Samples drawn per spacing² of surface before the voxel grid thins them to one per voxel.
SAMPLES_PER_CELL = 4
#: Largest cloud a mesh is sampled into [points]: the Laplacian and eigenbasis of a bigger one take
#: minutes and gigabytes on a workstation.
MAX_MESH_POINTS = 200_000
#: Seed of the surface samples: the same file gives the same cloud.
SAMPLE_SEED = 0


def read_mesh(path: Path, spacing_m: float, units: str = "m") -> CloudFile:
    """The cloud sampled from the mesh file at ``path`` every ``spacing_m`` [m], as a
    :class:`tactex.pointcloud.cloud.CloudFile`; the file's vertices are in ``units`` (m, mm, in)."""
    from tactex.pointcloud.mesh_load import load_mesh

    mesh, load_notes = load_mesh(path)
    if units != "m":
        mesh.vertices = to_metres(mesh.vertices, units)
    n_faces = len(mesh.faces)
    good = np.isfinite(mesh.vertices).all(axis=1)
    dropped = int((~good).sum())
    if dropped:
        mesh.update_faces(good[mesh.faces].all(axis=1))
        mesh.remove_unreferenced_vertices()
    cloud = sample_mesh(mesh, spacing_m, f"'{path}'", units)
    notes = [f"a mesh of {n_faces} faces ({mesh.area:.4g} m² of surface), sampled every {spacing_m * 1e3:.3g} mm",
             *load_notes]
    if dropped:
        notes.append(f"dropped {dropped} vertices with NaN/inf coordinates (and their faces)")
    return CloudFile(cloud, dropped, n_faces=n_faces, notes=tuple(notes))


def sample_mesh(mesh, spacing_m: float, name: str = "the mesh", units: str = "m") -> SurfaceCloud:
    """A cloud with one point per ``spacing_m`` voxel of ``mesh``'s surface (a ``trimesh.Trimesh``, in metres,
    read from a file in ``units``: for the hint when it is too wide).

    Raises:
        UnitsError: the mesh spans more than :data:`MAX_EXTENT_M` (it is probably in millimetres).
        CloudError: the sampling would exceed :data:`MAX_MESH_POINTS` points, or the mesh has no area.
    """
    import trimesh

    from tactex.pointcloud.voxel import voxel_indices

    if not (math.isfinite(spacing_m) and spacing_m > 0):
        raise CloudError("a mesh is sampled at the voxel size, so it needs voxel_size_m > 0")
    if len(mesh.faces) == 0:
        raise CloudError(f"{name} holds no triangles")
    extent = float(np.max(np.ptp(mesh.vertices, axis=0)))
    if extent > MAX_EXTENT_M:
        raise UnitsError(f"{name} spans {extent:.4g} along one axis; tactex works in metres, an object over "
                         f"{MAX_EXTENT_M:g} m is out of reach, and {millimetre_hint(extent, units)}")
    area = float(mesh.area)
    if not (math.isfinite(area) and area > 0):
        raise CloudError(f"{name} has no surface area (all its triangles are degenerate)")
    cells = area / spacing_m**2
    if cells > MAX_MESH_POINTS:
        finest = math.sqrt(area / MAX_MESH_POINTS)
        raise CloudError(
            f"{name} has {area:.3g} m² of surface, {cells:,.0f} points at {spacing_m * 1e3:.3g} mm: more than the "
            f"{MAX_MESH_POINTS:,} points tactex handles; give voxel_size_m={math.ceil(finest * 1e4) / 1e4:g} or more"
            + (f"; {inch_hint(extent)}" if inch_hint(extent) else ""))
    count = max(math.ceil(SAMPLES_PER_CELL * cells), 16)
    points, faces, bary = trimesh.sample.sample_surface(mesh, count, return_barycentric=True, seed=SAMPLE_SEED)
    normals = np.asarray(mesh.face_normals[faces], dtype=np.float64)
    colors = None
    if mesh.visual.defined and mesh.visual.kind == "vertex":
        rgb = np.asarray(mesh.visual.vertex_colors[:, :3], dtype=np.float64) / 255.0
        colors = np.einsum("nk,nkc->nc", bary, rgb[mesh.faces[faces]])
    elif mesh.visual.defined and mesh.visual.kind == "face":
        colors = np.asarray(mesh.visual.face_colors[faces, :3], dtype=np.float64) / 255.0
    points = np.asarray(points, dtype=np.float64)
    inverse, counts = voxel_indices(points, spacing_m)
    first = np.empty(counts.size, dtype=np.int64)
    first[inverse[::-1]] = np.arange(inverse.size)[::-1]  # the first sample of each voxel
    return SurfaceCloud(points=points[first], normals=normals[first],
                        colors=None if colors is None else np.clip(colors[first], 0.0, 1.0), spacing=spacing_m)
