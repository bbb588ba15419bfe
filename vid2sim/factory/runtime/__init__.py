"""Runtime: pipeline stage chain, Ray orchestrator, stage cache, progress, bundle assembly, demo."""
