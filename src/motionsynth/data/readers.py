"""The interface every dataset reader implements.

A reader is chosen by the dataset config's ``reader._target_`` (Hydra
``instantiate``), so supporting a new archive layout in an existing format is
a config file, and a new format is one new module plus a config file.

Accounting (done by the ingest driver, :mod:`.ingest`): every member of the
reader's format (:attr:`DatasetReader.format_pattern`) that is neither part of a
listed item, nor rejected, nor an auxiliary member (a skeleton template, a camera
file) was left out by the config (``reader.pattern``, ``reader.actions``, ...): it
is counted as *filtered out*, with :meth:`DatasetReader.why_filtered` as its reason.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any

from .archive import Archive
from .types import Item, Rejected, Sequence, Skeleton


class DatasetReader(ABC):
    """Reads one dataset archive, member by member, without unpacking it."""

    #: archive members of this format (motion files), e.g. ``**/*.bvh``; ``None``: no filter accounting
    format_pattern: str | None = None

    @abstractmethod
    def list_items(self, archive: Archive) -> tuple[list[Item], list[Rejected]]:
        """Every candidate sequence of the archive, plus items rejected from names alone
        (for example a label file without its motion file). Sorted, deterministic.
        Members the config's filters leave out are neither: they are counted as filtered."""

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

    def auxiliary_members(self) -> set[str]:
        """Members of :attr:`format_pattern` read for another purpose than as items (a template)."""
        return set()

    def why_filtered(self, member: str) -> str:
        """Why the config leaves ``member`` (of the format, not listed) out; says which setting."""
        return f"not matched by reader.pattern {getattr(self, 'pattern', None)!r}"

    def class_names(self, archive: Archive, items: list[Item]) -> dict[int, str]:
        """Raw class id -> name of every class the dataset holds: the labels of ``items`` (every
        listed item, before a profile's item limit). The driver maps the raw ids, sorted, to the
        contiguous labels ``0..C-1`` (:func:`motionsynth.data.ingest.class_table`)."""
        return {int(it.meta["label"]): str(it.meta.get("label_name", it.meta["label"]))
                for it in items if it.meta.get("label") is not None}
