"""Shared fixtures: the TEC point clouds in ../shared/data (skipped with a reason when absent)."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import numpy as np
import pytest
from hypothesis import settings

from tactex.pointcloud import SurfaceCloud

# Property tests draw the same examples on every run: reproducible, and CI cannot flake on a new draw.
settings.register_profile("tactex", derandomize=True)
settings.load_profile("tactex")

try:  # one BLAS thread: on a shared 2-core machine threaded BLAS makes small products 2–10× slower
    from threadpoolctl import threadpool_limits

    threadpool_limits(1)
except ImportError:  # pragma: no cover - threadpoolctl is a dependency, but the suite must not need it
    pass

os.environ.setdefault("MUJOCO_GL", "disable")
os.environ.setdefault("MPLBACKEND", "Agg")

# A suite started in the background by a non-interactive shell (`make test &`, some CI runners) has
# SIGINT ignored, and every process it starts inherits that: the tests that Ctrl-C a run would see it
# finish instead. Python's own handler here gives the children the default action back at exec.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)



def pytest_collection_modifyitems(config, items) -> None:
    """The Ray tests run last: after them (ray.shutdown() included) the real-time twin tests in this
    process lose the F/T stream's timing (test_ft_stream_stopped_is_a_lost_sensor_as_in_simulation
    failed after them and passes alone or before them)."""
    items.sort(key=lambda item: item.get_closest_marker("distributed") is not None)  # stable: order kept


REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("TACTEX_SHARED_DATA", REPO.parent / "shared" / "data")) / "tactile_ergodic_control"
TEC_CLOUDS = ("bun270_X", "cup_X", "plate_shapes")


def tec_cloud_path(name: str) -> Path:
    """Path of a TEC cloud; skips the calling test when ../shared/data is not there."""
    path = SHARED_DATA / f"{name}.ply"
    if not path.is_file():
        pytest.skip(f"TEC point cloud {path} not found: these tests need ../shared/data beside the repository")
    return path


def tec_initial_positions(name: str) -> np.ndarray:
    """The authors' ten initial agent positions (10, 3) [m] for a TEC cloud."""
    path = SHARED_DATA / f"{name}_x0_arr_10.npz"
    if not path.is_file():
        pytest.skip(f"{path} not found: these tests need ../shared/data beside the repository")
    with np.load(path, allow_pickle=False) as z:
        return np.array(z["x0_arr"], dtype=float)


def gap_strips(gap_m: float, target_beyond_m: float, seed: int) -> SurfaceCloud:
    """Two 3 mm grids (15 × 30 points) on z = 0 side by side along x with a scan hole of gap_m [m]
    between them; the target is the right grid's points farther than target_beyond_m [m] from the hole."""
    h = 0.003
    rng = np.random.default_rng(seed)
    u, v = np.meshgrid(np.arange(15) * h, np.arange(30) * h)
    left = np.c_[u.ravel(), v.ravel(), np.zeros(u.size)]
    right = left + np.array([14 * h + gap_m, 0.0, 0.0])
    pts = np.vstack([left, right]) + rng.uniform(-1e-4, 1e-4, (2 * u.size, 3)) * [1, 1, 0]
    return SurfaceCloud(pts, target=(pts[:, 0] > 14 * h + gap_m + target_beyond_m).astype(float), spacing=h)


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)


@pytest.fixture
def descent_sweep_search(monkeypatch) -> None:
    """The planned sweep's search as a pure descent moving one corner at a time (no annealing, reversals or recuts):
    the search that planned the sweeps some scenarios were found with, reproduced draw for draw."""
    from tactex.tasks.clean import sweep_plan

    monkeypatch.setattr(sweep_plan, "ANNEAL_START_M", 0.0)
    monkeypatch.setattr(sweep_plan, "STEP_SHRINK", 1.0)
    monkeypatch.setattr(sweep_plan, "REVERSE_SHARE", 0.0)
    monkeypatch.setattr(sweep_plan, "RECUT_SHARE", 0.0)


@pytest.fixture(autouse=True)
def _no_machine_wide_idle_request(monkeypatch) -> None:
    """No test makes the CPUs of the machine running the suite poll (a PM QoS request is system-wide);
    the tests of the request give it a device of their own."""
    from tactex.robots import cpu_latency

    monkeypatch.setattr(cpu_latency, "PM_QOS_DEVICE", "/nonexistent/cpu_dma_latency")
