"""How closely a distilled student follows its teacher on the states it drove into itself.

    python benchmarks/distill_labels.py RUN_DIR [RUN_DIR ...] [--rounds 4]
    python benchmarks/distill_labels.py RUN_DIR --contacts 5 --registry ROOT/registry

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
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import numpy as np  # noqa: E402
import torch  # noqa: E402
from common import Run, add_run_args  # noqa: E402

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


def contact_episodes(run_dir: Path, registry: str, trials: int, rescue: bool) -> dict:
    """Held-out episodes of the run's student with teacher labels beside it (see the module docs)."""
    saved = json.loads((run_dir / "config.json").read_text())
    checkouts = saved.get("env_kwargs", {}).get("checkout_root", str(run_dir / "scenes"))
    comfort = saved["distill"].get("teacher_comfort", 0.0)  # the teacher's route as in training
    conf = EvalConfig(registry=registry, policy=str(run_dir), trials=trials, max_steps=600, checkout_root=checkouts,
                      env_kwargs={"episode": {"expert_comfort": comfort}})
    scenes = held_out_scenes(conf)
    env = TeacherLabels(make_eval_env(conf, scenes))
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
    add_run_args(ap)
    args = ap.parse_args()
    with Run("distill_labels", args) as run:
        for run_dir in args.runs:
            report(run, run_dir, label_fit(run_dir, args.rounds))
            if args.contacts:
                registry = args.registry or json.loads((run_dir / "config.json").read_text())["registry"]
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
