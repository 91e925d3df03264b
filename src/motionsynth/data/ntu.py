"""NTU RGB+D: the raw Kinect v2 ``.skeleton`` text format, read in place from a zip.

File format (one file per sequence, CRLF or LF text)::

    <frame count T>
    then per frame:
      <body count B>            (may be 0)
      then per body:
        <10 values: bodyID clipedEdges handLeftConfidence handLeftState
                    handRightConfidence handRightState isResticted leanX leanY trackingState>
        <joint count>           (always 25)
        25 lines of 12 values:  x y z depthX depthY colorX colorY
                                orientationW orientationX orientationY orientationZ trackingState

File names ``SsssCcccPpppRrrrAaaa`` give setup, camera, performer, replication
and action, all 1-based (:func:`parse_name`).

Coordinates. ``x y z`` are Kinect v2 *camera space* in metres: origin at the
depth sensor, X grows to the sensor's left, Y up (relative to the sensor's
tilt, so only approximately against gravity), Z out of the sensor into the
scene (depth > 0). That frame is right-handed and already Y-up; the reader
keeps x, y, z exactly as given (no flip, no re-centring). ``colorX colorY`` are
pixel coordinates in the 1920x1080 colour image of the same camera.

Joint order. The file lists the 25 joints in Kinect ``JointType`` order
(:data:`KINECT_JOINTS`), where ``SpineShoulder`` (index 20) is the parent of
``Neck`` (2) and both shoulders (4, 8). :class:`~motionsynth.data.types.Skeleton`
needs every parent before its child, so the dataset config lists the joints in
a topological order (:data:`DEFAULT_JOINT_NAMES`: ``SpineShoulder`` moved
right after ``SpineMid``) and the reader permutes the data columns by name.
:func:`parse_skeleton` itself returns the file (Kinect) order.

Parent table: the Kinect SDK hierarchy (:data:`KINECT_PARENT`). Hand tip and
thumb both hang off the hand; ST-GCN's graph chains ``HandTip -> Thumb ->
Hand``, which is a drawing convention, not the sensor's hierarchy.

Several people. A frame lists up to 6 tracked bodies, each with a 64-bit body
ID. :func:`parse_skeleton` keeps ``max_bodies`` body *slots*: IDs are ranked by
motion (sum over joints and axes of the variance of the position over the
frames the ID is tracked); each ID in turn goes to the first slot that has no
frame in common with it (so an ID that replaces another after lost tracking
continues that slot), and an ID that overlaps every slot is dropped with a
warning. Each ID occupies exactly one slot in all its frames; slots are then
ordered by first appearance.

Speed: the structure walk is a loop over frames and bodies that reads only the
small header lines; the 300 joint values of every body block are converted in
one vectorised pass over the whole file.
"""

from __future__ import annotations

import re
from itertools import chain
from pathlib import PurePosixPath
from typing import Any

import numpy as np

from .archive import Archive
from .readers import DatasetReader
from .types import InputError, Item, Rejected, Sequence, Skeleton

#: The 25 Kinect v2 joints in file (``JointType``) order.
KINECT_JOINTS: list[str] = [
    "SpineBase", "SpineMid", "Neck", "Head",
    "ShoulderLeft", "ElbowLeft", "WristLeft", "HandLeft",
    "ShoulderRight", "ElbowRight", "WristRight", "HandRight",
    "HipLeft", "KneeLeft", "AnkleLeft", "FootLeft",
    "HipRight", "KneeRight", "AnkleRight", "FootRight",
    "SpineShoulder", "HandTipLeft", "ThumbLeft", "HandTipRight", "ThumbRight",
]

