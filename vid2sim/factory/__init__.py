"""Factory: pipeline stages from a walking video to a registered simulation scene.

Grouped by stage: ingest/, sfm/, recon/, geometry/, synthetic/, evaluation/, runtime/.

Each stage is a module with a config dataclass, named presets, and
`main(conf, inputs..., out_dir) -> Path`; finished outputs are marked with
`stage.json` (see `runtime/stage_cache.py`) so re-runs skip work already done.
"""
