"""trimesh's reading of a mesh file, quiet and with its failures in tactex's words.

trimesh logs what it cannot do (a missing texture: a warning with its traceback) and raises many
kinds of exception on files it cannot parse. Here its log records are caught instead of printed,
its warnings are ignored (numerical noise of its own processing), and every exception is one
:class:`~tactex.errors.CloudError` naming the file. A texture that cannot be loaded drops trimesh's
vertex colours with it (it keeps the texture coordinates and no image); the mesh is then read again
without the texture, from the same file, so that its vertex colours are kept, and a note says so.
A binary STL's per-face colours (in the two attribute bytes of each triangle, VisCAM/SolidView's
convention) become face colours.
"""

from __future__ import annotations

import contextlib
import logging
import warnings
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from tactex.errors import CloudError

__all__ = ["load_mesh", "quiet_trimesh"]


class _Records(logging.Handler):
    def __init__(self) -> None:
        super().__init__(logging.DEBUG)
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)


@contextlib.contextmanager
def quiet_trimesh() -> Iterator[list[logging.LogRecord]]:
    """trimesh's log records (kept in the yielded list, not printed) and warnings (ignored) while
    the block runs; the logger is as it was afterwards."""
    logger = logging.getLogger("trimesh")
    handler = _Records()
    propagate, level = logger.propagate, logger.level
    logger.addHandler(handler)
    logger.propagate = False
    logger.setLevel(logging.DEBUG)  # a texture that failed to load is a debug record in some loaders
    try:
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            yield handler.records
    finally:
        logger.removeHandler(handler)
        logger.propagate, logger.level = propagate, level


def _detail(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0][:120] if text else type(exc).__name__


def _failed_texture(records: list[logging.LogRecord]) -> str | None:
    """The name of a texture trimesh could not load, from its log records: "" when it names none,
    None when no texture failed."""
    for record in records:
        exc = record.exc_info[1] if record.exc_info else None
        if isinstance(exc, OSError) or "unable to load image" in record.getMessage():
            return str(exc.args[0])[:80] if isinstance(exc, OSError) and exc.args else ""
    return None


def _image_missing(mesh) -> bool:
    """Whether the textured mesh has no texture image to colour it."""
    material = getattr(mesh.visual, "material", None)
    return getattr(material, "image", None) is None and getattr(material, "baseColorTexture", None) is None


def _has_colors(mesh) -> bool:
    return bool(mesh.visual.defined and mesh.visual.kind in ("vertex", "face"))


def _without_texture(path: Path):
    """The mesh of a PLY or OBJ file read with its texture left out: its vertex colours, if any, kept."""
    import trimesh
    from trimesh.exchange.obj import load_obj
    from trimesh.exchange.ply import load_ply

    suffix = path.suffix.lower()
    with path.open("rb") as f:
        if suffix == ".ply":
            kwargs = load_ply(f, skip_materials=True, fix_texture=False)
        elif suffix == ".obj":
            geometry = load_obj(f, resolver=trimesh.resolvers.FilePathResolver(str(path)),
                                skip_materials=True).get("geometry", {})
            if len(geometry) != 1:  # several objects: their colours cannot be joined safely here
                return None
            kwargs = next(iter(geometry.values()))
        else:
            return None
    colors = kwargs.get("vertex_colors")
    if colors is None or len(colors) != len(kwargs.get("vertices", ())):
        return None
    return trimesh.Trimesh(vertices=kwargs["vertices"], faces=kwargs["faces"], vertex_colors=colors, process=True)


#: An STL face's attribute bytes hold a colour when bit 15 is set (the VisCAM/SolidView convention):
#: 5 bits each of red (bits 10–14), green (5–9) and blue (0–4).
STL_COLOR_VALID = 0x8000
#: The colour of an STL face without one when others have one.
STL_DEFAULT_RGB = (200, 200, 200)


def _stl_colors(mesh) -> bool:
    """Give an STL mesh the face colours its attribute bytes hold (VisCAM/SolidView: bit 15 set), if any
    face has one; True when it had."""
    attrs = getattr(mesh, "face_attributes", {}).get("stl")
    if attrs is None or len(attrs) != len(mesh.faces) or mesh.visual.defined:
        return False
    a = np.asarray(attrs, dtype=np.uint16)
    valid = (a & STL_COLOR_VALID) != 0
    if not valid.any():
        return False
    rgb = np.stack([(a >> 10) & 31, (a >> 5) & 31, a & 31], axis=1).astype(np.float64) * (255.0 / 31.0)
    rgb = np.where(valid[:, None], np.rint(rgb), np.array(STL_DEFAULT_RGB, dtype=np.float64))
    mesh.visual.face_colors = np.column_stack([rgb, np.full(len(rgb), 255.0)]).astype(np.uint8)
    return True


def load_mesh(path: Path):
    """The ``trimesh.Trimesh`` of the mesh file ``path`` and notes for the user (a texture that
    could not be loaded, replaced by the vertex colours).

    Raises:
        CloudError: trimesh cannot read the file, or it holds no triangles.
    """
    import trimesh

    notes: list[str] = []
    try:
        with quiet_trimesh() as records:
            mesh = trimesh.load(str(path), force="mesh", process=True)
            failed = _failed_texture(records)
            if isinstance(mesh, trimesh.Trimesh) and mesh.visual.kind == "texture" and (
                    failed is not None or _image_missing(mesh)):
                missing = failed or ""
                what = f"its texture '{missing}' could not be loaded" if missing else \
                    "it has texture coordinates but no texture image"
                colored = _without_texture(path)
                if colored is not None and _has_colors(colored):
                    mesh = colored
                    notes.append(f"{what}: using its vertex colours")
                else:
                    notes.append(f"{what}, and no vertex colours")
    except (CloudError, MemoryError):  # a MemoryError is a size check missing here: let it be seen
        raise
    except Exception as exc:  # trimesh raises many kinds on files it cannot parse
        raise CloudError(f"'{path}' is not a readable mesh: {_detail(exc)}") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise CloudError(f"'{path}' holds no triangles (an empty or unreadable mesh file)")
    if path.suffix.lower() == ".stl" and _stl_colors(mesh):
        notes.append("face colours read from its attribute bytes (the VisCAM/SolidView convention)")
    faces, vertices = np.asarray(mesh.faces), np.asarray(mesh.vertices)
    if faces.ndim != 2 or faces.shape[1] != 3 or vertices.ndim != 2 or vertices.shape[1] != 3 \
            or faces.min() < 0 or faces.max() >= len(vertices):
        raise CloudError(f"'{path}' is not a readable mesh: its faces are not triangles of its vertices")
    return mesh, tuple(notes)