#: The Kinect SDK hierarchy, by name (``None`` for the root).
KINECT_PARENT: dict[str, str | None] = {
    "SpineBase": None, "SpineMid": "SpineBase", "SpineShoulder": "SpineMid",
    "Neck": "SpineShoulder", "Head": "Neck",
    "ShoulderLeft": "SpineShoulder", "ElbowLeft": "ShoulderLeft", "WristLeft": "ElbowLeft",
    "HandLeft": "WristLeft", "HandTipLeft": "HandLeft", "ThumbLeft": "HandLeft",
    "ShoulderRight": "SpineShoulder", "ElbowRight": "ShoulderRight", "WristRight": "ElbowRight",
    "HandRight": "WristRight", "HandTipRight": "HandRight", "ThumbRight": "HandRight",
    "HipLeft": "SpineBase", "KneeLeft": "HipLeft", "AnkleLeft": "KneeLeft", "FootLeft": "AnkleLeft",
    "HipRight": "SpineBase", "KneeRight": "HipRight", "AnkleRight": "KneeRight", "FootRight": "AnkleRight",
}

#: A topological order of :data:`KINECT_JOINTS` (``SpineShoulder`` moved to index 2).
DEFAULT_JOINT_NAMES: list[str] = (
    KINECT_JOINTS[:2] + ["SpineShoulder"] + KINECT_JOINTS[2:20] + KINECT_JOINTS[21:]
)


def parents_for(names: list[str]) -> list[int]:
    """Parent indices into ``names`` from :data:`KINECT_PARENT` (-1 for the root)."""
    return [-1 if KINECT_PARENT[n] is None else names.index(KINECT_PARENT[n]) for n in names]


DEFAULT_PARENTS: list[int] = parents_for(DEFAULT_JOINT_NAMES)

NUM_JOINTS = 25
_VALUES_PER_JOINT = 12
_VALUES_PER_BODY_HEADER = 10
_NAME_RE = re.compile(r"S(\d{3})C(\d{3})P(\d{3})R(\d{3})A(\d{3})")
_NAME_FIELDS = ("setup", "camera", "performer", "replication", "action")


# ------------------------------------------------------------------------------- names

def parse_name(name: str) -> dict[str, int]:
    """Decode ``SsssCcccPpppRrrrAaaa`` from a member name (directory prefix and one
    extension allowed) into 1-based ints ``setup camera performer replication action``."""
    stem = PurePosixPath(str(name).replace("\\", "/")).stem
    m = _NAME_RE.fullmatch(stem)
    if m is None:
        raise InputError(name, f"file name {stem!r} is not an NTU name SsssCcccPpppRrrrAaaa "
                               "(setup, camera, performer, replication, action; 3 digits each)")
    out = {k: int(v) for k, v in zip(_NAME_FIELDS, m.groups())}
    zero = [k for k, v in out.items() if v == 0]
    if zero:
        raise InputError(name, f"file name {stem!r} has {', '.join(zero)} 0; NTU numbers are 1-based")
    return out


# ------------------------------------------------------------------------------- parsing

def _count(lines: list[str], i: int, member: str, what: str) -> int:
    """The single non-negative integer on line ``i`` (0-based), or an InputError saying why not."""
    parts = lines[i].split()
    if len(parts) != 1:
        raise InputError(member, f"line {i + 1}: expected the {what} (one integer) but found "
                                 f"{len(parts)} values; a body count or joint count does not "
                                 "match the lines that follow")
    try:
        v = int(parts[0])
    except ValueError:
        raise InputError(member, f"line {i + 1}: non-numeric {what} {parts[0]!r}") from None
    if v < 0:
        raise InputError(member, f"line {i + 1}: negative {what} {v}")
    return v


def _to_float(tokens: list[str], member: str, lines: list[str], line_idx) -> np.ndarray:
    """Tokens to float64 in one pass; on failure find the first non-numeric token (slow path)."""
    try:
        return np.array(tokens, dtype=np.float64)
    except ValueError:
        for i in line_idx:
            for tok in lines[i].split():
                try:
                    float(tok)
                except ValueError:
                    raise InputError(member, f"line {i + 1}: non-numeric token {tok!r}") from None
        raise InputError(member, "non-numeric token") from None  # pragma: no cover


