"""The loopback test infrastructure itself: moto's S3 server and a real 2-node Ray cluster."""

from __future__ import annotations

import subprocess
import sys

import psutil
import pytest

from cluster_fixtures import ray_cluster, s3_server


def test_s3_server_serves_pyarrow_and_stops(monkeypatch):
    import pyarrow.fs as pafs

    with s3_server() as s3:
        for k, v in s3.env.items():
            monkeypatch.setenv(k, v)
        fs, path = pafs.FileSystem.from_uri(s3.uri("a/b.txt"))
        with fs.open_output_stream(path) as f:
            f.write(b"hello")
        with fs.open_input_stream(path) as f:
            assert f.read() == b"hello"
        pid = s3.proc.pid
    assert not psutil.pid_exists(pid) or psutil.Process(pid).status() == psutil.STATUS_ZOMBIE


NODE_PROBE = """
import os, sys, ray
ray.init(address=sys.argv[1], log_to_driver=False)
@ray.remote(num_cpus=1)
def where(i):
    import time; time.sleep(0.5)
    return ray.get_runtime_context().get_node_id(), os.environ["VID2SIM_SCRATCH"]
refs = [where.options(resources={f"node{i % 2}": 0.01}).remote(i) for i in range(4)]
print(sorted(set(ray.get(refs))))
"""


def test_two_node_cluster_with_token_auth_leaves_nothing():
    with ray_cluster(workers=1) as cluster:
        root = cluster.root
        out = subprocess.run([sys.executable, "-c", NODE_PROBE, cluster.address], env=cluster.env,
                             capture_output=True, text=True, timeout=120)
        assert out.returncode == 0, out.stderr[-2000:]
        pairs = eval(out.stdout.strip().splitlines()[-1])  # [(node_id, scratch), ...]
        assert len({node for node, _ in pairs}) == 2
        assert {scratch for _, scratch in pairs} == {str(n.scratch) for n in cluster.nodes}

        no_token = {k: v for k, v in cluster.env.items() if k != "RAY_AUTH_TOKEN"}
        no_token["RAY_AUTH_TOKEN"] = "0" * 32
        denied = subprocess.run([sys.executable, "-c", NODE_PROBE, cluster.address], env=no_token,
                                capture_output=True, text=True, timeout=120)
        assert denied.returncode != 0
        assert cluster.node_pids()
    left = [p.pid for p in psutil.process_iter(["cmdline"])
            if any(str(root) in a for a in (p.info["cmdline"] or []))]
    assert left == []


if __name__ == "__main__":
    sys.exit(pytest.main([__file__, "-q", "-p", "no:xdist"]))
