"""The page of ``tactex annotate``: a cloud in its own colours, painted with the mouse, in a browser.

Served by viser on localhost: its client ships built in the viser wheel (no script, font or picture
from the internet) and it draws point clouds and reports clicks on the scene as rays, which is all
painting needs. A click paints (or fills from) the point under the cursor
(:meth:`tactex.pointcloud.annotation.Annotation.pick`), a Shift+click strokes the brush there from the
point clicked before (as image editors draw a straight line); a drag turns the view. The marks are kept
here, in Python (:class:`~tactex.pointcloud.annotation.Annotation`), and the page only shows them.
"""

from __future__ import annotations

import contextlib
import io
import socket
import threading
from pathlib import Path
from typing import Any

import numpy as np

from tactex.errors import InputError
from tactex.pointcloud.annotation import Annotation
from tactex.pointcloud.io import read_cloud
from tactex.pointcloud.ply_marks import write_marked_ply

__all__ = ["KEEP_OUT_RGB", "MARK_LABELS", "TARGET_RGB", "AnnotateView", "check_port", "open_annotation"]

#: Colours of the marks on the page (8-bit RGB): saturated, unlike a scan's own colours, and not the
#: pure red TEC's clouds mark their target in.
TARGET_RGB = (255, 0, 230)
KEEP_OUT_RGB = (0, 180, 255)
#: The page's names of the marks → :data:`tactex.pointcloud.annotation.MARK_KINDS`.
MARK_LABELS = {"target": "target", "keep-out": "keep_out", "erase": "erase"}


def open_annotation(path: str | Path, units: str = "m") -> tuple[Annotation, tuple[str, ...]]:
    """The cloud file's points (in ``units``: m, mm, in; held in metres) with the marks it already holds (its
    ``target`` and ``keep_out``), and what reading it did, in words."""
    read = read_cloud(path, units=units)
    return Annotation(read.cloud, read.cloud.target, read.keep_out), read.notes


def check_port(host: str, port: int) -> None:
    """InputError when ``port`` cannot be listened on (another program holds it)."""
    if not 0 <= port <= 65535:
        raise InputError(f"--port {port} is not a TCP port (0-65535; 0 takes a free one)")
    if port == 0:
        return
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        try:
            s.bind((host, port))
        except OSError as exc:
            raise InputError(f"--port {port} is in use on {host} ({exc.strerror}); give another, or --port 0 "
                             "for a free one") from None


def _base_colors(annotation: Annotation) -> np.ndarray:
    """The cloud's own colours (8-bit), or a grey by height when it has none."""
    cloud = annotation.cloud
    if cloud.colors is not None:
        return np.round(cloud.colors * 255.0).astype(np.uint8)
    z = cloud.points[:, 2]
    span = float(np.ptp(z)) or 1.0
    grey = 90.0 + 120.0 * (z - z.min()) / span
    return np.repeat(grey[:, None], 3, axis=1).astype(np.uint8)


