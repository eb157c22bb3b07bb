"""The tactex demo, and the run-and-report driver shared by ``tactex clean`` and ``tactex wipe``.

``run_task`` runs one closed-loop task (cleaning, TEC §V-A; wiping, VA-UFIC §III), writes its run
folder (:func:`tactex.report.write_run_report`) and, when GL rendering works, a replay video.
``run_compare`` runs tactex and its baselines into sub-folders with an index page.
``run_demo`` is ``tactex demo``: a short clean of the built-in plate and a short wipe of the sine
panel, no files needed, one run folder with an ``index.html`` linking the runs.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from tactex.config import param, write_json
from tactex.errors import ConfigError, InputError, MissingDependencyError, RunInterrupted
from tactex.report.outdir import prepare_out_dir
from tactex.report.run_report import RunReport, safety_summary, summary_table, write_index_html, write_run_report

__all__ = [
    "DemoConfig",
    "DemoResult",
    "TaskSpec",
    "baseline_names",
    "run_compare",
    "run_demo",
    "run_task",
    "task_spec",
    "write_replay_video",
]

Note = Callable[[str], None]


@dataclass(frozen=True)
class TaskSpec:
    """A closed-loop task: its config class, its runner, its baselines ('' is tactex itself)."""

    name: str
    config_cls: type
    run: Callable[..., Any]
    baselines: tuple[str, ...]


def task_spec(kind: str) -> TaskSpec:
    """The cleaning or wiping task (imported lazily: each pulls in MuJoCo)."""
    if kind == "clean":
        from tactex.tasks.clean import CLEAN_BASELINES, CleanConfig, run_clean

        return TaskSpec("clean", CleanConfig, run_clean, tuple(CLEAN_BASELINES))
    if kind == "wipe":
        from tactex.tasks.wipe import WIPE_BASELINES, WipeConfig, run_wipe

        return TaskSpec("wipe", WipeConfig, run_wipe, tuple(WIPE_BASELINES))
    raise ConfigError(f"unknown task '{kind}'; valid: clean, wipe")


def baseline_names(kind: str) -> tuple[str, ...]:
    """The named baselines of a task (without tactex itself)."""
    return tuple(b for b in task_spec(kind).baselines if b)


def _note_stderr(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


# --------------------------------------------------------------------------------------------- video


def write_replay_video(result: Any, path: str | Path, *, fps: float = 8.0, max_frames: int = 80,
                       width: int = 320, height: int = 240) -> Path:
    """Replay the recorded joint positions ``series['q']`` in a fresh scene and write an animated GIF.

    Kinematic replay (the dirt texture is not replayed): MuJoCo renders each posture with OpenGL,
    so this needs ``MUJOCO_GL=egl`` or ``osmesa`` on a machine without a display; otherwise
    :class:`MissingDependencyError`. Pillow (a matplotlib dependency) writes the GIF, so no ffmpeg.
    """
    from PIL import Image

    from tactex.robots.mujoco_backend import MujocoBackend

    series = getattr(result, "series", {}) or {}
    if "q" not in series or "t" not in series:
        raise InputError("the run recorded no joint positions 'q' in its series, so there is nothing to replay")
    q, t = np.asarray(series["q"], dtype=np.float64), np.asarray(series["t"], dtype=np.float64)
    if q.ndim != 2 or q.shape[0] != t.shape[0] or q.shape[0] == 0:
        raise InputError(f"series 'q' must be (T, n_joints) like 't' ({t.shape[0]} rows), got {q.shape}")
    if fps <= 0 or max_frames < 1:
        raise ConfigError(f"fps must be > 0 and max_frames ≥ 1, got {fps} and {max_frames}")
    n = int(min(max_frames, max(1, np.floor((t[-1] - t[0]) * fps) + 1)))
    idx = np.unique(np.searchsorted(t, np.linspace(t[0], t[-1], n)).clip(0, len(t) - 1))
    backend = MujocoBackend(result.config.scene())
    try:
        frames = []
        for i in idx:
            if not np.isfinite(q[i]).all():
                continue
            backend.reset(q0=q[i])
            frames.append(Image.fromarray(backend.render_rgb(width, height)))
    finally:
        backend.close()
    if not frames:
        raise InputError("series 'q' holds no finite posture to render")
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    frames[0].save(out, save_all=True, append_images=frames[1:], duration=int(1000 / fps), loop=0)
    return out


def _try_video(result: Any, rep: RunReport, enabled: bool) -> None:
    if not enabled:
        return
    try:
        rep.files["video"] = write_replay_video(result, rep.out_dir / "replay.gif")
    except MissingDependencyError:
        rep.notes.append("video skipped: GL rendering unavailable (without a display, set MUJOCO_GL=egl or osmesa)")
    except InputError as exc:
        rep.notes.append(f"video skipped: {exc}")


# --------------------------------------------------------------------------------------------- runs


def run_task(kind: str, config: Any, out_dir: str | Path, *, label: str | None = None, progress: bool = True,
             video: bool = True, note: Note | None = _note_stderr, robot: Any = None) -> RunReport:
    """Run one task with ``config`` and write its run folder; returns the report (metrics, files, notes).
    ``robot``: :class:`~tactex.tasks.robot.RealRobotParams` to run on a real Franka, None for simulation.

    Ctrl-C during the task's program writes what it recorded (metrics marked ``"partial": true``, no
    video), then raises :class:`~tactex.errors.RunInterrupted`."""
    spec = task_spec(kind)
    if not isinstance(config, spec.config_cls):
        raise ConfigError(f"{kind} needs a {spec.config_cls.__name__}, got {type(config).__name__}")
    from tactex.tasks.robot import stopped_by_user

    out = prepare_out_dir(out_dir)
    result = spec.run(config, progress=progress) if robot is None else spec.run(config, progress=progress, robot=robot)
    interrupted = stopped_by_user(result.metrics)
    rep = write_run_report(result, out, label=label or (config.baseline or "tactex"))
    _try_video(result, rep, video and not interrupted)  # after Ctrl-C the user waits for the exit, not a replay
    if note is not None:
        for n in rep.notes:
            note(f"{kind} {rep.label}: {n}")
    if interrupted:
        raise RunInterrupted(f"what the {kind} run recorded up to then ({result.metrics.get('sim_time_s', 0.0):.1f} s) "
                             f"is in {out}: metrics.json (\"partial\": true), series.npz and the report")
    return rep


def run_compare(kind: str, config: Any, out_dir: str | Path, *, baselines: Sequence[str] | None = None,
                progress: bool = True, video: bool = True, note: Note | None = _note_stderr) -> list[RunReport]:
    """tactex and its baselines with the same parameters, each in ``out_dir/<name>``, plus ``index.html``."""
    names = tuple(baseline_names(kind) if baselines is None else baselines)
    valid = baseline_names(kind)
    for b in names:
        if b not in valid:
            raise ConfigError(f"unknown {kind} baseline '{b}'; valid: {', '.join(valid)}")
    out = prepare_out_dir(out_dir)
    reports = []
    for b in ("", *names):
        label = b or "tactex"
        if note is not None:
            note(f"{kind}: running {label}")
        cfg = dataclasses.replace(config, baseline=b)
        reports.append(run_task(kind, cfg, out / label, label=label, progress=progress, video=video, note=note))
    write_index_html(out / "index.html", reports, title=f"tactex {kind}: tactex vs baselines")
    (out / "summary.txt").write_text(summary_table([(r.label, r.metrics) for r in reports]) + "\n")
    return reports


# --------------------------------------------------------------------------------------------- demo


@dataclass(frozen=True)
class DemoConfig:
    """``tactex demo``: short runs of both tasks on built-in objects (budgets tuned for < 3 min wall)."""

    clean_budget_s: float = param(40.0, "simulated time of the short cleaning run on the plate [s]")
    wipe_duration_s: float = param(10.0, "simulated duration of the short wiping run on the sine panel [s]")
    baselines: bool = param(
        False, "also run the baselines (raster, HEDAC without vision; Cartesian impedance): about 2.5× longer"
    )
    quick: bool = param(False, "a smoke run: a quarter of the budgets, no baselines")
    video: bool = param(True, "write replay videos when GL rendering works")
    seed: int = param(0, "seed of the simulations and the explorer")

    def __post_init__(self) -> None:
        for name in ("clean_budget_s", "wipe_duration_s"):
            v = float(getattr(self, name))
            if not (np.isfinite(v) and v > 0):
                raise ConfigError(f"{name} must be a positive number of seconds, got {getattr(self, name)!r}")

    def task_configs(self) -> dict[str, Any]:
        """The CleanConfig and WipeConfig of the demo."""
        scale = 0.25 if self.quick else 1.0
        clean = task_spec("clean").config_cls(object_name="plate", marking="X", budget_s=scale * self.clean_budget_s,
                                              seed=self.seed)
        wipe = task_spec("wipe").config_cls(duration_s=scale * self.wipe_duration_s, seed=self.seed)
        return {"clean": clean, "wipe": wipe}


@dataclass
class DemoResult:
    """The demo's run folder, its index page, the reports per task and the terminal summary."""

    out_dir: Path
    index: Path
    reports: dict[str, list[RunReport]] = field(default_factory=dict)
    wall_time_s: float = 0.0

    def summary(self) -> str:
        """The tables of the runs per task, then a line per run whose safety layer stepped in."""
        tables = {k: summary_table([(r.label, r.metrics) for r in reps]) for k, reps in self.reports.items() if reps}
        text = "\n\n".join(f"{kind}:\n{table}" for kind, table in tables.items())
        safety = [f"safety layer ({kind} {r.label}): {said}" for kind, reps in self.reports.items() for r in reps
                  if (said := safety_summary(r.metrics))]
        return "\n\n".join([text, "\n".join(safety)]) if safety else text


