"""Real loopback infrastructure for cluster tests: moto's S3 server and a 2-node Ray cluster.

Both are separate processes started here and stopped here; teardown checks with psutil that
none of the processes they spawned (found by their private temp dirs) is left behind.
"""

from __future__ import annotations

import os
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import psutil

BIN = Path(sys.executable).parent
PROJECT_ROOT = Path(__file__).resolve().parent.parent
BUCKET = "vid2sim-test"


def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@dataclass
class S3Server:
    """A running moto S3 server and the environment that points clients at it."""

    endpoint: str
    bucket: str
    proc: subprocess.Popen

    @property
    def env(self) -> dict[str, str]:
        """AWS variables understood by pyarrow, delta-rs (object_store) and boto3."""
        return {"AWS_ENDPOINT_URL": self.endpoint, "AWS_ACCESS_KEY_ID": "testing",
                "AWS_SECRET_ACCESS_KEY": "testing", "AWS_REGION": "us-east-1",
                "AWS_DEFAULT_REGION": "us-east-1", "AWS_ALLOW_HTTP": "true",
                "AWS_EC2_METADATA_DISABLED": "true"}

    def uri(self, key: str) -> str:
        return f"s3://{self.bucket}/{key.strip('/')}"


def _wait_http(url: str, proc: subprocess.Popen, timeout: float = 60.0) -> None:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        if proc.poll() is not None:
            raise RuntimeError(f"{proc.args[0]} exited with {proc.returncode}")
        try:
            urllib.request.urlopen(url, timeout=2).read()
            return
        except OSError:
            time.sleep(0.2)
    raise TimeoutError(f"{url} did not answer within {timeout} s")


