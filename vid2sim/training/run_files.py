"""Where a training run keeps its policy: the one lookup evaluation, export and ensembles share."""

from __future__ import annotations

from pathlib import Path

from vid2sim.training.distill import STUDENT_NAME


def policy_path(policy: str) -> Path:
    """The policy file of `policy`: itself when a file, else a run (or ensemble) folder's final.zip,
    student.pt, checkpoints/last.zip or checkpoints/last.pt, the first that exists."""
    p = Path(policy)
    for cand in (p, p / "final.zip", p / STUDENT_NAME, p / "checkpoints" / "last.zip", p / "checkpoints" / "last.pt"):
        if cand.is_file():
            return cand
    raise FileNotFoundError(f"no policy at {policy} (looked for final.zip, {STUDENT_NAME}, checkpoints/last.zip, "
                            "checkpoints/last.pt)")
