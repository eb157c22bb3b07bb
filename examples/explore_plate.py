"""Explore the built-in plate with its drawn shapes and write a small report.

    python examples/explore_plate.py [OUT_DIR]

The same as ``tactex explore plate --steps 300 --out OUT_DIR``, spelled out with the library:
sample the surface, mark the target, build the Laplace basis, step the HEDAC explorer.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from tactex.ergodic import HedacConfig, HedacExplorer
from tactex.pointcloud.markings import marked_cloud
from tactex.pointcloud.shapes import get_surface
from tactex.report import cloud_html, plot_cloud, plot_series, write_metrics
from tactex.spectral import build_basis

out = Path(sys.argv[1] if len(sys.argv) > 1 else "runs/explore_plate")
cloud = marked_cloud(get_surface("plate"), "shapes", spacing_m=0.003)  # 3 mm, as TEC's voxel grid
basis = build_basis(cloud, n_eigen=200)  # cached on disk after the first run
explorer = HedacExplorer(cloud, basis, HedacConfig(alpha=10.0, n_eigen=200, agent_radius_m=0.015))

explorer.reset(np.array([0.0, -0.06, 0.0]))  # on the plate, below the square (projected onto it)
path, ergodicity = [], []
for _ in range(300):
    path.append(explorer.step().point)
    ergodicity.append(explorer.ergodicity())
path = np.array(path)

fields = {"target": cloud.target, "coverage": explorer.coverage, "potential": explorer.potential}
plot_series({"ergodicity ε": ergodicity}, out / "ergodicity.png")
plot_cloud(cloud.points, fields, out / "cloud.png", trajectory=path)
cloud_html(cloud.points, fields, out / "plate.html", trajectory=path, title="plate, 300 steps", keep=cloud.target > 0,
           normals=cloud.normals)
write_metrics({"n_points": len(cloud), "ergodicity": ergodicity, "path_length_m": explorer.path_length}, out / "m.json")
print(f"{len(cloud)} points, ergodicity {ergodicity[-1]:.3f} after 300 steps; report in {out}")
