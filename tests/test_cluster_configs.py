"""Schema-level checks of `cluster/`: the launcher YAML, KubeRay manifests, Dockerfile and job
commands parse, name the right images, entry points and resources, enable token auth on every
node, and mount no shared volume; every job's `vid2sim` command parses with the CLI's parser."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest
import typer
import yaml

from vid2sim.cli.app import app

CLUSTER = Path(__file__).resolve().parent.parent / "cluster"
IMAGE = "ghcr.io/vid2sim/vid2sim:0.1.0"
GPU_IMAGE = IMAGE + "-cuda"


def _load(name: str) -> dict:
    return yaml.safe_load((CLUSTER / name).read_text())


def _cli_accepts(argv: list[str]) -> bool:
    """True when the vid2sim CLI parses `argv`; a usage error (no such command, unknown option,
    missing argument) raises."""
    group = typer.main.get_command(app)
    ctx = group.make_context("vid2sim", list(argv), resilient_parsing=False)
    assert argv[0] in group.list_commands(ctx), f"`vid2sim {argv[0]}` is not a command of the CLI"
    name, cmd, rest = group.resolve_command(ctx, argv)
    cmd.make_context(name, rest)  # raises a usage error on unknown options / missing arguments
    return True


def _containers(manifest: dict) -> list[dict]:
    spec = manifest["spec"]
    groups = [spec["headGroupSpec"]] + spec.get("workerGroupSpecs", [])
    return [c for g in groups for c in g["template"]["spec"]["containers"]]


def test_launcher_yaml_has_head_cpu_and_gpu_workers_with_token_auth():
    conf = _load("ray-cluster.aws.yaml")
    types = conf["available_node_types"]
    assert conf["head_node_type"] == "head" and {"head", "cpu_worker", "gpu_worker"} <= set(types)
    assert conf["docker"]["image"] == IMAGE
    assert types["gpu_worker"]["resources"]["GPU"] == 1
    assert types["gpu_worker"]["docker"]["worker_image"] == GPU_IMAGE
    assert types["cpu_worker"]["resources"]["CPU"] >= 4 and types["cpu_worker"]["max_workers"] >= 1
    for cmd in conf["head_start_ray_commands"][1:] + conf["worker_start_ray_commands"][1:]:
        assert cmd.startswith("RAY_AUTH_MODE=token ray start")
    assert any("auth_token" in dest for dest in conf["file_mounts"])


def test_raycluster_images_resources_auth_and_no_shared_volume():
    rc = _load("kuberay/raycluster.yaml")
    assert (rc["apiVersion"], rc["kind"], rc["metadata"]["name"]) == ("ray.io/v1", "RayCluster", "vid2sim")
    groups = {g["groupName"]: g for g in rc["spec"]["workerGroupSpecs"]}
    assert set(groups) == {"cpu", "gpu"}
    gpu = groups["gpu"]["template"]["spec"]["containers"][0]
    assert gpu["image"] == GPU_IMAGE and gpu["resources"]["limits"]["nvidia.com/gpu"] == "1"
    assert groups["cpu"]["template"]["spec"]["containers"][0]["image"] == IMAGE
    for c in _containers(rc):
        env = {e["name"]: e for e in c["env"]}
        assert env["RAY_AUTH_MODE"]["value"] == "token"
        assert env["RAY_AUTH_TOKEN"]["valueFrom"]["secretKeyRef"]["name"] == "vid2sim-ray-token"
        assert env["VID2SIM_SCRATCH"]["value"] == "/scratch"
    for g in [rc["spec"]["headGroupSpec"], *groups.values()]:
        volumes = g["template"]["spec"]["volumes"]
        assert all(set(v) == {"name", "emptyDir"} for v in volumes), "a shared volume is mounted"


@pytest.mark.parametrize("name,command", [("kuberay/rayjob-ingest.yaml", "ingest"),
                                          ("kuberay/rayjob-train.yaml", "study")])
def test_rayjobs_target_the_cluster_and_name_cli_entry_points(name, command):
    job = _load(name)
    assert job["kind"] == "RayJob"
    assert job["spec"]["clusterSelector"] == {"ray.io/cluster": "vid2sim"}
    argv = shlex.split(job["spec"]["entrypoint"])
    assert argv[:2] == ["vid2sim", command]
    assert any(a.startswith("s3://") and a.endswith("/registry") for a in argv)
    sub = job["spec"]["submitterPodTemplate"]["spec"]["containers"][0]
    assert sub["image"] == IMAGE and {"RAY_AUTH_MODE", "RAY_AUTH_TOKEN"} <= {e["name"] for e in sub["env"]}
    assert _cli_accepts(argv[1:])
    if command == "ingest":
        assert (CLUSTER.parent / argv[2]).is_file()  # the manifest ships with the image


def test_ingest_parser_rejects_unknown_options():
    with pytest.raises(Exception, match="No such option"):
        _cli_accepts(["ingest", "x.mp4", "--no-such-option"])


def test_dockerfile_installs_like_the_readme_in_one_pip_command():
    text = (CLUSTER / "Dockerfile").read_text()
    pips = [line for line in text.splitlines() if re.search(r"\bpip install\b", line)]
    assert len(pips) == 1 and '"torch==2.13.0"' in pips[0] and '"."' not in pips[0]
    assert re.search(r'"\.\$\{EXTRAS:\+\[\$EXTRAS\]\}"', pips[0])
    assert text.splitlines()[[i for i, line in enumerate(text.splitlines())
                              if line.startswith("FROM")][0]].startswith("FROM python:3.11")
    assert "RAY_AUTH_MODE=token" in text and "VID2SIM_SCRATCH=" in text


def test_job_submit_commands_cover_ingest_train_study_and_parse():
    text = (CLUSTER / "jobs.sh").read_text()
    blocks = dict(re.findall(r"^  (\w+)\)[^\n]*\n(.*?);;", text, flags=re.S | re.M))
    assert set(blocks) == {"ingest", "train", "study"}
    for name, block in blocks.items():
        assert "ray job submit" in block and f"vid2sim {name}" in block
        # the entry point after `--`, with the shell's variables at their defaults
        command = re.sub(r"\$\{\w+:-([^}]*)\}", r"\1", block.split(" -- ", 1)[1].replace("\\\n", " "))
        argv = shlex.split(command.replace("$DATA", "s3://vid2sim-data").replace("$RAY_ADDRESS", "auto"))
        assert argv[:2] == ["vid2sim", name] and _cli_accepts(argv[1:])
