"""Ensembles of distilled pixel students: several students drive together, the mean of their actions.

Students distilled with the same recipe but different seeds fail in different episodes (held-out
SR 0.53-0.715 over three seeds); averaging their actions at every step is a policy of its own
(docs/studies/pixel_distillation.md). An ensemble is stored like one student: ENSEMBLE/student.pt
holds every member's checkpoint, so `vid2sim eval policy --policy ENSEMBLE`, `export_policy` and
`NavPolicy` take it unchanged; ENSEMBLE/ensemble.json names the runs it came from.

    vid2sim ensemble RUN_A RUN_B RUN_C --out ENSEMBLE

Members must see the same observation (stack, channels, size, goal vector); what each does with
it (frames used, pooling, widths) may differ, since each member preprocesses the raw observation.
"""

from __future__ import annotations

import json
from pathlib import Path

import torch
from torch import nn

from vid2sim.training.distill import STUDENT_NAME
from vid2sim.training.run_files import policy_path
from vid2sim.training.student import StudentPolicy
from vid2sim.versioning import code_version

ENSEMBLE_META = "ensemble.json"


class EnsembleError(ValueError):
    """An ensemble that cannot be built (too few members, members that see different observations)."""


class StudentEnsemble(nn.Module):
    """Raw observation (uint8 image [B, 6, C, H, W], vector [B, 6, 2]) -> mean member action [B, 2]."""

    def __init__(self, members: list[StudentPolicy], sources: list[str] | None = None):
        super().__init__()
        if len(members) < 2:
            raise EnsembleError(f"too_few_members: an ensemble needs at least 2 students, got {len(members)}")
        shapes = {(m.image_shape, m.vector_shape) for m in members}
        if len(shapes) > 1:
            raise EnsembleError(f"observation_mismatch: the students see different observations {sorted(shapes)} "
                                f"(sources: {sources or 'in memory'})")
        self.members = nn.ModuleList(members)
        self.sources = list(sources or [])
        self.image_shape, self.vector_shape = members[0].image_shape, members[0].vector_shape

    def forward(self, image: torch.Tensor, vector: torch.Tensor) -> torch.Tensor:
        return torch.stack([m(image, vector) for m in self.members]).mean(dim=0)  # [B, 2], each in [-1, 1]

    def architecture(self) -> dict:
        """What the export records: every member's encoder and input choice."""
        return {"ensemble": [m.config.to_dict() for m in self.members]}

    # ------------------------------------------------------------------ persistence
    def checkpoint(self) -> dict:
        return {"members": [m.checkpoint() for m in self.members], "sources": self.sources}

    @classmethod
    def from_checkpoint(cls, ckpt: dict) -> "StudentEnsemble":
        members = [StudentPolicy.from_checkpoint(c) for c in ckpt["members"]]
        return cls(members, ckpt.get("sources")).eval()

    def save(self, path: str | Path) -> None:
        torch.save(self.checkpoint(), path)


def load_student(path: str | Path) -> StudentPolicy | StudentEnsemble:
    """A student.pt (one student or an ensemble), or the `student` of a run's checkpoints/last.pt."""
    ckpt = torch.load(path, map_location="cpu", weights_only=False)
    if "members" in ckpt:
        return StudentEnsemble.from_checkpoint(ckpt)
    return StudentPolicy.from_checkpoint(ckpt["student"] if "student" in ckpt else ckpt)


def build_ensemble(runs: list[str | Path], out_dir: str | Path) -> Path:
    """Write OUT/student.pt (the members' checkpoints) and OUT/ensemble.json from distillation runs
    (run folders or student .pt files); returns OUT. Named errors for a missing or non-student run."""
    members, sources = [], []
    for run in runs:
        path = policy_path(str(run))
        if path.suffix != ".pt":
            raise EnsembleError(f"not_a_student: {run} holds a SAC model ({path.name}), not a distilled student")
        student = load_student(path)
        if isinstance(student, StudentEnsemble):
            raise EnsembleError(f"nested_ensemble: {run} is an ensemble already; list its runs instead")
        members.append(student)
        sources.append(str(Path(run).resolve()))
    ensemble = StudentEnsemble(members, sources)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    ensemble.save(out / STUDENT_NAME)
    meta = {"members": sources, "code_version": code_version(), "architecture": ensemble.architecture()}
    (out / ENSEMBLE_META).write_text(json.dumps(meta, indent=2))
    return out
