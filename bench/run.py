"""`make bench`: run every bench/bench_*.py, write one JSON, print a table.

A bench module defines ``run(args) -> dict`` returning nested results (seconds, counts, ratios),
and optionally ``TARGETS``: {dotted.key: (op, value)} with op in {"<=", ">="}, shown in the
table as the target and whether the measurement met it. Timing lives here, never in tests.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import platform
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))


def _flatten(d: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(_flatten(v, key + "."))
        else:
            out[key] = v
    return out


def _merge(dst: dict, src: dict) -> None:
    for k, v in src.items():
        if isinstance(v, dict) and isinstance(dst.get(k), dict):
            _merge(dst[k], v)
        else:
            dst[k] = v


def _probe_ms(repeats: int = 5) -> float:
    """Median wall time [ms] of a fixed single-threaded workload (Python loop and small numpy
    products, the mix of a control tick). This machine is shared: its speed swings by up to ~1.7×
    within seconds, so each stage's timings are recorded beside the probe taken just before it."""
    import numpy as np

    a = np.eye(3) * 1.0001
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        acc = 0
        for i in range(20000):
            acc += i * i
        m = a
        for _ in range(2000):
            m = m @ a
        times.append(time.perf_counter() - t0)
    return 1e3 * sorted(times)[len(times) // 2]


def _versions(names: tuple[str, ...]) -> dict[str, str]:
    from importlib.metadata import PackageNotFoundError, version

    out = {}
    for name in names:
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            out[name] = "not installed"
    return out


def _fmt(v: object) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, list):
        return f"[{len(v)} values]" if len(v) > 4 else "[" + ", ".join(_fmt(x) for x in v) + "]"
    return str(v)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", default=str(HERE / "results.json"))
    parser.add_argument("--only", nargs="*", default=None, help="bench module names (e.g. spectral)")
    parser.add_argument("--quick", action="store_true", help="fewer repetitions (smoke run)")
    parser.add_argument("--cases", nargs="*", default=None,
                        help="stages with named cases (robustness, clean_time): run only those starting with these "
                             "prefixes")
    args = parser.parse_args()

    out_path = Path(args.out)
    results: dict = {}
    if out_path.exists() and args.only:
        results = json.loads(out_path.read_text())  # keep the other stages' numbers
    targets: dict = {}
    probes: dict = {}
    for path in sorted(HERE.glob("bench_*.py")):
        name = path.stem.removeprefix("bench_")
        if args.only and name not in args.only:
            continue
        spec = importlib.util.spec_from_file_location(f"bench_{name}", path)
        mod = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
        spec.loader.exec_module(mod)  # type: ignore[union-attr]
        probes[name] = _probe_ms()
        print(f"== bench {name}  (machine probe {probes[name]:.2f} ms; lower is faster)", flush=True)
        t0 = time.perf_counter()
        _merge(results, mod.run(args))
        targets.update(getattr(mod, "TARGETS", {}))
        print(f"   ({time.perf_counter() - t0:.1f} s)", flush=True)
    results["machine"] = {
        "python": platform.python_version(),
        "platform": platform.platform(),
        "cpu_count": __import__("os").cpu_count(),
        "date": time.strftime("%Y-%m-%d %H:%M:%S"),
        # the probe's time before each stage [ms]: compare runs only at similar probe times
        "probe_ms": {**results.get("machine", {}).get("probe_ms", {}), **probes},
        # what uv.lock installed: a figure that moves with a lock refresh says so here
        "packages": _versions(("numpy", "scipy", "mujoco", "numba", "robust-laplacian", "pygafro", "pylibfranka",
                               "franky-sim")),
    }
    out_path.parent.mkdir(parents=True, exist_ok=True)
    out_path.write_text(json.dumps(results, indent=2) + "\n")

    flat = _flatten(results)
    width = max((len(k) for k in flat), default=10)
    print(f"\n{'measurement'.ljust(width)}  {'value':>12}  {'target':>10}  ok")
    for key, value in flat.items():
        if key.startswith("machine."):
            continue
        tgt = targets.get(key)
        ok = ""
        tgt_s = ""
        if tgt is not None and isinstance(value, (int, float)):
            op, ref = tgt
            tgt_s = f"{op} {ref:g}"
            ok = "yes" if (value <= ref if op == "<=" else value >= ref) else "NO"
        print(f"{key.ljust(width)}  {_fmt(value):>12}  {tgt_s:>10}  {ok}")
    print(f"\nwritten: {out_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
