"""Real processes: concurrent committers lose nothing; a SIGKILLed committer corrupts nothing.

Both run with a tiny auto-compaction threshold, so compactions race commits and each other, and
kills land mid-compaction too.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from registry_fixtures import KILL_LOOP, checkout_worker, concurrent_worker, make_bundle

from vid2sim.registry import Registry

TESTS_DIR = Path(__file__).resolve().parent
N_PROCS, N_EACH = 4, 4
AUTO_COMPACT_FILES = 3  # compact after nearly every commit


def _compactions(reg: Registry) -> int:
    return sum(h.get("vid2sim.operation") == "compact" for h in reg.manifest.history())


def _assert_consistent(reg: Registry) -> None:
    rows = reg.history()
    keys = [(r.scene_id, r.version) for r in rows]
    assert len(keys) == len(set(keys)), "duplicate (scene_id, version)"
    by_scene: dict[str, list[int]] = {}
    for s, v in keys:
        by_scene.setdefault(s, []).append(v)
    for s, vs in by_scene.items():
        assert sorted(vs) == list(range(1, len(vs) + 1)), f"{s}: versions not contiguous: {sorted(vs)}"
    for r in rows:
        for a in r.artifacts:
            assert reg.blobs.exists(a.sha256), f"{r.ref}:{a.name} points at a missing blob"
    assert reg.verify() == []


@pytest.mark.timeout(300)
def test_concurrent_committers_lose_nothing(tmp_path):
    root = str(tmp_path / "reg")
    reg = Registry(root)
    reg.add(make_bundle(tmp_path / "shared", "shared"))
    common = str(make_bundle(tmp_path / "common", "common", seed=99))
    jobs = [[str(make_bundle(tmp_path / f"b{w}-{i}", f"w{w}-s{i}", seed=w * 10 + i)) for i in range(N_EACH)]
            for w in range(N_PROCS)]
    ctx = mp.get_context("spawn")  # deltalake panics in forked children
    with ctx.Pool(N_PROCS) as pool:
        results = pool.starmap(concurrent_worker, [(root, w, jobs[w], common, "shared", AUTO_COMPACT_FILES)
                                                   for w in range(N_PROCS)])
    assert sum(len(r) for r in results) == 2 * N_PROCS * N_EACH

    reg = Registry(root)
    _assert_consistent(reg)
    shared = reg.history("shared")
    assert len(shared) == 1 + N_PROCS * N_EACH  # one add + every tag, none lost
    assert set(shared[-1].tags) == {f"w{w}-{i}" for w in range(N_PROCS) for i in range(N_EACH)}
    assert len(reg.history("common")) == 1  # identical content added 4 times concurrently -> 1 version
    assert {r.scene_id for r in reg.list()} == {"shared", "common"} | {f"w{w}-s{i}" for w in range(N_PROCS)
                                                                       for i in range(N_EACH)}
    n_compact = _compactions(reg)
    assert n_compact >= 1 and reg.manifest.num_files() <= AUTO_COMPACT_FILES + N_PROCS
    # version 0 = table creation, then one commit per row, plus the compactions (rows unchanged)
    assert reg.version == len(reg.history()) + n_compact


@pytest.mark.timeout(300)
def test_concurrent_checkouts_of_one_scene_into_one_folder_all_succeed(tmp_path):
    """Training processes sharing a checkout root check the same scene out at once: each copies
    into its own temporary folder, the first rename wins and the others hand back its folder."""
    root = str(tmp_path / "reg")
    reg = Registry(root)
    reg.add(make_bundle(tmp_path / "b", "street", seed=3, n_splats=400_000))  # copies of ~0.2 s overlap
    dest = tmp_path / "checkouts" / "street@1"
    n = 2 * N_PROCS
    ctx = mp.get_context("spawn")
    with ctx.Manager() as manager, ctx.Pool(n) as pool:
        barrier = manager.Barrier(n)
        got = pool.starmap(checkout_worker, [(root, "street", str(dest), barrier)] * n)
    assert got == [str(dest)] * n
    assert reg.refresh_checkout(reg.show("street"), dest) == []  # every artifact as registered
    assert [p.name for p in dest.parent.iterdir()] == ["street@1"]  # no temporary folder left


@pytest.mark.timeout(300)
def test_sigkilled_committer_leaves_registry_consistent(tmp_path):
    root = str(tmp_path / "reg")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(TESTS_DIR), os.environ.get("PYTHONPATH", "")])}
    rng = random.Random(1234)
    added_total = 0
    for rnd in range(4):
        bundles = [str(make_bundle(tmp_path / f"r{rnd}-s{i}", f"r{rnd}-s{i}", seed=rnd * 100 + i, n_splats=2000))
                   for i in range(12)]
        # auto-compaction after every commit from the 2nd file on: kills also land mid-compaction
        proc = subprocess.Popen([sys.executable, "-c", KILL_LOOP, root, "1", *bundles], stdout=subprocess.PIPE,
                                text=True, env=env)
        assert proc.stdout.readline().strip() == "ready"
        first = proc.stdout.readline()  # one acknowledged add per round, then kill at a random point
        time.sleep(rng.uniform(0.0, 0.5))
        proc.send_signal(signal.SIGKILL)
        out, _ = proc.communicate()
        assert proc.returncode == -signal.SIGKILL, "the committer finished before being killed"
        reg = Registry(root)
        _assert_consistent(reg)  # readable, no duplicate, no row pointing at a missing blob
        listed = {r.scene_id for r in reg.list()}
        confirmed = {Path(line.split()[1]).name for line in (first + out).splitlines() if line.startswith("added")}
        assert first.startswith("added") and confirmed <= listed  # every acknowledged add survived
        added_total = len(listed)
    # orphan blobs (stored before a commit that never happened) are all gc removes
    reg = Registry(root)
    refs = reg.referenced()
    removed = reg.gc(grace_s=0)
    assert all(x.startswith("tmp/") or x not in refs for x in removed)
    _assert_consistent(reg)
    assert len(reg.list()) == added_total >= 4
    assert _compactions(reg) >= 1
    assert not any(b.is_temp or b.sha256 not in refs for b in reg.blobs.list())
