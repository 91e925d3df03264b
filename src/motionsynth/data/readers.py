"""The interface every dataset reader implements.

A reader is chosen by the dataset config's ``reader._target_`` (Hydra
``instantiate``), so supporting a new archive layout in an existing format is
a config file, and a new format is one new module plus a config file.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any

from .archive import Archive
from .types import Item, Rejected, Sequence, Skeleton


class DatasetReader(ABC):
    """Reads one dataset archive, member by member, without unpacking it."""

    @abstractmethod
    def list_items(self, archive: Archive) -> tuple[list[Item], list[Rejected]]:
        """Every candidate sequence of the archive, plus items rejected from names alone
        (for example a label file without its motion file). Sorted, deterministic."""

    @abstractmethod
    def read(self, archive: Archive, item: Item) -> tuple[Sequence, Skeleton]:
        """Read one item. Raises :class:`~motionsynth.data.types.InputError` naming the
        member and the problem on any bad input."""

    def extras(self, archive: Archive) -> dict[str, Any]:
        """JSON-serialisable per-dataset extras (for example camera parameters)."""
        return {}

    def notes(self, archive: Archive) -> list[str]:
        """Human-readable findings about the dataset (for example a frame-rate conflict)."""
        return []
