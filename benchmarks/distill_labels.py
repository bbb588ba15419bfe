"""How closely a distilled student follows its teacher on the states it drove into itself.

    python benchmarks/distill_labels.py RUN_DIR [RUN_DIR ...] [--rounds 4]
    python benchmarks/distill_labels.py RUN_DIR --contacts 5 --registry ROOT/registry
    python benchmarks/distill_labels.py RUN_DIR --history-probe

Reads a distillation run folder (`vid2sim train --method distill`): its final student
(`student.pt`, the weight average when the run kept one) and the labelled states of its last
`--rounds` DAgger rounds (`data/round_*.npz`, the student driving). Prints, per run, the student's
steering against the teacher's label binned by the label (mean, spread, share of the opposite
sign), the correlation of the two, and the mean squared error: a student whose steering is a
shrunken copy of the labels (mean +0.2 where the teacher says full lock) cannot turn away from
what it is about to hit. Nothing is trained; CPU seconds are the forward passes only.

`--contacts K` also drives K evaluation episodes per held-out street (`vid2sim eval policy`'s
protocol: seeds 1000 + k, 0-5 static obstacles, 600 steps) with the teacher labelling every state
beside the student (`TeacherLabels`, the run's comfortable route), twice: the student alone, and
the student with the teacher taking the wheel at the first contact. It prints, per failed
episode, the student's and the teacher's steering over the 15 steps before the first contact,
and both runs' failures: what a rescue after the contact would win.

`--history-probe` measures how much of the teacher's steering label the goal-vector history alone
predicts (the observation's last 1, 2 and 6 entries of distance and heading to the goal): a small
MLP fitted on four fifths of a round's states, R^2 on the rest, for round 0 (the teacher drives)
and for the last `--rounds` rounds (the student drives). Two entries give the heading change of
the last step, i.e. the steering just applied: where that predicts the label, a student can copy
its last steering instead of reading the image.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import numpy as np  # noqa: E402
import torch  # noqa: E402
from common import Run, add_run_args  # noqa: E402

from vid2sim.training.config import TrainConfig  # noqa: E402
from vid2sim.training.distill import Batch  # noqa: E402
from vid2sim.training.evaluate import EvalConfig, held_out_scenes, load_policy, make_eval_env  # noqa: E402
from vid2sim.training.wrappers import TeacherLabels  # noqa: E402
from vid2sim.training.run_files import policy_path  # noqa: E402
from vid2sim.training.student import StudentPolicy  # noqa: E402

BINS = ((-1.0, -0.9), (-0.9, -0.5), (-0.5, -0.1), (-0.1, 0.1), (0.1, 0.5), (0.5, 0.9), (0.9, 1.0))


def predictions(student: StudentPolicy, batch: Batch, chunk: int = 512) -> np.ndarray:
    """The student's actions [N, 2] on a round's stored (preprocessed) states."""
    out = []
    with torch.no_grad():
        for i in range(0, len(batch.actions), chunk):
            frames = torch.from_numpy(batch.frames[i:i + chunk]).float()
            out.append(student.act(frames, torch.from_numpy(batch.vectors[i:i + chunk])).numpy())
    return np.concatenate(out)


def label_fit(run_dir: Path, rounds: int) -> dict:
    """Steering of the run's student against its teacher's labels on the last `rounds` rounds."""
    student = StudentPolicy.load(policy_path(str(run_dir))).eval()
    files = sorted((run_dir / "data").glob("round_*.npz"))[-rounds:]
    if not files:
        raise SystemExit(f"{run_dir}: no data/round_*.npz (the run folder keeps no labelled states)")
    batches = [Batch.load(f) for f in files]
    pred = np.concatenate([predictions(student, b) for b in batches])[:, 1]  # [N]
    label = np.concatenate([b.actions for b in batches])[:, 1]  # [N]
    rows = []
    for lo, hi in BINS:
        m = (label >= lo) & ((label < hi) if hi < 1.0 else (label <= hi))
        if m.any():
            opposite = float(np.mean(np.sign(pred[m]) != np.sign(label[m]))) if lo >= 0.1 or hi <= -0.1 else None
            rows.append({"label_low": lo, "label_high": hi, "states": int(m.sum()), "share": float(m.mean()),
                         "steer_mean": float(pred[m].mean()), "steer_sd": float(pred[m].std()),
                         "opposite_sign": opposite})
    return {"rounds": [f.stem for f in files], "states": int(len(label)), "bins": rows,
            "corr": float(np.corrcoef(pred, label)[0, 1]), "mse": float(np.mean((pred - label) ** 2)),
            "label_var": float(label.var()), "full_lock_share": float(np.mean(np.abs(label) >= 0.9))}


def history_probe(run_dir: Path, rounds: int, updates: int = 3000, seed: int = 0) -> list[dict]:
    """R^2 of the steering label from the latest k goal vectors, k = 1, 2, 6 (see the module docs)."""
    files = sorted((run_dir / "data").glob("round_*.npz"))
    rows = []
    for name, chosen in (("round 0 (teacher drives)", files[:1]), (f"last {rounds} rounds", files[-rounds:])):
        batches = [Batch.load(f) for f in chosen]
        vectors = np.concatenate([b.vectors for b in batches])  # [N, 6, 2]
        label = np.concatenate([b.actions for b in batches])[:, 1]  # [N]
        order = np.random.default_rng(seed).permutation(len(label))
        train, test = order[: len(order) * 4 // 5], order[len(order) * 4 // 5:]
        for k in (1, 2, 6):
            pred = _fit_mlp(vectors[:, -k:].reshape(len(label), -1), label, train, test, updates, seed)
            r2 = 1.0 - float(np.mean((pred - label[test]) ** 2) / label[test].var())
            rows.append({"states": name, "vector_history": k, "r2": r2, "label_var": float(label[test].var())})
    return rows


def _fit_mlp(x: np.ndarray, y: np.ndarray, train: np.ndarray, test: np.ndarray, updates: int,
             seed: int) -> np.ndarray:
    """A 2 x 128 MLP regressing y [N] from standardised x [N, D] on `train`; predictions on `test`."""
    torch.manual_seed(seed)
    xs = torch.from_numpy(((x - x[train].mean(0)) / (x[train].std(0) + 1e-6)).astype(np.float32))
    ys = torch.from_numpy(y.astype(np.float32))
    net = torch.nn.Sequential(torch.nn.Linear(x.shape[1], 128), torch.nn.ReLU(), torch.nn.Linear(128, 128),
                              torch.nn.ReLU(), torch.nn.Linear(128, 1))
    opt = torch.optim.Adam(net.parameters(), 1e-3)
    rows = torch.from_numpy(train)
    for _ in range(updates):
        idx = rows[torch.randint(len(rows), (256,))]
        loss = (net(xs[idx])[:, 0] - ys[idx]).square().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    with torch.no_grad():
        return net(xs[torch.from_numpy(test)])[:, 0].numpy()


def contact_episodes(run_dir: Path, registry: str, trials: int, rescue: bool) -> dict:
    """Held-out episodes of the run's student with teacher labels beside it (see the module docs)."""
    saved = TrainConfig.load(run_dir / "config.json")
    teacher = saved.distill  # the teacher as in training: its route, re-planning and look-ahead
    checkouts = saved.env_kwargs.get("checkout_root", str(run_dir / "scenes"))
    conf = EvalConfig(registry=registry, policy=str(run_dir), trials=trials, max_steps=600, checkout_root=checkouts,
                      env_kwargs={"episode": {"expert_comfort": teacher.teacher_comfort}})
    scenes = held_out_scenes(conf)
    env = TeacherLabels(make_eval_env(conf, scenes), teacher.teacher_replan, lookahead=teacher.teacher_lookahead)
    act, _ = load_policy(conf.policy, conf.seed)
    failures, before_contact = 0, []
    for sid in scenes:
        for k in range(trials):
            obs, info = env.reset(seed=conf.seed + k, options={"scene_id": sid})
            steer, contact = [], None
            while True:
                action = act(env, obs) if contact is None or not rescue else info["teacher_action"]
                steer.append((float(action[1]), float(info["teacher_action"][1])))
                obs, _, terminated, truncated, info = env.step(action)
                contact = len(steer) if contact is None and info.get("collided") else contact
                if terminated or truncated:
                    break
            if not info["nav_episode"].success:
                failures += 1
                if contact is not None:
                    before_contact.append({"scene_id": sid, "trial": k, "contact_step": contact,
                                           "student": [a for a, _ in steer[max(0, contact - 15):contact]],
                                           "teacher": [t for _, t in steer[max(0, contact - 15):contact]]})
    env.close()
    return {"episodes": len(scenes) * trials, "failures": failures, "failures_after_contact": before_contact}


