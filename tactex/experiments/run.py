"""The run driver shared by ``tactex clean`` and ``tactex wipe``: one task run into its run folder
with its report and replay video, or tactex beside its baselines with an index page.

``run_task`` runs one closed-loop task (cleaning, TEC §V-A; wiping, VA-UFIC §III), writes its run
folder (:func:`tactex.report.write_run_report`) and, when GL rendering works, a replay video.
``run_compare`` runs tactex and its baselines into sub-folders with an index page led by their
overlay (``compare.png``, :mod:`tactex.report.compare_plot`). Each prepares
the folder it writes (:func:`~tactex.experiments.run_folder.prepare_out_dir`); a command only
checks, before any work, that ``--out`` holds no other run.
"""

from __future__ import annotations

import dataclasses
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from tactex.errors import ConfigError, InputError, MissingDependencyError, RunInterrupted
from tactex.experiments.run_folder import prepare_out_dir
from tactex.experiments.tasks import baseline_names, task_spec
from tactex.experiments.video import write_replay_video
from tactex.report.compare_plot import plot_compare
from tactex.report.run_report import RunReport, run_remarks, summary_table, write_index_html, write_run_report

__all__ = ["Note", "note_stderr", "remark_lines", "run_compare", "run_task", "task_summary"]

Note = Callable[[str], None]


def note_stderr(msg: str) -> None:
    """The drivers' default way to tell the user what happens: a line on stderr."""
    print(msg, file=sys.stderr, flush=True)


def _try_video(result: Any, rep: RunReport, enabled: bool) -> None:
    if not enabled:
        return
    try:
        rep.files["video"] = write_replay_video(result, rep.out_dir / "replay.gif")
    except MissingDependencyError:
        rep.notes.append("video skipped: GL rendering unavailable (without a display, set MUJOCO_GL=egl or osmesa)")
    except InputError as exc:
        rep.notes.append(f"video skipped: {exc}")


def run_task(kind: str, config: Any, out_dir: str | Path, *, label: str | None = None, progress: bool = True,
             video: bool = True, note: Note | None = note_stderr, robot: Any = None, live: Any = None) -> RunReport:
    """Run one task with ``config`` and write its run folder; returns the report (metrics, files, notes).
    ``robot``: :class:`~tactex.tasks.robot.RealRobotParams` to run on a real Franka, None for simulation.
    ``live``: a :class:`~tactex.tasks.live_feed.LiveFeed` the run shows itself on (``--view``), or None.

    Ctrl-C during the task's program writes what it recorded (metrics marked ``"partial": true``, no
    video), then raises :class:`~tactex.errors.RunInterrupted`."""
    spec = task_spec(kind)
    if not isinstance(config, spec.config_cls):
        raise ConfigError(f"{kind} needs a {spec.config_cls.__name__}, got {type(config).__name__}")
    from tactex.tasks.robot import stopped_by_user

    out = prepare_out_dir(out_dir)
    extra = {"robot": robot} if robot is not None else {}
    if live is not None:
        extra["live"] = live
    result = spec.run(config, progress=progress, **extra)
    interrupted = stopped_by_user(result.metrics)
    if live is not None:  # the program has ended: the page's Stop has nothing left to stop (not the report)
        live.finish(stopped=interrupted)
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
                progress: bool = True, video: bool = True, note: Note | None = note_stderr) -> list[RunReport]:
    """tactex and its baselines with the same parameters, each in ``out_dir/<name>``, plus ``compare.png`` (the
    methods on shared axes) and ``index.html``."""
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
    overlay = plot_compare(kind, [(r.label, r.out_dir) for r in reports], out / "compare.png")
    if note is not None:
        for n in overlay.notes:
            note(f"{kind} compare: {n}")
    write_index_html(out / "index.html", reports, title=f"tactex {kind}: tactex vs baselines", figure=overlay.path,
                     figure_notes=overlay.notes)
    (out / "summary.txt").write_text(summary_table([(r.label, r.metrics) for r in reports]) + "\n")
    return reports


def remark_lines(runs: Sequence[tuple[str, Any]]) -> list[str]:
    """The runs' remarks (:func:`~tactex.report.run_report.run_remarks`), a line each, grouped by topic."""
    said = [(topic, name, line) for name, metrics in runs for topic, line in run_remarks(metrics)]
    topics = list(dict.fromkeys(topic for topic, _, _ in said))
    return [f"{topic} ({name}): {line}" for t in topics for topic, name, line in said if topic == t]


def task_summary(reports: Sequence[RunReport]) -> str:
    """What a command prints after its runs: the table of their metrics, then a line per run whose
    safety layer stepped in."""
    rows = [(r.label, r.metrics) for r in reports]
    for r in reports:  # a re-planned wipe: the first pass it re-planned from beside it
        first = (r.metrics.get("replan") or {}).get("first_pass")
        if first:
            rows.insert(0, (f"first pass ({Path(r.metrics['replan']['from']).name})", first))
    lines = [summary_table(rows)]
    lines += remark_lines([(r.label, r.metrics) for r in reports])
    return "\n".join(lines)
