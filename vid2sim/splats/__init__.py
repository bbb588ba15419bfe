"""splats"""
