"""Data layer: one reader per on-disk format, the canonical store, clips, controls and splits."""