class AnnotateView:
    """A viser server showing one :class:`Annotation` and taking its clicks.

    Args:
        annotation: the marks being edited.
        out: the PLY the Save button writes.
        port: TCP port on ``host`` (0: a free one).
        source: the file the cloud came from (shown on the page).
    """

    def __init__(self, annotation: Annotation, out: str | Path, *, port: int = 8080, host: str = "127.0.0.1",
                 source: str | Path = "") -> None:
        import viser

        check_port(host, port)
        self.annotation = annotation
        self.out = Path(out)
        self.saved: Path | None = None
        self.unsaved = 0
        self.last_index: int | None = None  # the point clicked last: a Shift+click strokes from it
        self._lock = threading.Lock()
        self._base = _base_colors(annotation)
        with contextlib.redirect_stdout(io.StringIO()):  # viser's banner: the command prints the address itself
            self.server = viser.ViserServer(host=host, port=port, verbose=False)
        if port and self.server.get_port() != port:  # viser moves to the next port when one is taken
            self.server.stop()
            raise InputError(f"--port {port} is in use on {host}; give another, or --port 0 for a free one")
        self.url = f"http://{host}:{self.server.get_port()}/"
        self._build(Path(source).name if source else "")

    def _build(self, name: str) -> None:
        cloud = self.annotation.cloud
        h_mm = float(cloud.spacing) * 1e3
        lo, hi = cloud.points.min(axis=0), cloud.points.max(axis=0)
        centre, size = (lo + hi) / 2.0, float(np.linalg.norm(hi - lo)) or 1.0
        scene, gui = self.server.scene, self.server.gui
        scene.set_up_direction("+z")
        self.server.initial_camera.look_at = tuple(centre)
        self.server.initial_camera.position = tuple(centre + np.array([0.6, -0.6, 0.9]) * size)
        self.points = scene.add_point_cloud("/cloud", points=cloud.points.astype(np.float32), colors=self.colors(),
                                            point_size=float(cloud.spacing) * 1.2, point_shape="circle",
                                            precision="float32")
        gui.add_markdown(f"**{name or 'cloud'}**: {len(cloud)} points, spacing {h_mm:.2f} mm. "
                         "Click the cloud to paint, Shift+click to stroke from the last click; drag to turn the view.")
        self.mark = gui.add_dropdown("Mark", tuple(MARK_LABELS), initial_value="target")
        self.tool = gui.add_dropdown("Tool", ("brush", "fill"), initial_value="brush")
        self.radius = gui.add_slider("Brush radius [mm]", min=1.0, max=100.0, step=1.0,
                                     initial_value=float(min(100.0, max(5.0, round(3.0 * h_mm)))))
        self.weight = gui.add_number("Target weight", initial_value=1.0, min=0.01, max=1000.0, step=0.01)
        self.counts_md = gui.add_markdown(self.counts_text())
        undo = gui.add_button("Undo")
        undo.on_click(lambda _event: self.undo())
        save = gui.add_button("Save")
        self.status_md = gui.add_markdown(f"Saves to `{self.out}`")
        save.on_click(lambda _event: self._save_clicked())
        scene.on_click()(self._clicked)
        scene.on_click(modifier="shift")(lambda event: self._clicked(event, from_last=True))

    def colors(self) -> np.ndarray:
        """(N, 3) uint8 colours drawn: the cloud's own, the marks over them (target brighter with weight)."""
        a = self.annotation
        rgb = self._base.copy()
        t = a.target > 0
        if t.any():
            strength = 0.55 + 0.45 * a.target[t] / float(a.target[t].max())
            rgb[t] = np.round(np.outer(strength, TARGET_RGB) + np.outer(1 - strength, (40, 40, 40))).astype(np.uint8)
        rgb[a.keep_out] = KEEP_OUT_RGB
        return rgb

    def counts_text(self) -> str:
        c = self.annotation.counts()
        return (f"target: {c.n_target} points, {c.target_area_cm2:.1f} cm²  \n"
                f"keep-out: {c.n_keep_out} points, {c.keep_out_area_cm2:.1f} cm²")

    def apply(self, index: int, *, from_last: bool = False) -> np.ndarray:
        """What a click on point ``index`` does with the page's current settings (``from_last``: a
        Shift+click, a brush stroke from the point clicked before); the indices changed."""
        kind, weight, radius_m = MARK_LABELS[self.mark.value], float(self.weight.value), float(self.radius.value) * 1e-3
        with self._lock:
            last, self.last_index = self.last_index, index
            if self.tool.value == "fill":
                changed = self.annotation.fill(index, kind, weight)
            elif from_last and last is not None:
                changed = self.annotation.stroke(last, index, radius_m, kind, weight)
            else:
                changed = self.annotation.paint(index, radius_m, kind, weight)
            if changed.size:
                self.unsaved += 1
                self._redraw()
        return changed

    def undo(self) -> np.ndarray:
        """Take back the last change (the Undo button); the indices restored."""
        with self._lock:
            restored = self.annotation.undo()
            if restored.size:
                self.unsaved += 1
                self._redraw()
        return restored

    def _redraw(self) -> None:
        self.points.colors = self.colors()
        self.counts_md.content = self.counts_text()
        if self.saved is not None:  # the last save's line no longer says what the file holds
            self.status_md.content = f"{self.unsaved} change(s) since `{self.saved}` was saved"

    def _clicked(self, event: Any, from_last: bool = False) -> None:
        if event.ray_origin is None or event.ray_direction is None:
            return
        index = self.annotation.pick(np.asarray(event.ray_origin), np.asarray(event.ray_direction))
        if index is not None:
            with contextlib.suppress(InputError):  # a weight typed as 0: nothing painted
                self.apply(index, from_last=from_last)

    def save(self) -> Path:
        """Write the marked cloud to ``out``."""
        with self._lock:
            a = self.annotation
            path = write_marked_ply(a.cloud, a.target, a.keep_out, self.out)
            self.saved, self.unsaved = path, 0
        return path

    def _save_clicked(self) -> None:
        try:
            path = self.save()
        except (InputError, OSError) as exc:
            self.status_md.content = f"**not saved**: {exc}"
            return
        c = self.annotation.counts()
        self.status_md.content = f"saved `{path}`: {c.n_target} target, {c.n_keep_out} keep-out points"

    def stop(self) -> None:
        with contextlib.redirect_stdout(io.StringIO()):
            self.server.stop()
