"""Drawn targets (markings, dirt patterns) over a surface's uv square [0, 1]².

A marking is a boolean mask over uv coordinates: strokes (letters) are polylines with a width,
blobs are discs. TEC marks an 'X', 'RLI' and hand-drawn shapes on its objects; the simulator uses
the same masks to lay dirt. Add one by adding an entry to :data:`MARKINGS`.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable

import numpy as np

from tactex.errors import ConfigError, InputError
from tactex.pointcloud.cloud import SurfaceCloud
from tactex.pointcloud.shapes import Surface

__all__ = ["BASE_RGB", "MARKINGS", "MARK_RGB", "marked_cloud", "marking_mask", "marking_names", "mask_from_image",
           "resolve_marking"]

#: Colour of marked (dirty) points: pure red, as the TEC clouds mark their target.
MARK_RGB = np.array([1.0, 0.0, 0.0])
#: Colour of the clean surface.
BASE_RGB = np.array([0.85, 0.85, 0.82])

Polyline = list[tuple[float, float]]

# Letter strokes in a unit box (u right, v up), drawn into a sub-box of the uv square.
_LETTERS: dict[str, list[Polyline]] = {
    "X": [[(0.0, 0.0), (1.0, 1.0)], [(0.0, 1.0), (1.0, 0.0)]],
    "R": [
        [(0.0, 0.0), (0.0, 1.0), (0.7, 1.0), (0.9, 0.85), (0.9, 0.65), (0.7, 0.5), (0.0, 0.5)],
        [(0.35, 0.5), (0.9, 0.0)],
    ],
    "L": [[(0.0, 1.0), (0.0, 0.0), (0.9, 0.0)]],
    "I": [[(0.5, 0.0), (0.5, 1.0)]],
}


def _segments_distance(uv: np.ndarray, polylines: list[Polyline]) -> np.ndarray:
    """Distance from each uv point to the nearest segment of the polylines."""
    best = np.full(len(uv), np.inf)
    for line in polylines:
        pts = np.asarray(line, dtype=float)
        for a, b in itertools.pairwise(pts):
            ab = b - a
            t = np.clip(((uv - a) @ ab) / float(ab @ ab), 0.0, 1.0)
            d = np.linalg.norm(uv - (a + t[:, None] * ab), axis=1)
            best = np.minimum(best, d)
    return best


def _text(letters: str, box: tuple[float, float, float, float], width: float) -> Callable[[np.ndarray], np.ndarray]:
    u0, v0, u1, v1 = box
    cell = (u1 - u0) / len(letters)

    def mask(uv: np.ndarray) -> np.ndarray:
        lines: list[Polyline] = []
        for i, ch in enumerate(letters):
            ox = u0 + i * cell + 0.15 * cell
            sx = 0.7 * cell
            lines += [[(ox + sx * p, v0 + (v1 - v0) * q) for p, q in stroke] for stroke in _LETTERS[ch]]
        return _segments_distance(uv, lines) <= width / 2

    return mask


def _blobs(uv: np.ndarray) -> np.ndarray:
    centres = np.array([[0.3, 0.3], [0.7, 0.35], [0.5, 0.72]])
    radii = np.array([0.12, 0.09, 0.1])
    d = np.linalg.norm(uv[:, None, :] - centres[None], axis=2)
    return (d <= radii[None]).any(axis=1)


def _spots(uv: np.ndarray) -> np.ndarray:
    # Sparse dirt: three small spots far apart, 1 cm across on the 26 cm plate, the case where cleaning
    # only where the dirt is should beat covering the whole surface most clearly.
    centres = np.array([[0.27, 0.3], [0.74, 0.42], [0.42, 0.76]])
    d = np.linalg.norm(uv[:, None, :] - centres[None], axis=2)
    return (d <= 0.005 / 0.26).any(axis=1)


def _shapes(uv: np.ndarray) -> np.ndarray:
    # Hand-drawn-like shapes as on the TEC plate: a ring, a triangle outline, a square outline.
    ring = np.abs(np.linalg.norm(uv - [0.3, 0.68], axis=1) - 0.12) <= 0.025
    tri = _segments_distance(uv, [[(0.55, 0.55), (0.85, 0.55), (0.7, 0.82), (0.55, 0.55)]]) <= 0.025
    sq = _segments_distance(uv, [[(0.35, 0.18), (0.65, 0.18), (0.65, 0.42), (0.35, 0.42), (0.35, 0.18)]]) <= 0.025
    return ring | tri | sq


MARKINGS: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "X": _text("X", (0.2, 0.2, 0.8, 0.8), 0.08),
    "RLI": _text("RLI", (0.1, 0.3, 0.9, 0.7), 0.06),
    "blobs": _blobs,
    "shapes": _shapes,
    "spots": _spots,
    "full": lambda uv: np.ones(len(uv), dtype=bool),
}


def marking_names() -> list[str]:
    return sorted(MARKINGS)


def resolve_marking(name: str) -> str:
    """The marking called ``name`` in any case ('x' → 'X', 'rli' → 'RLI'); the error lists them."""
    found = {n.lower(): n for n in MARKINGS}.get(str(name).lower())
    if found is None:
        raise ConfigError(f"unknown marking '{name}'; valid: {', '.join(marking_names())}")
    return found


def marking_mask(name: str | Callable[[np.ndarray], np.ndarray], uv: np.ndarray) -> np.ndarray:
    """Boolean mask (N,) of the uv points (N, 2) covered by marking ``name`` (or by a mask function uv → (N,),
    a part's own marking)."""
    uv = np.asarray(uv, dtype=float)
    if uv.ndim != 2 or uv.shape[1] != 2:
        raise InputError(f"uv must have shape (N, 2), got {uv.shape}")
    if callable(name):
        return np.asarray(name(uv), dtype=bool).reshape(len(uv))
    return np.asarray(MARKINGS[resolve_marking(name)](uv), dtype=bool)


def mask_from_image(image: np.ndarray, uv: np.ndarray, threshold: float = 0.5) -> np.ndarray:
    """Marking from a 2-D image (H, W) in [0, 1] (or 0..255): dark pixels above ``threshold``
    darkness are marked. Row 0 is the top (v = 1), as images are stored."""
    img = np.asarray(image, dtype=float)
    if img.ndim != 2 or min(img.shape) < 2:
        raise InputError(f"marking image must be a 2-D array of at least 2×2, got {img.shape}")
    if img.max() > 1.0:
        img = img / 255.0
    h, w = img.shape
    cols = np.clip(np.round(uv[:, 0] * (w - 1)).astype(int), 0, w - 1)
    rows = np.clip(np.round((1.0 - uv[:, 1]) * (h - 1)).astype(int), 0, h - 1)
    return (1.0 - img[rows, cols]) >= threshold


def marked_cloud(surface: Surface, marking: str = "X", spacing_m: float = 0.003) -> SurfaceCloud:
    """Sample ``surface`` at ``spacing_m`` [m] and mark ``marking`` as target (mass 1) and red."""
    cloud = surface.sample(spacing_m)
    mask = marking_mask(marking, surface.uv(cloud.points))
    colors = np.where(mask[:, None], MARK_RGB, BASE_RGB)
    return SurfaceCloud(
        points=cloud.points, normals=cloud.normals, colors=colors, target=mask.astype(float), spacing=cloud.spacing
    )
