"""SfM stage: COLMAP/GLOMAP poses, camera models, metric gravity-aligned frame, posed-clip exports."""
