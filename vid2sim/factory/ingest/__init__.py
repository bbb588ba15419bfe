"""Ingest stage: sources, clip lists, clips, video decode, privacy blur, dynamic masks."""
