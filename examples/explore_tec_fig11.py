"""TEC Fig. 11: ergodicity over 1000 steps on the paper's three clouds, ten starts each (K = 200, α = 10).

    python examples/explore_tec_fig11.py [OUT_DIR]

Needs the TEC clouds in ../shared/data/tactile_ergodic_control (or $TACTEX_SHARED_DATA). Every
run writes its own report under OUT_DIR/<cloud>/<start>; OUT_DIR/fig11_<cloud>.png shows the ten
runs, their mean and standard deviation, as in the paper.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np

from tactex.experiments import ExploreConfig, run_explore
from tactex.report import plot_series, write_metrics

REPO = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("TACTEX_SHARED_DATA", REPO.parent / "shared" / "data")) / "tactile_ergodic_control"
out = Path(sys.argv[1] if len(sys.argv) > 1 else "runs/tec_fig11")
if not DATA.is_dir():
    sys.exit(f"TEC clouds not found in {DATA}")

summary = {}
for name in ("bun270_X", "cup_X", "plate_shapes"):
    runs = []
    print(f"{name}: ten starts of 1000 steps ...", flush=True)
    for start in range(10):  # seed i picks the authors' start position i
        # TEC §VI-D: "a high number" of neighbours so that the bunny is one object (30 leaves its ear apart).
        cfg = ExploreConfig(steps=1000, n_eigen=200, alpha=10.0, n_neighbors=50, seed=start, html=False)
        result = run_explore(DATA / f"{name}.ply", out / name / f"start{start}", cfg)
        runs.append(result.metrics["ergodicity"])
    runs = np.asarray(runs)
    plot_series({"ergodicity ε (eq. 48)": runs}, out / f"fig11_{name}.png", title=f"{name}: 10 starts")
    final = runs[:, -1]
    summary[name] = {"final_mean": float(final.mean()), "final_std": float(final.std()), "final": final}
    print(f"{name}: ergodicity after 1000 steps {final.mean():.3f} ± {final.std():.3f}")
write_metrics(summary, out / "fig11_summary.json")
print(f"figures and per-run reports in {out}")
