"""A two-host Ray cluster on this machine: a head and a worker node, each in a Linux network namespace.

The hosts are joined by a bridge in the root namespace (``10.77.0.1``): the head is ``10.77.0.2``,
the worker ``10.77.0.3``; nothing outside this machine is addressed. Each host has its own network
stack (its ports, its loopback), so both run Ray on the same fixed ports as two machines would.

What the hosts share, and why that matches a real cluster:

- the Python interpreter and its site-packages (the venv): on a cluster, every node runs the same
  image with the same Python, Ray and third-party packages installed;
- nothing else: each host has its own folder (Ray's ``--temp-dir``, its home and temporary
  folder), tactex reaches the workers through Ray's runtime environment (``py_modules``: the
  driver's copy, zipped into the cluster's store and unpacked in each node's folder), and the data
  (a study's input files, a sweep's clouds and bases) go as study inputs through the object store.
  The tests check that the workers import tactex from their node's folder and read the study's
  input file from their own copy of it.

``ray stop`` is not used to end the hosts: it ends every Ray process of the machine, in any namespace
(other Ray instances on this machine included). A host is ended by killing the processes in its
namespace (``ip netns pids``).
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

SUBNET = "10.77.0"
BRIDGE_IP = f"{SUBNET}.1"
HEAD_IP = f"{SUBNET}.2"
WORKER_IP = f"{SUBNET}.3"
GCS_PORT = 6379
CLIENT_PORT = 10001
#: Fixed ports of every host (the same on each: each namespace has its own), so a firewall can list them.
NODE_PORTS = {"--node-manager-port": 6380, "--object-manager-port": 6381, "--dashboard-agent-listen-port": 6382,
              "--dashboard-agent-grpc-port": 6383, "--runtime-env-agent-port": 6384, "--metrics-export-port": 6385,
              "--min-worker-port": 11000, "--max-worker-port": 11199}
#: Object store per node [bytes]: small, the machine is shared.
OBJECT_STORE_BYTES = 200 * 1024 * 1024
#: How fast the head declares a silent node dead: 1 s health checks, dead after 3 missed [ms, -].
FAST_NODE_DEATH = {"RAY_health_check_period_ms": "1000", "RAY_health_check_timeout_ms": "1000",
                   "RAY_health_check_failure_threshold": "3"}
#: A raylet waits for its dashboard agent's port before it registers; on a loaded machine the agent's
#: imports alone can take longer than Ray's default wait [ms].
AGENT_WAIT_MS = "120000"
#: ``ray start`` gives a raylet a fixed 30 s to register: a start that times out is tried again.
START_ATTEMPTS = 3


class NetnsUnavailable(RuntimeError):
    """Network namespaces cannot be made here (not root, no ``ip``, no permission)."""


def _ip(*args: str, check: bool = True) -> subprocess.CompletedProcess:
    return subprocess.run(["ip", *args], capture_output=True, text=True, check=check, timeout=30)


@dataclass
class Host:
    """One namespace with one address on the bridge."""

    name: str  # namespace name
    ip: str
    veth: str  # root-side end of its veth pair
    folder: Path  # this host's own folder (Ray's --temp-dir)

    def cmd(self, *argv: str) -> list[str]:
        """``argv`` run inside this host's namespace."""
        return ["ip", "netns", "exec", self.name, *argv]

    def pids(self) -> list[int]:
        """The processes in this namespace (what ``ip netns pids`` lists, read from /proc without a
        process of its own: the tests poll it every few tens of milliseconds)."""
        try:
            ns = os.stat(f"/var/run/netns/{self.name}")
        except OSError:
            return []
        out = []
        for entry in os.scandir("/proc"):
            if not entry.name.isdigit():
                continue
            try:
                st = os.stat(f"/proc/{entry.name}/ns/net")
            except OSError:  # gone, or a kernel thread
                continue
            if (st.st_ino, st.st_dev) == (ns.st_ino, ns.st_dev):
                out.append(int(entry.name))
        return out


