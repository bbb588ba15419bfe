"""Browser viewer for scenes and episodes (viser): splats, collision mesh, walkable map, camera
path, metric grid and scene card as layers; episode replay; a registry page.

`vid2sim view` is the entry point (`vid2sim.cli.view`); `vid2sim.viewer.app` starts the server.
"""
