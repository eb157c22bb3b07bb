"""The live page of a run (``--view``): a viser server in a process of its own, reading the run's
:class:`~tactex.tasks.live_feed.LiveFeed`.

It polls the feed's slot at :data:`POLL_S` and sends the browser what changed: the cloud coloured by
what is left of the target (red left, green done; the keep-out zone blue), the agent's and the TCP's
paths, the tool's frame, the normal force against its set point over the last :data:`FORCE_WINDOW_S`,
the phase and the time breakdown so far. A snapshot taken while the page is busy replaces the one
before it (the slot holds one; viser's outgoing buffer also replaces a node's unsent update with the
newer one), so a slow page drops frames and never holds the run back. The **Stop** button sends the
run SIGINT, so the run stops exactly as on Ctrl-C; the page ignores SIGINT itself (Ctrl-C in the
terminal reaches the whole process group) and ends with the run.
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import shutil
import signal
import sys
import time
from collections import deque
from pathlib import Path

import numpy as np

from tactex.report.annotate_view import KEEP_OUT_RGB, check_port
from tactex.tasks.live_feed import FAILED, PORT, RUNNING, SERVING, STOP, STOPPED, VIEWER, LiveFeed, read_snapshot

__all__ = ["FORCE_WINDOW_S", "POLL_S", "LiveView", "serve_live"]

#: How often the page reads the run's slot [s] (the run writes it at most every 0.1 s).
POLL_S = 0.05
#: Span of the force plot [s].
FORCE_WINDOW_S = 10.0
#: Longest path drawn [points]: older points are thinned out (every other one dropped).
MAX_PATH_POINTS = 4000
#: Colours (8-bit RGB): target left, target done, agent path, TCP path.
LEFT_RGB = np.array((220, 30, 30), dtype=float)
DONE_RGB = np.array((40, 190, 70), dtype=float)
AGENT_RGB = (255, 150, 0)
TCP_RGB = (60, 60, 60)


def _wxyz(rot: np.ndarray) -> tuple[float, float, float, float]:
    """Unit quaternion (w, x, y, z) of a rotation matrix (viser's convention)."""
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(rot).as_quat()
    return (float(w), float(x), float(y), float(z))


class _Path:
    """A polyline grown a point at a time, thinned to :data:`MAX_PATH_POINTS`."""

    def __init__(self) -> None:
        self.points: list[np.ndarray] = []

    def add(self, p: np.ndarray) -> bool:
        if not np.isfinite(p).all() or (self.points and np.array_equal(self.points[-1], p)):
            return False
        self.points.append(np.array(p, dtype=np.float32))
        if len(self.points) > MAX_PATH_POINTS:
            self.points = self.points[:-1:2] + self.points[-1:]
        return len(self.points) >= 2

    def segments(self) -> np.ndarray:
        p = np.asarray(self.points)
        return np.stack([p[:-1], p[1:]], axis=1)


class LiveView:
    """The page of one run: a viser server on ``host:port`` (0: a free one) over ``feed``.

    Args:
        feed: the run's slot (opened on its folder).
        parent_pid: the run's process: Stop sends it SIGINT.
        title: the page's heading (the command and its run folder).
        force_set_point_n: the run's normal force set point [N] (the force plot's scale); 0: no force plot.
    """

    def __init__(self, feed: LiveFeed, parent_pid: int, *, port: int = 8080, host: str = "127.0.0.1",
                 title: str = "tactex run", force_set_point_n: float = 0.0) -> None:
        import viser
        import viser.uplot as uplot

        from tactex.errors import InputError

        check_port(host, port)
        self.feed, self.parent_pid = feed, parent_pid
        with contextlib.redirect_stdout(io.StringIO()):
            self.server = viser.ViserServer(host=host, port=port, verbose=False)
        if port and self.server.get_port() != port:  # viser moves to the next port when one is taken
            self.server.stop()
            raise InputError(f"--view-port {port} is in use on {host}; give another, or --view-port 0 for a free one")
        self.port = self.server.get_port()
        # [N] the force axis: contact peaks reach about twice the set point (a run without force: no plot)
        force_axis_n = (-5.0, 5.0 * math.ceil(2.5 * force_set_point_n / 5.0)) if force_set_point_n > 0 else (-1.0, 1.0)
        self.server.scene.set_up_direction("+z")
        gui = self.server.gui
        gui.add_markdown(f"**{title}** (live)")
        self.status_md = gui.add_markdown("waiting for the run ...")
        self.stop_button = gui.add_button("Stop", color="red")
        self.stop_button.on_click(lambda _event: self.stop())
        self.force_plot = gui.add_uplot(
            # two points to start from: the page keeps the x span relative to the first data's, which an empty
            # series leaves undefined for good
            data=(np.array([0.0, 1.0]), np.zeros(2), np.zeros(2)),
            series=(uplot.Series(label="t [s]"),
                    uplot.Series(label="force [N]", stroke="#1f77b4", width=2),
                    uplot.Series(label="set point [N]", stroke="#d62728", width=1, dash=[6, 4])),
            # a fixed force axis: the page keeps its axes across data pushes (one fitted to the first,
            # out-of-contact forces would hide every later one), and a new range would rebuild the chart
            scales={"x": uplot.Scale(time=False), "y": uplot.Scale(range=force_axis_n)}, visible=force_set_point_n > 0,
            title=f"normal force [N] over run time [s], last {FORCE_WINDOW_S:g} s", aspect=1.6)
        self.breakdown_md = gui.add_markdown("")
        self._seq = -1.0
        self._gen = 0
        self._field: np.ndarray | None = None
        self._cloud = None
        self._base = self._target = self._keep_out = None
        self._last_field: np.ndarray | None = None
        self.colour_updates = 0  # times the cloud's colours were sent (shown on the page)
        self.snapshots = 0
        self._force: deque[tuple[float, float, float]] = deque()
        self._agent, self._tcp = _Path(), _Path()
        self._lines: dict[str, object] = {}
        self._tool = None
        self._point_size = 0.003  # [m] the cloud's drawn point size
        self._stopping = False

    # -- Stop ---------------------------------------------------------------------------------------------
    def stop(self) -> None:
        """Stop the run as Ctrl-C does: SIGINT to its process (once)."""
        if self._stopping:
            return
        self._stopping = True
        self.feed.numbers[STOP] = 1.0
        self.stop_button.disabled = True
        self.status_md.content = "**stopping** (as on Ctrl-C): the run writes what it recorded ..."
        with contextlib.suppress(ProcessLookupError):
            os.kill(self.parent_pid, signal.SIGINT)

    # -- updates ------------------------------------------------------------------------------------------
    def poll(self) -> bool:
        """Take the slot's latest snapshot and send what changed; False when there was nothing new."""
        snap = read_snapshot(self.feed, self._field)
        if snap is None or snap.seq == self._seq:
            return False
        self._seq = snap.seq
        self.snapshots += 1
        if snap.cloud_gen != self._gen:
            self._load_cloud(snap.cloud_gen)
            snap = read_snapshot(self.feed, self._field) or snap
        if snap.field is not None and self._cloud is not None and np.isfinite(snap.field).any():
            if self._last_field is None or not np.array_equal(snap.field, self._last_field, equal_nan=True):
                self._last_field = snap.field
                self._cloud.colors = self.colors(snap.field)
                self.colour_updates += 1
        self._paths(snap)
        if np.isfinite(snap.world_R_tool).all() and np.isfinite(snap.tcp_m).all() \
                and abs(np.linalg.det(snap.world_R_tool) - 1.0) < 1e-3:
            if self._tool is None:
                self._tool = self.server.scene.add_frame("/tool", axes_length=0.05, axes_radius=0.002)
            self._tool.position = tuple(float(x) for x in snap.tcp_m)
            self._tool.wxyz = _wxyz(snap.world_R_tool)
        if math.isfinite(snap.force_n):
            self._force.append((snap.t_s, snap.force_n, snap.set_point_n))
            while self._force and self._force[0][0] < snap.t_s - FORCE_WINDOW_S:
                self._force.popleft()
            f = np.asarray(self._force, dtype=float)
            # no set point (out of contact) is drawn as 0 N, as the run's report draws it: uPlot takes no NaN
            set_point = np.where(np.isfinite(f[:, 2]), f[:, 2], 0.0)
            self.force_plot.data = (f[:, 0].copy(), f[:, 1].copy(), set_point)
        if math.isfinite(snap.t_s):
            self.status_md.content = self._status_text(snap)
        self.breakdown_md.content = self._breakdown_text(snap)
        if snap.state != RUNNING:
            self.stop_button.disabled = True
        return True

    def _load_cloud(self, gen: int) -> None:
        folder = self.feed.folder
        with np.load(folder / f"cloud_{gen}.npz", allow_pickle=False) as z:
            points = z["points"]
            colors = z["colors"] if "colors" in z.files else None
            self._target = z["target"] if "target" in z.files else None
            self._keep_out = z["keep_out"] if "keep_out" in z.files else None
        if colors is not None:  # the scan's own colours, faded so that the target's stand out
            self._base = 0.35 * 255.0 * colors + 0.65 * 200.0
        else:
            z = points[:, 2]
            grey = 110.0 + 90.0 * (z - z.min()) / (float(np.ptp(z)) or 1.0)
            self._base = np.repeat(grey[:, None], 3, axis=1)
        self._field = np.memmap(folder / f"field_{gen}.f32", dtype=np.float32, mode="r", shape=(len(points),))
        self._gen, self._last_field = gen, None
        lo, hi = points.min(axis=0), points.max(axis=0)
        centre, size = (lo + hi) / 2.0, float(np.linalg.norm(hi - lo)) or 1.0
        spacing = float(np.median(np.linalg.norm(np.diff(points[:200], axis=0), axis=1))) if len(points) > 1 else 0.003
        self._point_size = max(min(spacing, 0.01), 0.001) * 1.3
        self._cloud = self.server.scene.add_point_cloud(
            "/cloud", points=points, colors=self.colors(None), point_size=self._point_size,
            point_shape="circle", precision="float32")
        self.server.initial_camera.look_at = tuple(float(x) for x in centre)
        self.server.initial_camera.position = tuple(float(x) for x in centre + np.array([0.7, -0.7, 0.9]) * size)

    def colors(self, field: np.ndarray | None) -> np.ndarray:
        """(N, 3) uint8: target points from red (all left) to green (none left), the rest in their own colours
        (faded), the keep-out zone blue."""
        rgb = self._base.copy()
        if self._target is not None:
            t = self._target > 0
            left = np.ones(int(t.sum())) if field is None else np.nan_to_num(
                np.clip(field[t] / self._target[t], 0.0, 1.0), nan=1.0)
            rgb[t] = np.outer(left, LEFT_RGB) + np.outer(1.0 - left, DONE_RGB)
        if self._keep_out is not None:
            rgb[self._keep_out] = KEEP_OUT_RGB
        return np.round(rgb).astype(np.uint8)

    def _paths(self, snap) -> None:
        # drawn a little off the surface (away from it along the tool axis, else up), or the cloud's points hide them
        tool_z = snap.world_R_tool[:, 2]
        off = -tool_z if np.isfinite(tool_z).all() and np.linalg.norm(tool_z) > 0.5 else np.array([0.0, 0.0, 1.0])
        off = off * 2.0 * self._point_size
        for name, path, colour, width in (("agent", self._agent, AGENT_RGB, 3.0), ("tcp", self._tcp, TCP_RGB, 1.5)):
            p = snap.agent_m if name == "agent" else snap.tcp_m
            if not path.add(p + off):
                continue
            # added anew under the same name (one message): points and colours updated apart could reach the page
            # with different lengths
            self._lines[name] = self.server.scene.add_line_segments(
                f"/{name}_path", points=path.segments(), colors=colour, thickness=width, thickness_units="screen")

    def _status_text(self, snap) -> str:
        state = "running" if snap.state == RUNNING else "stopped" if snap.state == STOPPED else "finished"
        if self._stopping and snap.state == RUNNING:
            state = "stopping (as on Ctrl-C)"
        lines = [f"**{state}** · phase **{snap.phase or '-'}** · t = {snap.t_s:.1f} s"
                 + (f" ({100 * snap.progress:.0f} %)" if math.isfinite(snap.progress) else "")]
        if math.isfinite(snap.force_n):
            lines.append(f"force {snap.force_n:.1f} N" + (f", set point {snap.set_point_n:.1f} N"
                                                          if math.isfinite(snap.set_point_n) else ""))
        lines += [f"{k}: {v:.3g}" for k, v in snap.figures.items()]
        lines.append(f"cloud colours sent {self.colour_updates} times")
        return "  \n".join(lines)

    @staticmethod
    def _breakdown_text(snap) -> str:
        if not snap.breakdown_s:
            return ""
        total = sum(snap.breakdown_s.values()) or 1.0
        rows = "\n".join(f"| {k.replace('_', ' ')} | {v:.1f} | {100 * v / total:.0f} % |"
                         for k, v in snap.breakdown_s.items())
        return f"**time so far**\n\n| | s | |\n|---|---:|---:|\n{rows}"

    def close(self) -> None:
        with contextlib.redirect_stdout(io.StringIO()):
            self.server.stop()


def serve_live(folder: str, port: int, title: str, parent_pid: int, force_set_point_n: float = 0.0) -> None:
    """The page's process: serve ``folder``'s feed until the run's process ends (Ctrl-C is the run's to take)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    with contextlib.suppress(OSError):
        os.nice(10)  # the run's loop comes first on a shared core
    feed = LiveFeed(folder)
    try:
        view = LiveView(feed, parent_pid, port=port, title=title, force_set_point_n=force_set_point_n)
    except Exception as exc:  # the run says it in one line (a port in use, viser missing)
        Path(folder, "viewer.err").write_text(f"{exc}".splitlines()[0] if str(exc) else type(exc).__name__)
        feed.numbers[VIEWER] = FAILED
        raise SystemExit(1) from None
    feed.numbers[PORT] = view.port
    feed.numbers[VIEWER] = SERVING
    try:
        while os.getppid() == parent_pid:
            try:
                view.poll()
            except Exception as exc:  # a snapshot the page cannot draw is skipped, never the end of the page
                print(f"live page: skipped a snapshot: {type(exc).__name__}: {exc}", file=sys.stderr, flush=True)
            time.sleep(POLL_S)
    finally:
        view.close()
        if os.getppid() != parent_pid:  # the run was killed outright: its feed's folder is left to this process
            shutil.rmtree(folder, ignore_errors=True)


if __name__ == "__main__":
    serve_live(sys.argv[1], int(sys.argv[2]), sys.argv[3], int(sys.argv[4]), float(sys.argv[5]))