@dataclass
class Cluster:
    """The hosts, the bridge and the processes started in them; :meth:`remove` undoes all of it."""

    tag: str
    root: Path
    bridge: str
    hosts: dict[str, Host] = field(default_factory=dict)
    logs: list[Path] = field(default_factory=list)

    @property
    def head(self) -> Host:
        return self.hosts["head"]

    @property
    def worker(self) -> Host:
        return self.hosts["worker"]

    # -- network -------------------------------------------------------------------------------------
    @classmethod
    def make(cls, root: Path) -> Cluster:
        """The bridge and the two namespaces; raises :class:`NetnsUnavailable` (nothing left behind)."""
        if os.geteuid() != 0:
            raise NetnsUnavailable("needs root to create network namespaces (ip netns add)")
        if shutil.which("ip") is None:
            raise NetnsUnavailable("needs the ip command (apt-get install iproute2)")
        tag = f"txc{os.getpid() % 100000}"
        cluster = cls(tag=tag, root=root, bridge=f"{tag}br")
        try:
            cluster._make_network()
        except (subprocess.CalledProcessError, OSError) as exc:
            cluster.remove()
            detail = exc.stderr.strip() if isinstance(exc, subprocess.CalledProcessError) else str(exc)
            raise NetnsUnavailable(f"cannot make network namespaces here: {detail}") from exc
        return cluster

    def _make_network(self) -> None:
        _ip("link", "add", self.bridge, "type", "bridge")
        _ip("addr", "add", f"{BRIDGE_IP}/24", "dev", self.bridge)
        _ip("link", "set", self.bridge, "up")
        for role, ip in (("head", HEAD_IP), ("worker", WORKER_IP)):
            host = Host(name=f"{self.tag}{role[0]}", ip=ip, veth=f"{self.tag}{role[0]}0", folder=self.root / role)
            self.hosts[role] = host
            host.folder.mkdir(parents=True, exist_ok=True)
            _ip("netns", "add", host.name)
            _ip("link", "add", host.veth, "type", "veth", "peer", "name", "eth0", "netns", host.name)
            _ip("link", "set", host.veth, "master", self.bridge)
            _ip("link", "set", host.veth, "up")
            _ip("-n", host.name, "addr", "add", f"{ip}/24", "dev", "eth0")
            _ip("-n", host.name, "link", "set", "eth0", "up")
            _ip("-n", host.name, "link", "set", "lo", "up")

    # -- Ray -----------------------------------------------------------------------------------------
    def ray_env(self, folder: Path) -> dict[str, str]:
        """The environment of a host's processes: its own home and temporary folder in ``folder`` (Ray
        keeps files in ~/.ray; a study's runs write their copies of its input files in the latter),
        token authentication off as set here (not from a token some other Ray left in this machine's
        ~/.ray), one BLAS thread, fast node-death detection, and Ray's workers at the nice level of
        everything else: Ray lowers them to nice 15 by default, which suits a node of its own, but here the
        nodes share the machine with the rest of the suite, and niced workers are starved by it."""
        env = {k: v for k, v in os.environ.items() if not k.startswith("RAY_")}
        env.update(FAST_NODE_DEATH)
        env["HOME"] = str(folder)
        env["TMPDIR"] = str(folder / "tmp")  # each machine its own /tmp
        (folder / "tmp").mkdir(parents=True, exist_ok=True)
        env["RAY_AUTH_MODE"] = "disabled"
        env["RAY_agent_register_timeout_ms"] = AGENT_WAIT_MS
        env["RAY_worker_niceness"] = "0"
        env.update({"RAY_USAGE_STATS_ENABLED": "0", "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1",
                    "MKL_NUM_THREADS": "1"})
        env.pop("PYTHONPATH", None)
        return env

    def _ray_start(self, host: Host, *extra: str) -> None:
        ray = str(Path(sys.executable).with_name("ray"))
        ports = [x for k, v in NODE_PORTS.items() for x in (k, str(v))]
        argv = host.cmd(ray, "start", "--node-ip-address", host.ip, "--num-cpus", "1",
                        "--object-store-memory", str(OBJECT_STORE_BYTES), "--temp-dir", str(host.folder / "ray"),
                        "--disable-usage-stats", *ports, *extra)
        for attempt in range(1, START_ATTEMPTS + 1):
            log = self.root / f"ray-start-{host.name}-{attempt}.log"
            self.logs.append(log)
            with log.open("w") as f:
                proc = subprocess.run(argv, stdout=f, stderr=subprocess.STDOUT, cwd=host.folder,
                                      env=self.ray_env(host.folder), timeout=300)
            if proc.returncode == 0:
                return
            self._kill_all(host)  # what the failed start left, before the next
        raise RuntimeError(f"ray start on {host.name} failed {START_ATTEMPTS} times:\n{log.read_text()[-3000:]}")

    def start_head(self) -> None:
        self._ray_start(self.head, "--head", "--port", str(GCS_PORT), "--ray-client-server-port", str(CLIENT_PORT),
                        "--include-dashboard", "false")

    def start_worker(self) -> None:
        self._ray_start(self.worker, "--address", f"{HEAD_IP}:{GCS_PORT}")

    def kill_host(self, role: str) -> list[int]:
        """SIGKILL every process in a host's namespace (the machine lost): the killed PIDs."""
        pids = self.hosts[role].pids()
        for pid in pids:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        return pids

    # -- clean-up ------------------------------------------------------------------------------------
    def _kill_all(self, host: Host) -> None:
        for _ in range(100):  # a dying Ray process can start a child: kill until none is left
            pids = host.pids()
            if not pids:
                return
            for pid in pids:
                try:
                    os.kill(pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
            time.sleep(0.1)

    def remove(self) -> None:
        """Every process in the namespaces killed, the namespaces, veths and the bridge deleted."""
        for host in self.hosts.values():
            self._kill_all(host)
        for host in self.hosts.values():
            _ip("link", "del", host.veth, check=False)
            _ip("netns", "del", host.name, check=False)
        _ip("link", "del", self.bridge, check=False)

    def leftovers(self) -> list[str]:
        """What :meth:`remove` should have removed and is still there."""
        names = _ip("netns", "list", check=False).stdout
        links = _ip("-o", "link", "show", check=False).stdout
        return [n for n in [*(h.name for h in self.hosts.values()), *(h.veth for h in self.hosts.values()),
                            self.bridge] if f"{n} " in names or f" {n}:" in links or f" {n}@" in links]