def parse_skeleton(text: str, member: str, max_bodies: int = 2) -> dict[str, Any]:
    """Parse one NTU ``.skeleton`` text.

    Returns a dict with (joints in file order, :data:`KINECT_JOINTS`):

    * ``positions`` float32 ``[T, max_bodies, 25, 3]``: camera-space x y z, metres;
      zero where a slot is empty;
    * ``color2d`` float32 ``[T, max_bodies, 25, 2]``: colour-image pixels;
    * ``tracking`` uint8 ``[T, max_bodies, 25]``: per-joint tracking state
      (0 not tracked, 1 inferred, 2 tracked);
    * ``body_mask`` bool ``[T, max_bodies]``;
    * ``body_ids``: per slot, the list of Kinect body IDs (ints) it holds;
    * ``dropped_ids``: body IDs left out (more than ``max_bodies`` at once);
    * ``warnings``: human-readable notes (dropped bodies);
    * ``bodies``: the most bodies listed in one frame; ``frames_without_body``:
      frames whose body count is 0.

    Raises :class:`InputError` naming ``member`` on an empty or truncated file, a
    non-numeric token, a frame or body count that does not match the lines that
    follow, a joint count other than 25, NaN/Inf, or no body in any frame.
    """
    if max_bodies < 1:
        raise ValueError(f"max_bodies must be >= 1, got {max_bodies}")
    lines = text.splitlines()
    n = len(lines)
    while n and not lines[n - 1].strip():
        n -= 1
    if n == 0:
        raise InputError(member, "empty file")
    T = _count(lines, 0, member, "frame count")
    if T == 0:
        raise InputError(member, "frame count header is 0: no frames")

    # Structure walk: only the count lines and the body header lines are read here.
    nb_frame = np.zeros(T, dtype=np.int64)
    blk_frame: list[int] = []   # frame of each body block
    blk_line: list[int] = []    # line index of each block's first joint line
    blk_id: list[int] = []      # body ID of each block
    head_lines: list[int] = []  # line index of each block's 10-value header
    i = 1
    for f in range(T):
        if i >= n:
            raise InputError(member, f"truncated: the frame-count header says {T} frames "
                                     f"but the file ends after {f} frame(s)")
        nb = _count(lines, i, member, f"body count of frame {f}")
        nb_frame[f] = nb
        i += 1
        for b in range(nb):
            if i >= n:
                raise InputError(member, f"frame {f}: the body count says {nb} bodies but the file "
                                         f"ends after {b} of them (body count does not match the joint "
                                         "lines that follow, or the file is truncated)")
            head = lines[i].split()
            if len(head) != _VALUES_PER_BODY_HEADER:
                raise InputError(member, f"line {i + 1}, frame {f}: the body count says {nb} bodies "
                                         f"but body {b + 1}'s header line has {len(head)} value(s), "
                                         f"expected {_VALUES_PER_BODY_HEADER} (body count does not "
                                         "match the joint lines that follow)")
            try:
                bid = int(head[0])
            except ValueError:
                raise InputError(member, f"line {i + 1}: non-numeric body ID {head[0]!r}") from None
            if i + 1 >= n:
                raise InputError(member, f"truncated: frame {f} body {b + 1} has no joint count line")
            jc = _count(lines, i + 1, member, f"joint count of frame {f} body {b + 1}")
            if jc != NUM_JOINTS:
                raise InputError(member, f"line {i + 2}, frame {f} body {b + 1}: joint count {jc}, "
                                         f"expected {NUM_JOINTS}")
            head_lines.append(i)
            blk_line.append(i + 2)
            blk_frame.append(f)
            blk_id.append(bid)
            i += 2 + NUM_JOINTS
            if i > n:
                raise InputError(member, f"truncated: frame {f} body {b + 1} has "
                                         f"{n - (i - NUM_JOINTS)} of {NUM_JOINTS} joint lines")
    if i < n:
        raise InputError(member, f"the frame-count header says {T} frames but {n - i} more line(s) "
                                 "follow the last of them (frame count or a body count does not "
                                 "match the data)")
    if not blk_line:
        raise InputError(member, f"no frame has any body ({T} frames, all with body count 0)")

    # Values: every joint line of every block, converted in one pass.
    nblk = len(blk_line)
    tokens = "\n".join(chain.from_iterable(lines[s:s + NUM_JOINTS] for s in blk_line)).split()
    if len(tokens) != nblk * NUM_JOINTS * _VALUES_PER_JOINT:
        for s in blk_line:  # slow path, errors only: find the malformed line
            for k in range(s, s + NUM_JOINTS):
                c = len(lines[k].split())
                if c != _VALUES_PER_JOINT:
                    raise InputError(member, f"line {k + 1}: joint line has {c} value(s), expected "
                                             f"{_VALUES_PER_JOINT} (a count does not match the lines "
                                             "that follow, or the file is truncated)")
    joint_lines = chain.from_iterable(range(s, s + NUM_JOINTS) for s in blk_line)  # lazy: errors only
    vals = _to_float(tokens, member, lines, joint_lines).reshape(nblk, NUM_JOINTS, _VALUES_PER_JOINT)
    head_tok = " ".join(lines[h] for h in head_lines).split()
    _to_float(head_tok, member, lines, head_lines)
    finite = np.isfinite(vals).all(axis=(1, 2))
    if not finite.all():
        k = int(np.flatnonzero(~finite)[0])
        j = int(np.flatnonzero(~np.isfinite(vals[k]).all(axis=1))[0])
        raise InputError(member, f"line {blk_line[k] + j + 1}, frame {blk_frame[k]}: NaN or Inf "
                                 f"value ({int((~finite).sum())} body block(s) affected)")
    state = vals[..., 11]
    if not np.isin(state, (0.0, 1.0, 2.0)).all():
        k = int(np.flatnonzero(~np.isin(state, (0.0, 1.0, 2.0)).all(axis=1))[0])
        raise InputError(member, f"frame {blk_frame[k]}: joint tracking state outside 0/1/2 "
                                 "(malformed joint lines)")

    frames = np.asarray(blk_frame, dtype=np.int64)
    uniq = list(dict.fromkeys(blk_id))  # IDs in order of first appearance
    rank = {b: k for k, b in enumerate(uniq)}
    idk = np.array([rank[b] for b in blk_id], dtype=np.int64)
    pair = frames * len(uniq) + idk
    if len(np.unique(pair)) != nblk:
        _, first = np.unique(pair, return_index=True)
        k = int(np.setdiff1d(np.arange(nblk), first)[0])
        dup = int(frames[k])
        raise InputError(member, f"frame {dup}: body ID {blk_id[k]} listed twice")

    xyz = vals[..., 0:3]
    slot_of, dropped = _assign_slots(xyz, frames, idk, len(uniq), T, max_bodies)
    warnings: list[str] = []
    for k in dropped:
        warnings.append(f"{member}: dropped body {uniq[k]} ({int((idk == k).sum())} frames): more "
                        f"than {max_bodies} bodies at once; kept the {max_bodies} with most motion")

    keep = slot_of[idk] >= 0
    fk, sk = frames[keep], slot_of[idk][keep]
    positions = np.zeros((T, max_bodies, NUM_JOINTS, 3), dtype=np.float32)
    color2d = np.zeros((T, max_bodies, NUM_JOINTS, 2), dtype=np.float32)
    tracking = np.zeros((T, max_bodies, NUM_JOINTS), dtype=np.uint8)
    body_mask = np.zeros((T, max_bodies), dtype=bool)
    positions[fk, sk] = xyz[keep]
    color2d[fk, sk] = vals[keep][..., 5:7]
    tracking[fk, sk] = state[keep].astype(np.uint8)
    body_mask[fk, sk] = True
    body_ids = [[uniq[k] for k in range(len(uniq)) if slot_of[k] == s] for s in range(max_bodies)]
    return {
        "positions": positions, "color2d": color2d, "tracking": tracking, "body_mask": body_mask,
        "body_ids": body_ids, "dropped_ids": [uniq[k] for k in dropped], "warnings": warnings,
        "bodies": int(nb_frame.max()), "frames_without_body": int((nb_frame == 0).sum()),
    }