def run_demo(out_dir: str | Path = "runs/demo", config: DemoConfig | None = None, *, progress: bool = True,
             note: Note | None = _note_stderr) -> DemoResult:
    """Short clean + short wipe (+ baselines) into ``out_dir/<task>/<run>``, with ``out_dir/index.html``."""
    cfg = config or DemoConfig()
    out = prepare_out_dir(out_dir)
    wall0 = time.perf_counter()
    configs = cfg.task_configs()
    plan = [(kind, b) for kind in ("clean", "wipe")
            for b in ("", *(baseline_names(kind) if cfg.baselines and not cfg.quick else ()))]
    reports: dict[str, list[RunReport]] = {"clean": [], "wipe": []}
    for i, (kind, b) in enumerate(plan, 1):
        label = b or "tactex"
        if note is not None:
            note(f"demo [{i}/{len(plan)}] {kind} {label}")
        task_cfg = dataclasses.replace(configs[kind], baseline=b)
        reports[kind].append(run_task(kind, task_cfg, out / kind / label, label=label, progress=progress,
                                      video=cfg.video, note=note))
    all_reports = [r for reps in reports.values() for r in reps]
    index = write_index_html(out / "index.html", all_reports, title="tactex demo")
    result = DemoResult(out_dir=out, index=index, reports=reports, wall_time_s=time.perf_counter() - wall0)
    write_json({"demo": cfg, "tasks": configs}, out / "config.json")
    (out / "summary.txt").write_text(result.summary() + "\n")
    return result
