"""Factory: pipeline stages from a walking video to a registered simulation scene.

Grouped by stage: ingest/, sfm/, recon/, geometry/, synthetic/, evaluation/, runtime/.

Each stage is a module with a config dataclass, named presets, and
`work(conf, inputs...) -> StageWork` (the parts of its cache key and the work that fills its
folder); `runtime/runner.run_stage(work, out_dir)` runs it and marks the finished folder with
`stage.json` (see `runtime/stage_cache.py`) so re-runs skip work already done.
"""