def _assign_slots(xyz: np.ndarray, frames: np.ndarray, idk: np.ndarray, K: int, T: int,
                  max_bodies: int) -> tuple[np.ndarray, list[int]]:
    """Slot per body ID (-1 dropped): most motion first, each into the first slot it does
    not overlap in time; slots then renumbered by first appearance."""
    slot_of = -np.ones(K, dtype=np.int64)
    if K <= max_bodies:  # the common case: one slot per ID, by first appearance
        slot_of[:] = np.arange(K)
        return slot_of, []
    motion = np.zeros(K)
    present = np.zeros((K, T), dtype=bool)
    for k in range(K):  # loop over body IDs (a handful), never over frames or joints
        sel = idk == k
        motion[k] = float(xyz[sel].var(axis=0).sum())
        present[k, frames[sel]] = True
    occupied = np.zeros((max_bodies, T), dtype=bool)
    dropped: list[int] = []
    for k in np.argsort(-motion, kind="stable"):
        for s in range(max_bodies):
            if not (occupied[s] & present[k]).any():
                occupied[s] |= present[k]
                slot_of[k] = s
                break
        else:
            dropped.append(int(k))
    used = [s for s in range(max_bodies) if occupied[s].any()]
    # first appearance; ties (same first frame) by the order the file lists the IDs
    order = sorted(used, key=lambda s: (int(np.argmax(occupied[s])), int(np.flatnonzero(slot_of == s)[0])))
    renum = {s: r for r, s in enumerate(order)}
    slot_of = np.array([renum[s] if s >= 0 else -1 for s in slot_of], dtype=np.int64)
    return slot_of, sorted(dropped)


