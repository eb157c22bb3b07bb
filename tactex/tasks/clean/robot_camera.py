"""The clean's captures with a robot's wrist camera (``tactex clean --robot franka --camera twin|realsense``).

A capture pauses torque control first (the robot holds its posture itself), then reads the camera's frames
and makes the target cloud, so neither the frames nor the cloud's processing run inside the 1 kHz loop; the
next move starts torque control again. On tactex twin with its camera the twin's own count of the dirt left
is asked at each capture and at the end: the run's ``dirt_removed_fraction`` is the twin's, counted from what was
left at this run's first capture (a twin keeps its dirt from one run to the next).
"""

from __future__ import annotations

import math
import time
import warnings

from tactex.errors import SensorFault
from tactex.perception.acquisition import AcquisitionConfig
from tactex.pointcloud.cloud import SurfaceCloud
from tactex.tasks.capture import read_views
from tactex.tasks.robot import RealRobotParams, twin_dirt_remaining
from tactex.tasks.vision import capture_target_cloud

__all__ = ["TWIN_FRESH", "RobotCapture"]

#: The twin's count of its marking left at a run's start below which its dirt is not fresh (an earlier run's
#: cleaning), said in a warning [-].
TWIN_FRESH = 0.99


class RobotCapture:
    """The robot's camera (a frame source posed in the base frame) and what its captures took."""

    def __init__(self, camera, robot: RealRobotParams) -> None:
        self.camera = camera
        self.robot = robot
        self.times_s: list[float] = []  # wall clock of each capture (frames + processing) [s]
        self._twin_dirt = twin_dirt_remaining(robot)
        self._dirt_seen = float("nan")
        self._dirt_start = float("nan")  # the twin's count at this run's first answer (of its whole marking)

    @property
    def knows_dirt(self) -> bool:
        """Whether the dirt left is known (the twin's own count)."""
        return self._twin_dirt is not None

    def capture(self, loop, acq: AcquisitionConfig) -> SurfaceCloud:
        """Pause torque control, read ``capture_frames`` frames, and make the target cloud of the last."""
        loop.pause()
        t0 = time.perf_counter()
        try:
            frames = read_views(self.camera, self.robot.capture_frames, getattr(self.camera, "what", "the camera"))
        finally:
            stop = getattr(self.camera, "stop", None)
            if stop is not None:
                stop()  # the twin renders only while streamed
        cloud = capture_target_cloud(frames[-1], acq)
        self.times_s.append(time.perf_counter() - t0)
        self.refresh()
        return cloud

    def refresh(self, final: bool = False) -> None:
        """Ask the twin for its count of the dirt left: kept from its last answer when it does not answer, but
        not known (NaN) when it does not answer the ``final`` ask at the run's end (the twin stopped)."""
        if self._twin_dirt is None:
            return
        try:
            self._dirt_seen = self._twin_dirt()
        except SensorFault:
            if final:
                self._dirt_seen = float("nan")
            return
        if math.isnan(self._dirt_start):
            self._dirt_start = self._dirt_seen
            if self._dirt_start < TWIN_FRESH:
                warnings.warn(f"the twin holds {100 * self._dirt_start:.1f} % of its marking at this run's start (a "
                              "run before cleaned it): the dirt removed is counted from there; restart tactex twin "
                              "for a fresh part", RuntimeWarning, stacklevel=2)

    def dirt_remaining(self) -> float:
        """The fraction of the dirt at this run's start left at the last capture or refresh (NaN: not known)."""
        return self._dirt_seen / self._dirt_start if self._dirt_start > 0.0 else float("nan")

    def metrics(self) -> dict:
        return {"camera": self.robot.camera, "captures": len(self.times_s), "capture_time_s": float(sum(self.times_s)),
                "capture_times_s": list(self.times_s), "dirt_truth": "twin" if self.knows_dirt else "none",
                "twin_dirt_at_start": self._dirt_start}
