"""Runtime: the factory's typed steps (`steps/`) and their one runner, the pipeline driver, Ray
orchestrator, stage cache, progress, demo, and the work store (local folder or object store)
that step folders live in."""
