"""Fuzz one reader with atheris for a bounded time; ``make fuzz`` runs every reader.

    python tools/fuzz/run.py ply --seconds 600 --out fuzz

Each input is written to a file with the reader's suffix (the readers take paths) and read. It
passes when the reader returns a valid result or raises a :mod:`tactex.errors` type whose message
names the file, printing nothing and logging nothing. Anything else is a crash: another exception,
a MemoryError (the address space is capped, so an allocation bomb fails fast instead of swapping),
more than ``--hang-seconds`` of CPU on one input, output on stdout/stderr or a log record. Crashes
are grouped into classes (exception type and the innermost frame); the first input of each class
is kept in ``OUT/crashes/READER/``. Executions, crashes and classes go to ``OUT/READER.json``
every few seconds and at the end. Python warnings are counted apart (the CLI shows them as one line).
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import json
import logging
import os
import resource
import shutil
import signal
import sys
import tempfile
import time
import traceback
import warnings
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parent))

from targets import TARGETS, LogRecords

#: Modules instrumented for coverage feedback: the readers and the libraries they call.
INSTRUMENTED = ["tactex", "plyfile", "pypcd4", "trimesh", "tomllib", "numpy.lib", "zipfile", "json"]
#: Address space of the fuzz process [bytes]: far above what any seed needs, far below the machine.
MEMORY_LIMIT = 4 << 30


class Hang(Exception):
    """One input took more than the allowed CPU time."""


def _on_hang(signum, frame):
    raise Hang("more CPU time than allowed on one input")


class Fuzzer:
    """Runs one reader on inputs and keeps the tally."""

    def __init__(self, name: str, out: Path, seconds: float, hang_seconds: float) -> None:
        self.name = name
        self.target = TARGETS[name]
        self.out = out
        self.crash_dir = out / "crashes" / name
        self.started = time.time()
        self.deadline = self.started + seconds
        self.hang_seconds = hang_seconds
        self.work = Path(tempfile.mkdtemp(prefix=f"tactex-fuzz-{name}-", dir="/dev/shm" if Path("/dev/shm").is_dir()
                                          else None))
        self.executions = 0
        self.crashes = 0
        self.classes: dict[str, dict] = {}
        self.warnings: dict[str, int] = {}
        self.last_write = 0.0
        # a real file, not a StringIO: libraries ask sys.stderr for its fileno() (faulthandler, lazy imports)
        self.sink = tempfile.TemporaryFile("w+", dir=self.work)
        self.records = LogRecords()
        logging.getLogger().addHandler(self.records)
        signal.signal(signal.SIGVTALRM, _on_hang)

    def _path(self, data: bytes) -> tuple[Path, bytes]:
        suffix = self.target.suffix
        if callable(suffix):
            suffix, data = suffix(data)
        return self.work / f"input{suffix}", data

    def _crash(self, key: str, detail: str, data: bytes, suffix: str) -> None:
        self.crashes += 1
        entry = self.classes.get(key)
        if entry is None:
            self.crash_dir.mkdir(parents=True, exist_ok=True)
            example = self.crash_dir / (hashlib.sha1(data).hexdigest()[:12] + suffix)
            example.write_bytes(data)
            self.classes[key] = {"count": 1, "detail": detail[:300], "example": str(example),
                                 "first_after_s": round(time.time() - self.started, 1)}
            print(f"[{self.name}] new crash class: {key}: {detail[:160]}", file=sys.__stderr__, flush=True)
            self.write()
        else:
            entry["count"] += 1

    def one(self, raw: bytes) -> None:
        """Read one input; record a crash if it is one."""
        if time.time() >= self.deadline:
            self.write()
            self.sink.close()
            shutil.rmtree(self.work, ignore_errors=True)
            os._exit(0)  # libFuzzer would exit() without running Python's clean-up either
        from tactex.errors import TactexError

        path, data = self._path(raw)
        path.write_bytes(data)
        self.executions += 1
        self.records.records.clear()
        self.sink.seek(0)
        self.sink.truncate()
        key = detail = None
        signal.setitimer(signal.ITIMER_VIRTUAL, self.hang_seconds)
        try:
            with warnings.catch_warnings(record=True) as caught, contextlib.redirect_stderr(self.sink), \
                    contextlib.redirect_stdout(self.sink):
                warnings.simplefilter("always")
                self.target.read(path)
        except TactexError as exc:
            if self.target.names_file and path.name not in str(exc):
                key, detail = f"{type(exc).__name__} without the file name", str(exc)
        except BaseException as exc:
            if isinstance(exc, KeyboardInterrupt):
                raise
            frame = traceback.extract_tb(exc.__traceback__)[-1] if exc.__traceback__ else None
            where = f"{Path(frame.filename).name}:{frame.name}" if frame else "?"
            key, detail = f"{type(exc).__name__} at {where}", f"{exc}"
        finally:
            signal.setitimer(signal.ITIMER_VIRTUAL, 0)
        self.sink.flush()
        self.sink.seek(0)
        printed = self.sink.read()
        if key is None and printed:
            key, detail = "printed output", printed
        if key is None and self.records.records:
            rec = self.records.records[0]
            key, detail = f"log record from {rec.name}", rec.getMessage()
        for w in caught if "caught" in locals() else ():
            tag = f"{w.category.__name__}: {str(w.message)[:80]}"
            if tag not in self.warnings:  # keep the first input of each, to trace it
                self.crash_dir.mkdir(parents=True, exist_ok=True)
                (self.crash_dir / f"warning-{hashlib.sha1(data).hexdigest()[:12]}{path.suffix}").write_bytes(data)
            self.warnings[tag] = self.warnings.get(tag, 0) + 1
        if key is not None:
            self._crash(key, detail, data, path.suffix)
        if time.time() - self.last_write > 5.0:
            self.write()

    def write(self) -> None:
        self.last_write = time.time()
        summary = {"reader": self.name, "executions": self.executions,
                   "seconds": round(self.last_write - self.started, 1), "crashes": self.crashes,
                   "crash_classes": self.classes, "warnings": self.warnings}
        self.out.mkdir(parents=True, exist_ok=True)
        (self.out / f"{self.name}.json").write_text(json.dumps(summary, indent=2) + "\n")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("reader", choices=sorted(TARGETS))
    parser.add_argument("--seconds", type=float, default=600.0, help="how long to fuzz [s]")
    parser.add_argument("--out", type=Path, default=Path("fuzz"), help="folder of the results and crashes")
    parser.add_argument("--hang-seconds", type=float, default=5.0, help="CPU time one input may take [s]")
    parser.add_argument("--max-len", type=int, default=4096, help="largest input [bytes]")
    args, libfuzzer_args = parser.parse_known_args(argv)
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))
    import atheris

    with atheris.instrument_imports(include=INSTRUMENTED):
        import tactex.experiments.study_spec
        import tactex.pointcloud.io
        import tactex.pointcloud.mesh
        import tactex.pointcloud.pcd_header
        import tactex.tasks.robot  # noqa: F401
    fuzzer = Fuzzer(args.reader, args.out, args.seconds, args.hang_seconds)
    corpus = args.out / "corpus" / args.reader
    corpus.mkdir(parents=True, exist_ok=True)
    for i, seed in enumerate(fuzzer.target.seeds()):
        (corpus / f"seed{i:02d}").write_bytes(seed)
    max_len = max(args.max_len, *(len(s) for s in fuzzer.target.seeds()))
    # libFuzzer's own limits: memory off (the address space is capped), time a safety net past ours
    # (atheris reads -timeout=0 as "any unit running at its 1 s check has timed out").
    artifacts = args.out / "artifacts" / args.reader
    artifacts.mkdir(parents=True, exist_ok=True)
    atheris.Setup([sys.argv[0], f"-max_total_time={int(args.seconds) + 60}", "-timeout=120", "-rss_limit_mb=0",
                   f"-artifact_prefix={artifacts}/",
                   f"-max_len={max_len}", "-print_final_stats=1", *libfuzzer_args, str(corpus)], fuzzer.one)
    atheris.Fuzz()


if __name__ == "__main__":
    main()
