"""motionsynth: a reproducible pipeline for human-motion synthesis.

Library layout (see README's architecture section):
``data`` readers, skeletons, clips, control signals and splits; ``models``;
``training``; ``metrics``; ``tracking`` (MLflow); ``viz``.
"""

__version__ = "0.1.0"