def _stop(proc: subprocess.Popen, timeout: float = 30.0) -> None:
    """SIGTERM, then SIGKILL after `timeout`: this process only."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)


@contextmanager
def s3_server() -> Iterator[S3Server]:
    """moto's standalone S3 server on 127.0.0.1 (free port) with one bucket."""
    import boto3

    port = free_port()
    proc = subprocess.Popen([str(BIN / "moto_server"), "-H", "127.0.0.1", "-p", str(port)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    server = S3Server(f"http://127.0.0.1:{port}", BUCKET, proc)
    try:
        _wait_http(server.endpoint + "/moto-api/", proc)
        env = server.env
        boto3.client("s3", endpoint_url=server.endpoint, region_name=env["AWS_REGION"],
                     aws_access_key_id=env["AWS_ACCESS_KEY_ID"],
                     aws_secret_access_key=env["AWS_SECRET_ACCESS_KEY"]).create_bucket(Bucket=BUCKET)
        yield server
    finally:
        _stop(proc)


@dataclass
class RayNode:
    proc: subprocess.Popen
    temp_dir: Path
    scratch: Path


@dataclass
class RayCluster:
    """A head and workers started with `ray start --block`, one process tree each."""

    address: str
    env: dict[str, str]
    root: Path
    nodes: list[RayNode] = field(default_factory=list)

    def node_pids(self) -> set[int]:
        """Every live process whose command line names one of this cluster's temp dirs."""
        mine = str(self.root)
        pids = set()
        for p in psutil.process_iter(["pid", "cmdline"]):
            if any(mine in arg for arg in (p.info["cmdline"] or [])):
                pids.add(p.info["pid"])
        tree = {n.proc.pid for n in self.nodes}
        for n in self.nodes:
            try:
                tree |= {c.pid for c in psutil.Process(n.proc.pid).children(recursive=True)}
            except psutil.NoSuchProcess:
                pass
        return (pids | tree) - {os.getpid()}


def ray_env(token: str, scratch: Path, extra: dict[str, str]) -> dict[str, str]:
    """Environment of one Ray node: token auth, node-local scratch, project on the path."""
    env = dict(os.environ)
    env.update(extra)
    env.update({"RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": token, "VID2SIM_SCRATCH": str(scratch),
                "VID2SIM_CHECKOUTS": str(scratch / "checkouts"),  # the envs' scene checkouts stay on the node
                "PYTHONPATH": os.pathsep.join([str(PROJECT_ROOT), str(PROJECT_ROOT / "tests")]),
                "RAY_USAGE_STATS_ENABLED": "0",
                "OMP_NUM_THREADS": "1"})
    env.pop("RAY_AUTH_TOKEN_PATH", None)
    return env


def _start_node(cluster: RayCluster, name: str, head_port: int, head: bool, extra: dict,
                attempt: int = 0) -> RayNode:
    folder = name if attempt == 0 else f"{name}-retry{attempt}"
    temp_dir, scratch = cluster.root / folder, cluster.root / f"{name}-scratch"
    temp_dir.mkdir()
    scratch.mkdir(exist_ok=True)
    args = [str(BIN / "ray"), "start", "--block", "--num-cpus", "1", "--node-ip-address", "127.0.0.1",
            "--temp-dir", str(temp_dir), "--object-store-memory", str(100 * 2**20),
            "--disable-usage-stats", "--dashboard-agent-listen-port", str(free_port()),
            "--metrics-export-port", str(free_port()), "--resources", f'{{"{name}": 1}}']
    if head:
        args += ["--head", "--port", str(head_port), "--include-dashboard", "false",
                 "--dashboard-port", str(free_port()), "--ray-client-server-port", str(free_port())]
    else:
        args += ["--address", f"127.0.0.1:{head_port}"]
    log = open(cluster.root / f"{folder}.log", "wb")
    proc = subprocess.Popen(args, env=ray_env(cluster.env["RAY_AUTH_TOKEN"], scratch, extra),
                            stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    node = RayNode(proc, temp_dir, scratch)
    cluster.nodes.append(node)
    return node


def _node_log(cluster: RayCluster, node: RayNode) -> str:
    return (cluster.root / f"{node.temp_dir.name}.log").read_text(errors="replace")


def _start_with_retry(cluster: RayCluster, name: str, head_port: int, head: bool, extra: dict,
                      attempts: int = 3, timeout: float = 300.0) -> None:
    """Start a node; retry when Ray's fixed 30 s raylet registration wait runs out (it does on a
    heavily loaded machine), after reaping whatever the failed start left behind."""
    for attempt in range(attempts):
        node = _start_node(cluster, name, head_port, head, extra, attempt)
        deadline = time.monotonic() + timeout
        while node.proc.poll() is None and "Ray runtime started" not in _node_log(cluster, node) \
                and time.monotonic() < deadline:
            time.sleep(1.0)
        if node.proc.poll() is None:
            return  # started (or still starting: _wait_nodes decides)
        if "timed out during startup" not in _node_log(cluster, node) or attempt == attempts - 1:
            return  # _wait_nodes reports the failure with the log
        cluster.nodes.remove(node)
        for p in psutil.process_iter(["cmdline"]):  # the failed start's gcs/raylet (our temp dir)
            if any(str(node.temp_dir) in a for a in (p.info["cmdline"] or [])):
                p.kill()


def _wait_nodes(cluster: RayCluster, count: int, timeout: float = 400.0) -> None:
    """Wait until every node's `ray start` reported success and `count` nodes are alive (checked
    from a separate authenticated driver; probes that time out on a loaded machine are retried)."""
    code = ("import ray,sys; ray.init(address=sys.argv[1], log_to_driver=False);"
            "print(sum(n['Alive'] for n in ray.nodes()))")
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        logs = []
        for n in cluster.nodes:
            log = _node_log(cluster, n)
            if n.proc.poll() is not None:
                raise RuntimeError(f"ray node {n.temp_dir.name} exited: {log[-2000:]}")
            logs.append(log)
        if not all("Ray runtime started" in log for log in logs):
            time.sleep(1.0)
            continue
        try:
            out = subprocess.run([sys.executable, "-c", code, cluster.address], env=cluster.env,
                                 capture_output=True, text=True, timeout=180)
        except subprocess.TimeoutExpired:
            continue
        if out.returncode == 0 and out.stdout.strip().splitlines()[-1:] == [str(count)]:
            return
        time.sleep(1.0)
    raise TimeoutError(f"{count} Ray nodes not alive after {timeout} s")


def stop_cluster(cluster: RayCluster) -> list[str]:
    """Stop the nodes (workers first), then kill anything of ours still alive; return leftovers."""
    for n in reversed(cluster.nodes):
        _stop(n.proc, timeout=40)
    deadline = time.monotonic() + 60  # a loaded machine can take a while to reap workers
    while (left := cluster.node_pids()) and time.monotonic() < deadline:
        time.sleep(0.5)
    leftovers = []
    for pid in sorted(left):  # ours: they name our private temp dir
        try:
            proc = psutil.Process(pid)
            leftovers.append(f"{pid} {proc.status()} {' '.join(proc.cmdline())[:200]}")
            proc.kill()
        except psutil.NoSuchProcess:
            pass
    return leftovers


@contextmanager
def ray_cluster(workers: int = 1, extra_env: dict[str, str] | None = None) -> Iterator[RayCluster]:
    """A head + `workers` worker nodes on 127.0.0.1, each with its own temp and scratch dirs.

    Every node and the driver share one random token (RAY_AUTH_MODE=token). Node names are
    custom resources (`node0` = head, `node1`...) so tasks can be pinned in tests.
    """
    root = Path(tempfile.mkdtemp(prefix="v2sray-", dir="/tmp"))  # short: Ray's socket paths
    port = free_port()
    token = secrets.token_hex(16)
    extra = dict(extra_env or {})
    cluster = RayCluster(f"127.0.0.1:{port}", ray_env(token, root / "driver-scratch", extra), root)
    try:
        _start_with_retry(cluster, "node0", port, True, extra)
        for i in range(workers):
            _start_with_retry(cluster, f"node{i + 1}", port, False, extra)
        _wait_nodes(cluster, workers + 1)
        yield cluster
    finally:
        leftovers = stop_cluster(cluster)
        shutil.rmtree(root, ignore_errors=True)
        assert not leftovers, f"Ray processes left after stopping the nodes: {leftovers}"