def report_contacts(run: Run, run_dir: Path, alone: dict, rescued: dict) -> None:
    print(f"{run_dir.name}: {alone['failures']} of {alone['episodes']} held-out episodes fail, "
          f"{len(alone['failures_after_contact'])} after a contact; with the teacher driving from the first "
          f"contact {rescued['failures']} fail")
    for f in alone["failures_after_contact"]:
        print(f"  {f['scene_id']} trial {f['trial']}, contact at step {f['contact_step']}: student "
              f"{np.round(f['student'], 2).tolist()}, teacher {np.round(f['teacher'], 2).tolist()}")
    run.record_all(f"{run_dir.name} held-out episodes", {"failures": alone["failures"],
                   "failures_after_contact": len(alone["failures_after_contact"]),
                   "failures_with_rescue": rescued["failures"]},
                   config={"episodes": alone["episodes"], "before_contact": alone["failures_after_contact"]})


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", type=Path, nargs="+", help="distillation run folders")
    ap.add_argument("--rounds", type=int, default=4, help="the last this many DAgger rounds")
    ap.add_argument("--contacts", type=int, default=0, help="held-out episodes per street to drive (0: none)")
    ap.add_argument("--registry", default=None, help="with --contacts: the registry the run trained on")
    ap.add_argument("--history-probe", action="store_true",
                    help="also: how much of the labels the goal-vector history alone predicts")
    add_run_args(ap)
    args = ap.parse_args()
    with Run("distill_labels", args) as run:
        for run_dir in args.runs:
            report(run, run_dir, label_fit(run_dir, args.rounds))
            if args.history_probe:
                for row in history_probe(run_dir, args.rounds):
                    print(f"  {row['states']}: steering label from the latest {row['vector_history']} goal "
                          f"vectors: R^2 {row['r2']:.3f} (label variance {row['label_var']:.3f})")
                    run.record(f"{run_dir.name} {row['states']}", f"r2_from_{row['vector_history']}_goal_vectors",
                               row["r2"], "", {"label_var": row["label_var"]})
            if args.contacts:
                registry = args.registry or TrainConfig.load(run_dir / "config.json").registry
                report_contacts(run, run_dir, contact_episodes(run_dir, registry, args.contacts, False),
                                contact_episodes(run_dir, registry, args.contacts, True))


def report(run: Run, run_dir: Path, fit: dict) -> None:
    print(f"{run_dir.name}: {fit['states']} states of {fit['rounds'][0]}..{fit['rounds'][-1]}, steering "
          f"corr {fit['corr']:.3f}, MSE {fit['mse']:.3f} (label variance {fit['label_var']:.3f}), "
          f"full-lock labels {fit['full_lock_share']:.3f}")
    for b in fit["bins"]:
        opp = "" if b["opposite_sign"] is None else f", opposite sign {b['opposite_sign']:.2f}"
        print(f"  label [{b['label_low']:+.1f}, {b['label_high']:+.1f}]: {b['states']:6d} states "
              f"({b['share']:.3f}), student {b['steer_mean']:+.3f} +- {b['steer_sd']:.3f}{opp}")
    config = {"rounds": fit["rounds"], "states": fit["states"], "bins": fit["bins"]}
    run.record_all(run_dir.name, {"steer_corr": fit["corr"], "steer_mse": fit["mse"],
                                  "label_var": fit["label_var"], "full_lock_share": fit["full_lock_share"]},
                   config=config)

if __name__ == "__main__":
    main()