# ------------------------------------------------------------------------------- reader

class NTUReader(DatasetReader):
    """NTU RGB+D (60 or 120) raw ``.skeleton`` files in one archive, any folder layout.

    Parameters (from ``conf/dataset/ntu_samples.yaml``, ``reader:`` section):

    pattern: members that are skeleton files (``**/*.skeleton``: flat or nested).
    max_bodies: body slots kept per sequence (NTU: 2).
    fps: frame rate (Kinect v2: 30).
    joint_names: the 25 Kinect joint names in a topological order (default
        :data:`DEFAULT_JOINT_NAMES`); the data columns are permuted to it.
    parents: parent index per ``joint_names`` entry, -1 for the root (default:
        the Kinect SDK hierarchy, :func:`parents_for`).
    action_names: 1-based action number -> name; absent numbers are named ``A%03d``.

    ``read`` stacks the body slots along the joint axis: ``J = max_bodies * 25``,
    joints named ``b<slot>_<Joint>``, each slot's ``SpineBase`` a root; an empty
    slot's joints are zero (see ``body_mask``). ``views2d`` ``[T, 1, J, 2]`` holds the
    colour-camera pixels of this file's camera; ``seq.view_depth`` ``[T, 1]`` the
    camera-space z (metres) of ``b0_SpineBase`` (0 where slot 0 is empty).
    Meta adds ``bodies`` (most bodies listed in one frame, before dropping),
    ``frames_without_body`` (frames with no kept body), ``dropped_bodies`` and,
    when bodies were dropped, ``warnings`` (also returned by :meth:`notes`).
    """

    format_pattern = "**/*.skeleton"

    def __init__(self, pattern: str = "**/*.skeleton", max_bodies: int = 2, fps: float = 30.0,
                 joint_names: list[str] | None = None, parents: list[int] | None = None,
                 action_names: dict[int, str] | None = None):
        self.pattern = pattern
        self.max_bodies = int(max_bodies)
        if self.max_bodies < 1:
            raise ValueError(f"reader.max_bodies must be >= 1, got {max_bodies}")
        self.fps = float(fps)
        self.joint_names = list(joint_names) if joint_names is not None else list(DEFAULT_JOINT_NAMES)
        if sorted(self.joint_names) != sorted(KINECT_JOINTS):
            raise ValueError("reader.joint_names must list each of the 25 Kinect v2 joints once; "
                             f"got {self.joint_names}")
        self.parents = list(parents) if parents is not None else parents_for(self.joint_names)
        if len(self.parents) != NUM_JOINTS:
            raise ValueError(f"reader.parents must have {NUM_JOINTS} entries, got {len(self.parents)}")
        if any(p >= j for j, p in enumerate(self.parents)):
            raise ValueError("reader.parents: every parent must come before its child "
                             "(list joint_names in a topological order)")
        self.action_names = {int(k): str(v) for k, v in (action_names or {}).items()}
        #: file column of each configured joint
        self.perm = np.array([KINECT_JOINTS.index(n) for n in self.joint_names], dtype=np.int64)
        self._warnings: list[str] = []

    # -- names
    @property
    def names(self) -> list[str]:
        return [f"b{b}_{n}" for b in range(self.max_bodies) for n in self.joint_names]

    def stacked_parents(self) -> np.ndarray:
        base = np.asarray(self.parents, dtype=np.int64)
        return np.concatenate([np.where(base >= 0, base + b * NUM_JOINTS, -1)
                               for b in range(self.max_bodies)])

    def _meta(self, fields: dict[str, int]) -> dict[str, Any]:
        a = fields["action"]
        return {**fields, "subject": "P%03d" % fields["performer"], "view": "C%03d" % fields["camera"],
                "label": a - 1, "label_name": self.action_names.get(a, "A%03d" % a)}

    # -- items
    def list_items(self, archive: Archive) -> tuple[list[Item], list[Rejected]]:
        items: list[Item] = []
        rejected: list[Rejected] = []
        seen: dict[str, str] = {}
        for m in archive.glob(self.pattern):
            try:
                fields = parse_name(m)
            except InputError as e:
                rejected.append(Rejected.from_error(e))
                continue
            key = PurePosixPath(m).stem
            if key in seen:
                rejected.append(Rejected(m, f"duplicate sequence {key} (also {seen[key]})"))
                continue
            seen[key] = m
            items.append(Item(key, {"motion": m}, self._meta(fields)))
        items.sort(key=lambda it: it.key)
        return items, rejected

    # -- reading
    def read(self, archive: Archive, item: Item) -> tuple[Sequence, Skeleton]:
        member = item.members["motion"]
        parsed = parse_skeleton(archive.text(member), member, self.max_bodies)
        self._warnings.extend(parsed["warnings"])
        T, P = parsed["body_mask"].shape
        J = P * NUM_JOINTS
        pos = parsed["positions"][:, :, self.perm].reshape(T, J, 3)
        col = parsed["color2d"][:, :, self.perm].reshape(T, 1, J, 2)
        mask = parsed["body_mask"]
        meta = {"member": member, **item.meta,
                "bodies": parsed["bodies"],
                "frames_without_body": int((~mask.any(axis=1)).sum()),
                "dropped_bodies": len(parsed["dropped_ids"])}
        if parsed["warnings"]:
            meta["warnings"] = "; ".join(parsed["warnings"])
        seq = Sequence(pos, self.fps, meta, views2d=col, body_mask=mask)
        seq.view_depth = pos[:, self.names.index("b0_SpineBase"), 2:3].astype(np.float32)  # [T, 1]
        return seq, self.skeleton(parsed["positions"][:, 0][:, self.perm], mask[:, 0])

    def skeleton(self, body0: np.ndarray | None = None, tracked: np.ndarray | None = None) -> Skeleton:
        """The stacked skeleton. Offsets: the mean bone vectors (metres, camera axes) of
        ``body0`` ``[T, 25, 3]`` (configured joint order) over its ``tracked`` frames,
        the same for every slot; roots at the origin. Zero offsets without data."""
        base = np.asarray(self.parents, dtype=np.int64)
        offs = np.zeros((NUM_JOINTS, 3), dtype=np.float32)
        if body0 is not None:
            b = body0 if tracked is None else body0[np.asarray(tracked, bool)]
            if len(b):
                bones = b - b[:, np.maximum(base, 0)]
                offs = bones.mean(axis=0).astype(np.float32)
                offs[base < 0] = 0.0
        return Skeleton(
            names=self.names, parents=self.stacked_parents(),
            offsets=np.tile(offs, (self.max_bodies, 1)),
            root="b0_SpineBase", hips=("b0_HipLeft", "b0_HipRight"),
            shoulders=("b0_ShoulderLeft", "b0_ShoulderRight"),
            feet=["b0_FootLeft", "b0_FootRight"],
        )

    def notes(self, archive: Archive) -> list[str]:
        """Warnings gathered by :meth:`read` so far (bodies dropped beyond ``max_bodies``)."""
        return sorted(set(self._warnings))
