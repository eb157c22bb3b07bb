"""Segments run one after another: :class:`PolicySequence`.

Each segment starts where the previous one ended (its offsets are shifted by the previous end), so
the path has no position jump. Its velocity may jump at a join (a line ending at rest, a sinusoid
starting at speed): over ``blend_s`` [s] centred on each join the reference mixes the two segments,
each continued past its end in a straight line at its end velocity, with a minimum-jerk weight. The
mix starts and ends on one segment's own reference with its own rate, so the blended reference is
C¹; its acceleration is about the velocity jump over ``blend_s``, which the validator checks
against the task's limit. The force set points mix the same way."""

from __future__ import annotations

import bisect
import math

from tactex.errors import ConfigError
from tactex.tasks.policies.base import ForceMotionPolicy, PolicyPoint, PolicySegment
from tactex.tasks.policies.timing import min_jerk

__all__ = ["PolicySequence"]


class PolicySequence(ForceMotionPolicy):
    """``segments`` one after another, velocity jumps at the joins blended over ``blend_s`` [s]."""

    def __init__(self, segments: list[PolicySegment], blend_s: float = 0.0) -> None:
        if not segments:
            raise ConfigError("a policy needs at least one segment")
        if not (isinstance(blend_s, (int, float)) and math.isfinite(blend_s) and blend_s >= 0):
            raise ConfigError(f"blend_s must be a number of seconds ≥ 0, got {blend_s!r}")
        self.segments = list(segments)
        self.blend_s = float(blend_s)
        starts, origins, t, o = [], [], 0.0, (0.0, 0.0)
        for k, seg in enumerate(self.segments):
            if k and self.blend_s > min(seg.duration_s, self.segments[k - 1].duration_s):
                raise ConfigError(f"segment {k + 1} ({seg.kind}): blend_s = {self.blend_s:g} s is longer than this "
                                  f"segment or the one before it; shorten blend_s or lengthen duration_s")
            starts.append(t)
            origins.append(o)
            if not math.isfinite(seg.duration_s):
                if k + 1 < len(self.segments):
                    raise ConfigError(f"segment {k + 1} ({seg.kind}): duration_s: only the last segment may run "
                                      "until the task stops it")
                t = math.inf
                break
            end = seg.at(seg.duration_s)
            t += seg.duration_s
            o = (o[0] + end.u_m, o[1] + end.v_m)
        self._starts, self._origins = starts, origins
        self.duration_s = t

    @property
    def segment_starts_s(self) -> tuple[float, ...]:
        return tuple(self._starts)

    def segment_index(self, t_s: float) -> int:
        return max(0, bisect.bisect_right(self._starts, t_s) - 1)

    def _on(self, k: int, t_s: float) -> PolicyPoint:
        """Segment ``k``'s own reference at policy time ``t_s``, shifted to where it starts."""
        p = self.segments[k].at(t_s - self._starts[k])
        ou, ov = self._origins[k]
        return p._replace(u_m=ou + p.u_m, v_m=ov + p.v_m)

    def at(self, t_s: float) -> PolicyPoint:
        if len(self.segments) == 1:
            return self.segments[0].at(t_s)
        k = self.segment_index(t_s)
        h = 0.5 * self.blend_s
        if h > 0.0:
            if k >= 1 and t_s < self._starts[k] + h:
                return self._blend(k - 1, k, t_s)
            if k + 1 < len(self.segments) and t_s > self._starts[k + 1] - h:
                return self._blend(k, k + 1, t_s)
        return self._on(k, t_s)

    def _blend(self, a: int, b: int, t_s: float) -> PolicyPoint:
        h = 0.5 * self.blend_s
        w, dw = min_jerk((t_s - (self._starts[b] - h)) / (2.0 * h))
        dw /= 2.0 * h
        pa, pb = self._on(a, t_s), self._on(b, t_s)
        return PolicyPoint(
            (1.0 - w) * pa.u_m + w * pb.u_m, (1.0 - w) * pa.v_m + w * pb.v_m,
            (1.0 - w) * pa.du_m_s + w * pb.du_m_s + dw * (pb.u_m - pa.u_m),
            (1.0 - w) * pa.dv_m_s + w * pb.dv_m_s + dw * (pb.v_m - pa.v_m),
            (1.0 - w) * pa.force_n + w * pb.force_n)

    @property
    def constant_force_n(self) -> float | None:
        forces = {seg.constant_force_n for seg in self.segments}
        return forces.pop() if len(forces) == 1 else None
