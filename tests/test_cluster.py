"""Studies and sweeps on a real two-node Ray cluster: a head and a worker node, each in its own
network namespace of this machine (tests/netns_cluster.py), and a third place submitting: a driver
on the head (``--ray-address 10.77.0.2:6379``) or a Ray client in the root namespace
(``--ray-address ray://10.77.0.2:10001``).

Needs root and network namespaces (``ip netns add``); skipped with the reason otherwise. The
namespaces, interfaces and every process in them are removed by the fixture's finalizer, whether
the tests pass or fail. The tests run in file order: the last one kills the worker node.
"""

from __future__ import annotations

import contextlib
import json
import os
import pickle
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

ray = pytest.importorskip("ray", reason="the distributed extra is not installed (pip install 'tactex[distributed]')")

from tactex.experiments.executor import LocalExecutor  # noqa: E402
from tactex.experiments.study import run_study  # noqa: E402
from tactex.experiments.study_spec import load_spec_file, spec_from_dict  # noqa: E402
from tactex.experiments.sweep import SweepConfig, prepare_clouds, run_sweep  # noqa: E402
from tests.conftest import tec_cloud_path  # noqa: E402
from tests.netns_cluster import (  # noqa: E402
    CLIENT_PORT,
    GCS_PORT,
    HEAD_IP,
    NODE_PORTS,
    WORKER_IP,
    Cluster,
    NetnsUnavailable,
)

pytestmark = [pytest.mark.slow, pytest.mark.distributed, pytest.mark.cluster]

HEAD_ADDRESS = f"{HEAD_IP}:{GCS_PORT}"
CLIENT_ADDRESS = f"ray://{HEAD_IP}:{CLIENT_PORT}"
#: Hang guard of one command on the cluster [s] (a study here takes well under a minute).
HANG_GUARD_S = 480

# Four short cleaning runs (tactex and the raster baseline on the plate, two seeds with F/T noise) whose dirt is
# the target of a cloud file (plate.npz, a scan in the robot's base frame): a file only the submitting place has.
STUDY_TOML = """task = "clean"
seeds = 2
[fixed]
object_name = "plate"
cloud = "plate.npz"
n_eigen = 60
budget_s = 1.0
ft_noise_n = 0.5
[grid]
baseline = ["", "raster"]
"""
# The study the worker node is killed in: eight longer runs (4 s of cleaning each), so that the worker node
# runs several of them and each is long enough to be seen in progress there.
KILL_STUDY_TOML = STUDY_TOML.replace("seeds = 2", "seeds = 4").replace("budget_s = 1.0", "budget_s = 4.0")
KILL_STUDY_RUNS = 8
# Six settings of a TEC cloud from ../shared/data: the cloud and its basis are the shared input.
SWEEP = {"n_eigen": (10, 30), "alpha": (5.0, 10.0, 20.0), "starts": 2, "steps": 30}
SWEEP_ARGS = ["--n-eigen", "10", "30", "--alpha", "5", "10", "20", "--starts", "2", "--steps", "30"]


# -- fixtures --------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def cluster(request):
    root = Path(tempfile.mkdtemp(prefix="txc-", dir="/tmp"))  # short: Ray's socket paths live under it
    failed_before = request.session.testsfailed
    try:
        hosts = Cluster.make(root)
    except NetnsUnavailable as exc:
        shutil.rmtree(root, ignore_errors=True)
        pytest.skip(f"no network namespaces for a cluster test: {exc}")
    try:
        hosts.start_head()
        hosts.start_worker()
        yield hosts
    finally:
        hosts.remove()
        left = hosts.leftovers()
        if request.session.testsfailed == failed_before:
            shutil.rmtree(root, ignore_errors=True)
        else:  # the hosts' Ray logs (ray/session_latest/logs) and the commands' output, for the failure
            print(f"\ncluster test failed: the hosts' folders are kept in {root}", file=sys.stderr)
        assert not left, f"the cluster's namespaces or interfaces were not removed: {left}"


