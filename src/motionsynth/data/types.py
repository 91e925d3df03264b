"""The data contracts shared by every reader and stage.

One place defines each contract; everything else imports it.

Shapes (documented once, used everywhere):

* ``Sequence.positions``: float32 ``[T, J, 3]``, metres, world frame, Y up.
* ``Sequence.views2d``: float32 ``[T, V, J, 2]`` 2-D projections (pixels) for
  ``V`` camera views, or ``None`` when the source has no camera.
* ``Sequence.body_mask``: bool ``[T, P]`` for multi-person sources whose
  skeleton stacks ``P`` bodies of ``J / P`` joints each, else ``None``.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np


class InputError(ValueError):
    """A problem with one input item. Always names the member and what is wrong."""

    def __init__(self, member: str, problem: str):
        self.member = member
        self.problem = problem
        super().__init__(f"{member}: {problem}")


class MissingDataError(FileNotFoundError):
    """A stage's input is not there: the message names the path and the command that makes it."""


class ConfigError(ValueError):
    """The config disagrees with the data: the message names the config field and the values found."""


#: the errors a stage's entry point prints as one line (``pipelines/_common.py: one_line_errors``):
#: bad input, missing input, a config that does not fit its data. Anything else is a bug: traceback.
USER_ERRORS = (InputError, MissingDataError, ConfigError)


@dataclass(frozen=True)
class Rejected:
    """One rejected input item: the archive member (or item key) and why."""

    member: str
    reason: str

    @classmethod
    def from_error(cls, err: InputError) -> "Rejected":
        return cls(err.member, err.problem)


@dataclass
class Skeleton:
    """A kinematic skeleton: joint names, parent indices (-1 for a root) and rest offsets.

    ``offsets`` are float32 ``[J, 3]`` in metres, each relative to the parent joint.
    ``root`` names the joint whose trajectory defines the body (Bandai: ``Hips``),
    which need not be the hierarchy's root. ``left``/``right`` name the hip and
    shoulder joints used for the facing direction; ``feet`` the contact joints.
    ``end_sites`` lists joints that are BVH End Sites (no channels).
    """

    names: list[str]
    parents: np.ndarray
    offsets: np.ndarray
    root: str | None = None
    hips: tuple[str, str] | None = None  # (left, right)
    shoulders: tuple[str, str] | None = None  # (left, right)
    feet: list[str] = field(default_factory=list)
    end_sites: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.parents = np.asarray(self.parents, dtype=np.int64)
        self.offsets = np.asarray(self.offsets, dtype=np.float32).reshape(len(self.names), 3)
        if len(self.parents) != len(self.names):
            raise ValueError("skeleton: parents and names differ in length")
        if np.any(self.parents >= np.arange(len(self.names))):
            raise ValueError("skeleton: every parent must come before its child")

    @property
    def num_joints(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"unknown joint {name!r}; skeleton has {self.names}") from None

    def indices(self, names: list[str]) -> np.ndarray:
        return np.array([self.index(n) for n in names], dtype=np.int64)

    def subset(self, names: list[str]) -> "Skeleton":
        """The skeleton restricted to ``names``; a parent outside the subset is
        replaced by its nearest kept ancestor, offsets are recomputed from rest positions."""
        keep = self.indices(names)
        rest = self.rest_positions()
        pos_in_keep = {int(j): i for i, j in enumerate(keep)}
        parents = []
        for j in keep:
            p = int(self.parents[j])
            while p >= 0 and p not in pos_in_keep:
                p = int(self.parents[p])
            parents.append(pos_in_keep.get(p, -1))
        parents = np.array(parents)
        offs = rest[keep] - np.where(parents[:, None] >= 0, rest[keep][np.maximum(parents, 0)], 0)
        keepset = set(names)
        return Skeleton(
            names=list(names), parents=parents, offsets=offs,
            root=self.root if self.root in keepset else None,
            hips=self.hips if self.hips and set(self.hips) <= keepset else None,
            shoulders=self.shoulders if self.shoulders and set(self.shoulders) <= keepset else None,
            feet=[f for f in self.feet if f in keepset],
            end_sites=[e for e in self.end_sites if e in keepset],
        )

    def rest_positions(self) -> np.ndarray:
        """Rest-pose joint positions ``[J, 3]`` (sum of offsets along each chain)."""
        pos = np.zeros_like(self.offsets)
        for j, p in enumerate(self.parents):  # loop over joints, never over frames
            pos[j] = self.offsets[j] + (pos[p] if p >= 0 else 0)
        return pos

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["parents"] = self.parents.tolist()
        d["offsets"] = self.offsets.round(6).tolist()
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "Skeleton":
        d = dict(d)
        for k in ("hips", "shoulders"):
            if d.get(k) is not None:
                d[k] = tuple(d[k])
        return cls(**d)

    def save(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(self.to_dict(), indent=1))

    @classmethod
    def load(cls, path: str | Path) -> "Skeleton":
        return cls.from_dict(json.loads(Path(path).read_text()))


@dataclass
class Sequence:
    """One source motion, the output of a reader.

    ``meta`` holds the metadata-table row: at least ``sequence_id`` and
    ``member``; readers add ``subject``, ``view``, ``label``, ``label_name``,
    ``style`` where the source has them.
    """

    positions: np.ndarray
    fps: float
    meta: dict[str, Any]
    views2d: np.ndarray | None = None
    body_mask: np.ndarray | None = None

    def __post_init__(self) -> None:
        member = str(self.meta.get("member", self.meta.get("sequence_id", "?")))
        p = np.asarray(self.positions)
        if p.ndim != 3 or p.shape[-1] != 3:
            raise InputError(member, f"positions must be [T, J, 3], got shape {p.shape}")
        if p.shape[0] == 0:
            raise InputError(member, "no frames")
        if not np.isfinite(p).all():
            bad = np.flatnonzero(~np.isfinite(p).reshape(p.shape[0], -1).all(1))
            raise InputError(member, f"NaN or Inf in {len(bad)} frame(s), first at frame {bad[0]}")
        self.positions = p.astype(np.float32, copy=False)
        if self.views2d is not None:
            v = np.asarray(self.views2d, dtype=np.float32)
            if v.ndim != 4 or v.shape[0] != p.shape[0] or v.shape[2] != p.shape[1] or v.shape[3] != 2:
                raise InputError(member, f"views2d must be [T, V, J, 2] matching positions, got {v.shape}")
            self.views2d = v
        if self.body_mask is not None:
            self.body_mask = np.asarray(self.body_mask, dtype=bool)
        if not (self.fps > 0):
            raise InputError(member, f"frame rate must be positive, got {self.fps}")

    @property
    def num_frames(self) -> int:
        return int(self.positions.shape[0])


@dataclass
class Item:
    """One candidate input of a dataset: a sequence key and the archive members it needs.

    ``members`` maps a role (``motion``, ``label``, ...) to an archive member name.
    ``meta`` holds what the reader already knows from the names alone.
    """

    key: str
    members: dict[str, str]
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def member(self) -> str:
        return self.members.get("motion") or next(iter(self.members.values()), self.key)
