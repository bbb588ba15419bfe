"""Bundle formats: the contracts every layer shares (scene bundle files, scene.json, cameras table,
walkable grid, 3DGS PLY properties, the robot spec). Imports nothing else from vid2sim except `versioning`."""