def _plate_cloud(path: Path) -> Path:
    """The plate's surface in the robot's base frame with a 4 × 4 cm dirty patch, as a ``cloud`` file."""
    import numpy as np

    from tactex.pointcloud import save_npz
    from tactex.pointcloud.markings import marked_cloud
    from tactex.tasks.clean import CleanConfig

    scene = CleanConfig(object_name="plate").scene()
    pos, rot = scene.object_pose()
    local = marked_cloud(scene.sim_object.surface, "full", 0.003)
    x, y = local.points[:, 0], local.points[:, 1]
    dirt = (np.abs(x - 0.03) <= 0.02) & (np.abs(y) <= 0.02)
    return save_npz(local.with_target(dirt.astype(float)).transformed(rot, pos), path)


@pytest.fixture(scope="module")
def study_file(cluster) -> dict[str, Path]:
    """The study file and its cloud file in each place that submits it (a host reads only its own files)."""
    out = {}
    for place in ("head", "client"):
        folder = cluster.root / place
        folder.mkdir(exist_ok=True)
        (folder / "study.toml").write_text(STUDY_TOML)
        (folder / "kill-study.toml").write_text(KILL_STUDY_TOML)
        _plate_cloud(folder / "plate.npz")
        out[place] = folder / "study.toml"
    return out


def _local(tmp_path_factory, spec_file: Path) -> Path:
    """A study file run on the local executor (one process): the reference tables."""
    out = tmp_path_factory.mktemp("local-study")
    here = os.getcwd()
    os.chdir(spec_file.parent)  # where its relative cloud path is
    try:
        run_study(spec_from_dict(load_spec_file(spec_file)), out, LocalExecutor(1))
    finally:
        os.chdir(here)
    return out


@pytest.fixture(scope="module")
def local_study(tmp_path_factory, study_file) -> Path:
    return _local(tmp_path_factory, study_file["client"])


@pytest.fixture(scope="module")
def local_kill_study(tmp_path_factory, study_file) -> Path:
    return _local(tmp_path_factory, study_file["client"].with_name("kill-study.toml"))


def _env(cluster: Cluster, place: str) -> dict[str, str]:
    folder = cluster.root / place
    folder.mkdir(exist_ok=True)
    return {**cluster.ray_env(folder), "TACTEX_CACHE_DIR": str(folder / "cache"), "MUJOCO_GL": "disable"}


def _tactex(cluster: Cluster, place: str, *args: str) -> subprocess.Popen:
    """``tactex ARGS`` started on the head (``place`` = head: in its namespace) or in the root
    namespace (``client``), from that place's own folder."""
    argv = [str(Path(sys.executable).with_name("tactex")), *args]
    if place == "head":
        argv = cluster.head.cmd(*argv)
    folder = cluster.root / place
    log = folder / f"tactex-{time.monotonic_ns()}.log"
    with log.open("w") as f:
        proc = subprocess.Popen(argv, cwd=folder, env=_env(cluster, place), stdout=f, stderr=subprocess.STDOUT)
    proc.log = log  # what _finish reads
    return proc


