"""Runtime: pipeline stage chain, Ray orchestrator, stage cache, progress, bundle assembly, demo,
and the work store (local folder or object store) that stage folders live in."""
