"""Evaluation: pose metrics, geometry metrics, scoring against synthetic ground truth."""