def _finish(proc: subprocess.Popen) -> str:
    """Wait for a tactex command (hang guard); its output, asserting it succeeded."""
    try:
        proc.wait(timeout=HANG_GUARD_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
    text = proc.log.read_text()
    assert proc.returncode == 0, f"tactex failed ({proc.returncode}):\n{text[-4000:]}"
    return text


def _records(out: Path) -> list[dict]:
    return [json.loads(line) for line in (out / "runs.jsonl").read_text().splitlines()]


def _same_tables(a: Path, b: Path, names=("table.csv", "summary.csv")) -> None:
    for name in names:
        assert (a / name).read_bytes() == (b / name).read_bytes(), f"{name} differs between {a} and {b}"


#: A Ray job that holds one CPU of the head node until its release file appears (run in the client's place).
_HOLD_HEAD = """
import pathlib, sys, time
import ray
from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy
from tactex.experiments.executor import CLIENT_ATTEMPTS
# as tactex's own client connection (executor._connect): the head's session for a client can fail to start once
for attempt in range(1, CLIENT_ATTEMPTS + 1):
    try:
        ray.init(address=sys.argv[1])
        break
    except ConnectionError as exc:
        ray.shutdown()
        if "Initialization failure from server" not in str(exc) or attempt == CLIENT_ATTEMPTS:
            raise
        time.sleep(1.0)
head = next(n["NodeID"] for n in ray.nodes() if n["Alive"] and n["NodeManagerAddress"] == sys.argv[2])

@ray.remote(num_cpus=1)
def hold(holding, release):
    pathlib.Path(holding).touch()
    while not pathlib.Path(release).exists():
        time.sleep(0.05)

ray.get(hold.options(scheduling_strategy=NodeAffinitySchedulingStrategy(head, soft=False)).remote(*sys.argv[3:5]))
"""


@contextlib.contextmanager
def _head_cpu_held(cluster: Cluster):
    """Within the block another job holds the head node's one CPU, so every task of ours runs on the worker."""
    folder = cluster.root / "client"
    holding, release = folder / "head-held", folder / "head-release"
    for f in (holding, release):
        f.unlink(missing_ok=True)
    log = folder / "hold-head.log"
    with log.open("w") as f:
        proc = subprocess.Popen([sys.executable, "-c", _HOLD_HEAD, CLIENT_ADDRESS, HEAD_IP, str(holding), str(release)],
                                cwd=folder, env=_env(cluster, "client"), stdout=f, stderr=subprocess.STDOUT)
    try:
        deadline = time.monotonic() + HANG_GUARD_S
        while not holding.exists() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert holding.exists(), f"the job holding the head's CPU never started:\n{log.read_text()[-3000:]}"
        yield
    finally:
        release.touch()
        try:
            proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def _store_counts(ip: str) -> tuple[int, int]:
    """Objects and bytes ever created in a node's object store (copies fetched from another node included)."""
    from ray._private.internal_api import node_stats

    stats = node_stats(ip, NODE_PORTS["--node-manager-port"], include_memory_info=False).store_stats
    return int(stats.cumulative_created_objects), int(stats.cumulative_created_bytes)


def _busy_ray_workers(pids: list[int]) -> list[int]:
    """Those of ``pids`` that are Ray workers executing a run now (Ray titles them ``ray::_call_ray``)."""
    busy = []
    for pid in pids:
        try:
            if Path(f"/proc/{pid}/cmdline").read_bytes().startswith(b"ray::_call_ray"):
                busy.append(pid)
        except OSError:
            continue
    return busy


# -- the tests -------------------------------------------------------------------------------------------
def test_hosts_are_removed_when_a_test_fails():
    """What the fixture's finalizer does, on a failure: processes, namespaces and interfaces go."""
    root = Path(tempfile.mkdtemp(prefix="txc-", dir="/tmp"))
    try:
        hosts = Cluster.make(root)
    except NetnsUnavailable as exc:
        shutil.rmtree(root, ignore_errors=True)
        pytest.skip(f"no network namespaces for a cluster test: {exc}")
    sleeper = subprocess.Popen(hosts.worker.cmd("sleep", "600"))
    try:
        with pytest.raises(RuntimeError, match="a failing test"):
            try:
                deadline = time.monotonic() + 30
                while sleeper.pid not in hosts.worker.pids() and time.monotonic() < deadline:
                    time.sleep(0.05)
                assert sleeper.pid in hosts.worker.pids()
                raise RuntimeError("a failing test")
            finally:
                hosts.remove()
        assert sleeper.wait(timeout=30) == -signal.SIGKILL
        assert hosts.leftovers() == []
    finally:
        hosts.remove()
        shutil.rmtree(root, ignore_errors=True)


def test_the_workers_run_the_drivers_tactex_from_their_own_node_folder(cluster):
    """tactex reaches the nodes in Ray's runtime environment: each worker imports the copy unpacked in
    its own node's folder, never this checkout."""
    script = cluster.root / "head" / "where.py"
    script.parent.mkdir(exist_ok=True)
    script.write_text(
        "import json, sys, time\n"
        "from tactex.experiments.executor import RayExecutor\n"
        "def where(task, shared):\n"
        "    import tactex\n"
        "    time.sleep(1.0)  # both nodes get runs: the head's one CPU is busy\n"
        "    return tactex.__file__\n"
        "with RayExecutor(address=sys.argv[1]) as ex:\n"
        "    print(json.dumps([(o.worker, o.value, o.error) for o in ex.run(where, list(range(4)))]))\n")
    proc = subprocess.run(cluster.head.cmd(sys.executable, str(script), HEAD_ADDRESS), cwd=script.parent,
                          env=_env(cluster, "head"), capture_output=True, text=True, timeout=HANG_GUARD_S)
    assert proc.returncode == 0, proc.stderr[-4000:]
    runs = json.loads(proc.stdout.strip().splitlines()[-1])
    folders = {HEAD_IP: cluster.head.folder, WORKER_IP: cluster.worker.folder}
    assert {worker.split(":")[0] for worker, _, _ in runs} == {HEAD_IP, WORKER_IP}
    for worker, path, error in runs:
        assert not error
        assert Path(path).is_relative_to(folders[worker.split(":")[0]]), (worker, path)


def test_a_study_on_the_cluster_gives_the_local_tables_from_a_driver_on_the_head_and_a_client(
        cluster, study_file, local_study):
    on_head, by_client = cluster.root / "head" / "study", cluster.root / "client" / "study"
    head = _tactex(cluster, "head", "study", "--spec", str(study_file["head"]), "--out", str(on_head),
                   "--ray-address", HEAD_ADDRESS)
    _finish(head)
    client = _tactex(cluster, "client", "study", "--spec", str(study_file["client"]), "--out", str(by_client),
                     "--ray-address", CLIENT_ADDRESS)
    _finish(client)
    for out in (on_head, by_client):
        _same_tables(local_study, out)
        records = _records(out)
        assert len(records) == 4 and all(r["status"] == "ok" for r in records)
        nodes = sorted(r["worker"].split(":")[0] for r in records)
        print(f"{out.parent.name}: runs on {nodes}")
        assert WORKER_IP in nodes, f"no run executed on the worker node: {nodes}"
    # the worker node's runs read the cloud from the copy they received, in the node's own temporary folder
    copies = list((cluster.worker.folder / "tmp" / "tactex-study-inputs").glob("*.npz"))
    assert [c.read_bytes() for c in copies] == [study_file["client"].with_name("plate.npz").read_bytes()]


def test_a_sweep_through_the_client_gives_the_local_table_and_sends_the_inputs_once_per_node(cluster, tmp_path):
    cloud = tec_cloud_path("cup_X")
    local = tmp_path / "local"
    run_sweep([cloud], local, SweepConfig(**SWEEP), executor=LocalExecutor(1))
    # the client's own copy of the data (the submitting machine's files): the nodes get it through the object store
    mine = cluster.root / "client" / "data"
    mine.mkdir(parents=True, exist_ok=True)
    for f in cloud.parent.glob("cup_X*"):
        shutil.copy(f, mine / f.name)
    # once per node is told apart from once per run only by a node with two runs or more; how Ray shares six
    # short settings between two one-CPU nodes depends on which node starts its worker process first (5/1 or 1/5
    # seen on a quiet machine), so another job holds the head's CPU meanwhile: every setting runs on the worker
    with _head_cpu_held(cluster):
        before = {ip: _store_counts(ip) for ip in (HEAD_IP, WORKER_IP)}
        out = cluster.root / "client" / "sweep"
        _finish(_tactex(cluster, "client", "sweep", str(mine / cloud.name), "--out", str(out), *SWEEP_ARGS,
                        "--ray-address", CLIENT_ADDRESS))
        after = {ip: _store_counts(ip) for ip in (HEAD_IP, WORKER_IP)}
    assert (local / "table.csv").read_bytes() == (out / "table.csv").read_bytes()
    ran_on = json.loads((out / "sweep.json").read_text())["ran_on"]
    per_node = {ip: sum(r["worker"].startswith(f"{ip}:") for r in ran_on) for ip in (HEAD_IP, WORKER_IP)}
    created = {ip: (after[ip][0] - before[ip][0], after[ip][1] - before[ip][1]) for ip in after}
    print(f"sweep: settings per node {per_node}; objects, bytes created per node {created}")
    assert per_node == {HEAD_IP: 0, WORKER_IP: 6} and len(ran_on) == 6
    # the shared input (cloud, basis, starts) as Ray stores it: pickle protocol 5, the arrays' buffers aligned
    clouds, _ = prepare_clouds([cloud], SweepConfig(**SWEEP), lambda msg: None)
    size = len(pickle.dumps(clouds, protocol=5))
    copies = created[WORKER_IP][1] / size
    print(f"sweep: shared input {size} bytes; the worker node stored {copies:.3f} times that for its "
          f"{per_node[WORKER_IP]} settings")
    # once per node: one copy for all its runs (per run would be {per_node[WORKER_IP]} copies)
    assert 0.9 < copies < 1.1, (created, size)


def test_a_client_disconnected_mid_study_resumes_from_runs_jsonl(cluster, study_file, local_study):
    out = cluster.root / "client" / "resumed"
    first = _tactex(cluster, "client", "study", "--spec", str(study_file["client"]), "--out", str(out),
                    "--ray-address", CLIENT_ADDRESS)
    deadline = time.monotonic() + HANG_GUARD_S
    while time.monotonic() < deadline and first.poll() is None and not (
            (out / "runs.jsonl").is_file() and (out / "runs.jsonl").read_text().count("\n") >= 1):
        time.sleep(0.05)
    assert first.poll() is None, "the study finished before the client could be cut off"
    first.send_signal(signal.SIGKILL)  # the client machine gone: no clean disconnect
    first.wait(timeout=60)
    done_before = len(_records(out))
    assert 1 <= done_before < 4, f"client cut off with {done_before} of 4 runs in runs.jsonl"
    text = _finish(_tactex(cluster, "client", "study", "--spec", str(study_file["client"]), "--out", str(out),
                           "--ray-address", CLIENT_ADDRESS))
    print(f"client cut off after {done_before} of 4 runs; the second session: {text.splitlines()[:2]}")
    assert f"{done_before} of 4 runs already in runs.jsonl" in text
    records = _records(out)
    assert len(records) == 4 and len({r["run_id"] for r in records}) == 4
    assert all(r["status"] == "ok" for r in records)
    _same_tables(local_study, out)


def test_the_worker_node_killed_mid_study_loses_no_run(cluster, study_file, local_kill_study):
    out = cluster.root / "head" / "killed"
    spec = study_file["head"].with_name("kill-study.toml")
    proc = _tactex(cluster, "head", "study", "--spec", str(spec), "--out", str(out),
                   "--ray-address", HEAD_ADDRESS)
    killed: list[int] = []
    deadline = time.monotonic() + HANG_GUARD_S
    while time.monotonic() < deadline and proc.poll() is None and not killed:
        if _busy_ray_workers(cluster.worker.pids()):  # a run in progress there: the node is lost mid-run
            killed = cluster.kill_host("worker")
        time.sleep(0.05)
    assert killed, ("the worker node was never seen running a run of the study; the runs ran on "
                    f"{[r['worker'] for r in _records(out)] if (out / 'runs.jsonl').is_file() else 'no node'}")
    done_at_kill = len(_records(out)) if (out / "runs.jsonl").is_file() else 0
    _finish(proc)
    records = _records(out)
    retried = [r for r in records if r["attempt"] > 0]
    print(f"worker node killed ({len(killed)} processes) with {done_at_kill} of {KILL_STUDY_RUNS} runs done; "
          f"retried: {[(r['index'], r['worker'], r['attempt']) for r in retried]}")
    assert len(records) == KILL_STUDY_RUNS and all(r["status"] == "ok" for r in records)
    assert retried and all(r["worker"].startswith(f"{HEAD_IP}:") for r in retried)
    _same_tables(local_kill_study, out)
