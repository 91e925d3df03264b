"""BVH: one general reader and writer, with vectorised forward kinematics.

Supported:

* any channel layout per joint, including position channels on every joint
  (all Bandai-Namco files have them), and any Euler order per joint;
* End Sites (optionally kept as joints, named ``<parent>_End``);
* tabs or spaces, CRLF or LF line ends, several ROOTs.

Conventions (the common BVH reading, as in Blender and the CMU conversions):

* A joint's rotation channels, listed ``A B C``, compose intrinsically:
  ``R = R_A(a) @ R_B(b) @ R_C(c)`` with angles in degrees.
* A joint's local translation is its OFFSET; each position channel present
  *replaces* that component of the OFFSET (Bandai: position == OFFSET on every
  joint but ``Hips``; CMU: the root's OFFSET is 0).
* World transform: ``G_j = G_parent(j) @ [R_j | t_j]``, so a joint's position is
  ``p_j = R_parent @ t_j + p_parent``.

Forward kinematics never loops over frames: it batches all frames and, per
depth level of the hierarchy, all joints of that level.
"""

from __future__ import annotations

import io
import re
import warnings
from dataclasses import dataclass, field
from pathlib import PurePosixPath

import numpy as np
import pandas as pd

from .archive import Archive, matches
from .readers import DatasetReader
from .types import InputError, Item, Rejected, Sequence, Skeleton

_POS = {"Xposition": 0, "Yposition": 1, "Zposition": 2}
_ROT = {"Xrotation": 0, "Yrotation": 1, "Zrotation": 2}
_MOTION_RE = re.compile(rb"^\s*MOTION\s*$", re.M)


@dataclass
class BvhData:
    """A parsed BVH file.

    ``names``/``parents``/``offsets`` ``[J, 3]`` cover every node, End Sites
    included (``is_end`` marks them). ``channels[j]`` lists joint j's channel
    names in file order; ``motion`` is float64 ``[T, C]`` with the columns in
    hierarchy order.
    """

    names: list[str]
    parents: np.ndarray
    offsets: np.ndarray
    channels: list[list[str]]
    motion: np.ndarray
    frame_time: float
    is_end: np.ndarray = field(default=None)  # type: ignore[assignment]

    def __post_init__(self) -> None:
        self.parents = np.asarray(self.parents, dtype=np.int64)
        self.offsets = np.asarray(self.offsets, dtype=np.float64).reshape(-1, 3)
        if self.is_end is None:
            self.is_end = np.zeros(len(self.names), dtype=bool)
        self.is_end = np.asarray(self.is_end, dtype=bool)

    @property
    def fps(self) -> float:
        return 1.0 / self.frame_time

    @property
    def num_frames(self) -> int:
        return int(self.motion.shape[0])

    @property
    def num_channels(self) -> int:
        return sum(len(c) for c in self.channels)

    def channel_offsets(self) -> np.ndarray:
        """Index of each joint's first column in ``motion``."""
        return np.concatenate([[0], np.cumsum([len(c) for c in self.channels])[:-1]]).astype(int)

    def positions(self, end_sites: bool = True, dtype=np.float32) -> np.ndarray:
        """World positions ``[T, J, 3]`` in file units (see :func:`forward_kinematics`)."""
        pos = forward_kinematics(self, dtype)
        return pos if end_sites else pos[:, ~self.is_end]

    def skeleton(self, end_sites: bool = True, scale: float = 1.0) -> Skeleton:
        keep = np.ones(len(self.names), bool) if end_sites else ~self.is_end
        idx = np.flatnonzero(keep)
        remap = -np.ones(len(self.names), dtype=np.int64)
        remap[idx] = np.arange(len(idx))
        parents = np.where(self.parents[idx] >= 0, remap[np.maximum(self.parents[idx], 0)], -1)
        return Skeleton(
            names=[self.names[i] for i in idx], parents=parents,
            offsets=(self.offsets[idx] * scale).astype(np.float32),
            end_sites=[self.names[i] for i in idx if self.is_end[i]],
        )

    def to_text(self, precision: int = 6) -> str:
        """Serialise to BVH text (spaces, LF)."""
        out: list[str] = ["HIERARCHY"]
        children: list[list[int]] = [[] for _ in self.names]
        for j, p in enumerate(self.parents):
            if p >= 0:
                children[p].append(j)

        def emit(j: int, depth: int) -> None:
            ind = "  " * depth
            if self.is_end[j]:
                out.append(f"{ind}End Site")
            else:
                out.append(f"{ind}{'ROOT' if self.parents[j] < 0 else 'JOINT'} {self.names[j]}")
            out.append(f"{ind}{{")
            o = self.offsets[j]
            out.append(f"{ind}  OFFSET {o[0]:.{precision}f} {o[1]:.{precision}f} {o[2]:.{precision}f}")
            if not self.is_end[j]:
                out.append(f"{ind}  CHANNELS {len(self.channels[j])} {' '.join(self.channels[j])}")
            for c in children[j]:
                emit(c, depth + 1)
            out.append(f"{ind}}}")

        for r in np.flatnonzero(self.parents < 0):
            emit(int(r), 0)
        out += ["MOTION", f"Frames: {self.num_frames}", f"Frame Time: {self.frame_time:.8f}"]
        buf = io.StringIO()
        np.savetxt(buf, self.motion, fmt=f"%.{precision}f", delimiter=" ")
        return "\n".join(out) + "\n" + buf.getvalue()


def parse_bvh(data: bytes | str, member: str = "<bvh>") -> BvhData:
    """Parse BVH bytes or text. Raises :class:`InputError` naming ``member`` on bad input."""
    raw = data.encode("latin-1") if isinstance(data, str) else data
    if not raw.strip():
        raise InputError(member, "empty file")
    m = _MOTION_RE.search(raw)
    if m is None:
        raise InputError(member, "no MOTION section (truncated or not a BVH file)")
    try:
        header = raw[: m.start()].decode("latin-1")
    except UnicodeDecodeError as e:  # pragma: no cover - latin-1 decodes any byte
        raise InputError(member, f"undecodable header: {e}") from e
    names, parents, offsets, channels, is_end = _parse_hierarchy(header, member)

    # MOTION: 'Frames: N', 'Frame Time: dt', then one row of floats per frame.
    body = raw[m.end():]
    lines = body.split(b"\n", 3)
    if len(lines) < 3:
        raise InputError(member, "truncated MOTION section (no Frames / Frame Time lines)")
    _, frames_line, time_line = lines[0], lines[1], lines[2]
    if lines[0].strip():  # MOTION followed by text on the same line is impossible with the regex
        raise InputError(member, "malformed MOTION header")
    n_frames = _header_number(frames_line, b"Frames:", member, int)
    frame_time = _header_number(time_line, b"Frame Time:", member, float)
    if n_frames <= 0:
        raise InputError(member, f"header declares {n_frames} frames")
    if not (frame_time > 0):
        raise InputError(member, f"non-positive Frame Time {frame_time}")
    n_ch = sum(len(c) for c in channels)
    rows = lines[3] if len(lines) > 3 else b""
    motion = _parse_rows(rows, n_ch, member, n_frames)
    if motion.shape[0] != n_frames:
        raise InputError(
            member, f"truncated: header declares {n_frames} frames, file holds {motion.shape[0]}")
    return BvhData(names, np.array(parents), np.array(offsets, dtype=np.float64),
                   channels, motion, frame_time, np.array(is_end))


def _header_number(line: bytes, key: bytes, member: str, typ):
    s = line.strip()
    if not s.startswith(key):
        raise InputError(member, f"expected '{key.decode()}' line, got {s[:40]!r}")
    try:
        return typ(s[len(key):].strip())
    except ValueError:
        raise InputError(member, f"non-numeric value in '{s.decode(errors='replace')[:60]}'") from None


# Below this size numpy's single-call text parser beats pandas, whose fixed cost
# per column dominates on short files (Bandai: ~150 frames x 132 channels).
_SMALL_MOTION_BYTES = 400_000


def _line_shape_ok(rows: bytes, n_ch: int, n_frames: int) -> bool:
    """Cheap structure check for the fast path: ``n_frames`` non-blank lines, the
    first and last of which hold ``n_ch`` tokens (the total count is checked by
    the caller, so a short or long line elsewhere would have to be exactly
    compensated by another to slip through)."""
    body = rows.strip()
    if body.count(b"\n") + 1 != n_frames:
        return False
    first = body[: body.find(b"\n")] if n_frames > 1 else body
    last = body[body.rfind(b"\n") + 1:]
    return len(first.split()) == n_ch and len(last.split()) == n_ch


def _parse_rows(rows: bytes, n_ch: int, member: str, n_frames: int) -> np.ndarray:
    """Frame rows to float64 ``[T, C]`` in one C-level pass (no Python loop over frames).

    Fast paths are trusted only when their result is exactly ``n_frames x n_ch``
    finite values; anything else is re-read by the strict path below, which
    also produces the precise error message.
    """
    if not rows.strip():
        return np.zeros((0, n_ch))
    if len(rows) < _SMALL_MOTION_BYTES:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # a bad token ends the parse early: caught by the count
                vals = np.fromstring(rows, dtype=np.float64, sep=" ")
        except ValueError:  # newer numpy raises on a bad token: the strict path explains it
            vals = np.zeros(0)
        if vals.size == n_frames * n_ch and np.isfinite(vals).all() and _line_shape_ok(rows, n_ch, n_frames):
            return vals.reshape(n_frames, n_ch)
    if b"\r" in rows:
        rows = rows.replace(b"\r", b"")
    if b"\t" in rows:
        rows = rows.replace(b"\t", b" ")
    # Single-space separated rows (the common case) take pandas' fastest path. Its
    # result is kept only when it is clean; anything irregular (double spaces,
    # padded lines, bad values) is re-read by the whitespace-regex path, which
    # also produces the precise error message.
    try:
        fast = pd.read_csv(io.BytesIO(rows), sep=" ", header=None, dtype=np.float64,
                           engine="c").to_numpy()
        if fast.shape[1] == n_ch and np.isfinite(fast).all():
            return fast
    except ValueError:
        pass
    try:
        df = pd.read_csv(io.BytesIO(rows), sep=r"\s+", header=None,
                         dtype=np.float64, engine="c", skip_blank_lines=True, na_filter=True)
    except ValueError as e:  # non-numeric token, or a row with too many values
        msg = str(e)
        found = re.search(r"Expected (\d+) fields in line (\d+), saw (\d+)", msg)
        if found:
            raise InputError(member, f"channel count does not match the hierarchy: frame "
                                     f"{int(found.group(2))} has {found.group(3)} values") from None
        raise InputError(member, f"non-numeric value in motion data ({msg.splitlines()[0][:80]})") from None
    motion = df.to_numpy(dtype=np.float64)
    if motion.shape[1] != n_ch:
        raise InputError(member, f"channel count does not match the hierarchy: frames have "
                                 f"{motion.shape[1]} values, hierarchy declares {n_ch} channels")
    bad = ~np.isfinite(motion).all(axis=1)
    if bad.any():
        first = int(np.flatnonzero(bad)[0])
        row = motion[first]
        k = int(np.argmax(np.isnan(row)))
        # A short row (pandas pads it with NaN) is a truncation, not a NaN frame.
        if np.isnan(row[-1]) and np.isnan(row[k:]).all() and np.isfinite(row[:k]).all():
            what = "truncated: last frame" if first == len(motion) - 1 else "channel count does not match the hierarchy: frame"
            raise InputError(member, f"{what} {first} has only {k} of {n_ch} values")
        raise InputError(member, f"NaN or Inf in {int(bad.sum())} frame(s), first at frame {first}")
    return motion


def _parse_hierarchy(header: str, member: str):
    toks = header.split()
    if not toks or toks[0] != "HIERARCHY":
        raise InputError(member, "missing HIERARCHY keyword")
    names: list[str] = []
    parents: list[int] = []
    offsets: list[list[float]] = []
    channels: list[list[str]] = []
    is_end: list[bool] = []
    stack: list[int] = []
    pending: int | None = None  # node declared, waiting for '{'
    i = 1
    n = len(toks)
    try:
        while i < n:
            t = toks[i]
            if t in ("ROOT", "JOINT", "End"):
                if t == "JOINT" and not stack:
                    raise InputError(member, "JOINT outside any ROOT")
                if t == "End" and (toks[i + 1] != "Site" or not stack):
                    raise InputError(member, "malformed End Site")
                names.append(f"{names[stack[-1]]}_End" if t == "End" else toks[i + 1])
                parents.append(stack[-1] if t != "ROOT" else -1)
                offsets.append([0.0, 0.0, 0.0])
                channels.append([])
                is_end.append(t == "End")
                pending = len(names) - 1
                i += 2
            elif t == "{":
                if pending is None:
                    raise InputError(member, "unexpected '{' in hierarchy")
                stack.append(pending)
                pending = None
                i += 1
            elif t == "}":
                if not stack:
                    raise InputError(member, "unbalanced '}' in hierarchy")
                stack.pop()
                i += 1
            elif t == "OFFSET":
                offsets[stack[-1]] = [float(x) for x in toks[i + 1: i + 4]]
                i += 4
            elif t == "CHANNELS":
                k = int(toks[i + 1])
                chans = toks[i + 2: i + 2 + k]
                unknown = [c for c in chans if c not in _POS and c not in _ROT]
                if len(chans) != k or unknown:
                    raise InputError(member, f"bad CHANNELS on joint {names[stack[-1]]!r}: {chans}")
                channels[stack[-1]] = chans
                i += 2 + k
            else:
                raise InputError(member, f"unexpected token {t!r} in hierarchy")
    except (IndexError, ValueError) as e:
        if isinstance(e, InputError):
            raise
        raise InputError(member, f"malformed hierarchy near token {i}: {e}") from None
    if stack or pending is not None:
        raise InputError(member, "truncated hierarchy: unbalanced braces")
    if not names:
        raise InputError(member, "hierarchy has no joints")
    if len(set(names)) != len(names):
        raise InputError(member, "duplicate joint names in hierarchy")
    return names, parents, offsets, channels, is_end


# ----------------------------------------------------------------------------- FK

def euler_to_matrix(angles_deg: np.ndarray, order: str) -> np.ndarray:
    """Rotation matrices for intrinsic Euler angles.

    ``angles_deg`` ``[..., 3]`` in the channel order ``order`` (e.g. ``"ZXY"``);
    returns ``[..., 3, 3]`` = ``R_order[0] @ R_order[1] @ R_order[2]``.
    """
    a = np.moveaxis(np.asarray(angles_deg), -1, 0)
    return np.moveaxis(_euler_cf(a, order), (0, 1), (-2, -1))


def _euler_cf(angles_deg: np.ndarray, order: str) -> np.ndarray:
    """Component-first Euler matrices: angles ``[3, ...]`` -> ``[3, 3, ...]``.

    Computed in the angles' dtype: float32 trigonometry is SIMD-vectorised in
    numpy and about 30x faster than float64, at ~1e-7 relative error.
    """
    a = np.deg2rad(angles_deg)
    c, s = np.cos(a), np.sin(a)
    out = _axis_cf(c[2], s[2], "XYZ".index(order[2]))
    for k in (1, 0):  # left-multiply by the sparse elemental rotations
        i, j = [(1, 2), (2, 0), (0, 1)]["XYZ".index(order[k])]
        ri, rj = out[i].copy(), out[j]
        out[i] = c[k] * ri - s[k] * rj
        out[j] = s[k] * ri + c[k] * rj
    return out


def _axis_cf(c: np.ndarray, s: np.ndarray, axis: int) -> np.ndarray:
    m = np.zeros((3, 3) + c.shape, dtype=c.dtype)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    m[axis, axis] = 1.0
    m[i, i] = c
    m[j, j] = c
    m[i, j] = -s
    m[j, i] = s
    return m


def _mul33(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Batched 3x3 product in component-first layout ``[3, 3, ...]``.

    Written out per entry: numpy's stacked ``matmul`` is several times slower
    for millions of tiny matrices than these 45 whole-array operations.
    """
    out = np.empty(np.broadcast_shapes(a.shape, b.shape), dtype=np.result_type(a, b))
    for i in range(3):
        for k in range(3):
            out[i, k] = a[i, 0] * b[0, k] + a[i, 1] * b[1, k] + a[i, 2] * b[2, k]
    return out


def local_transforms(bvh: BvhData, dtype=np.float32) -> tuple[np.ndarray, np.ndarray]:
    """Per-joint local rotations ``[3, 3, J, T]`` and translations ``[3, J, T]``
    (component-first layout, so each entry is one contiguous array)."""
    T, J = bvh.num_frames, len(bvh.names)
    motion_t = np.ascontiguousarray(bvh.motion.T, dtype=dtype)  # [C, T]
    rot = np.zeros((3, 3, J, T), dtype=dtype)
    for a in range(3):
        rot[a, a] = 1.0
    trans = np.repeat(bvh.offsets.T.astype(dtype)[:, :, None], T, axis=2)  # [3, J, T]
    starts = bvh.channel_offsets()
    groups: dict[str, tuple[list[int], list[list[int]]]] = {}
    for j, chans in enumerate(bvh.channels):
        for k, ch in enumerate(chans):
            if ch in _POS:
                trans[_POS[ch], j] = motion_t[starts[j] + k]
        rcols = [starts[j] + k for k, ch in enumerate(chans) if ch in _ROT]
        if rcols:
            order = "".join(ch[0] for ch in chans if ch in _ROT)
            if len(order) != 3:  # fewer than 3 rotation channels: pad with zero angles
                missing = [a for a in "XYZ" if a not in order]
                order += "".join(missing)
                rcols = rcols + [-1] * len(missing)
            g = groups.setdefault(order, ([], []))
            g[0].append(j)
            g[1].append(rcols)
    padded = np.concatenate([motion_t, np.zeros((1, T), dtype=dtype)], axis=0)  # row -1 = zero angle
    for order, (joints, cols) in groups.items():
        angles = padded[np.array(cols).T]  # [3, Jg, T]
        rot[:, :, joints] = _euler_cf(angles, order)
    return rot, trans


def forward_kinematics(bvh: BvhData, dtype=np.float32) -> np.ndarray:
    """World joint positions ``[T, J, 3]`` in file units, End Sites included.

    ``dtype`` float32 (default) is accurate to ~1e-6 relative, far below a
    millimetre on human-sized skeletons; pass float64 for reference checks."""
    rot, trans = local_transforms(bvh, dtype)
    return np.ascontiguousarray(chain(bvh.parents, rot, trans).transpose(2, 1, 0))


def chain(parents: np.ndarray, rot: np.ndarray, trans: np.ndarray) -> np.ndarray:
    """Compose local transforms down the hierarchy, one batched step per depth level.

    Component-first: ``rot`` ``[3, 3, J, T]``, ``trans`` ``[3, J, T]`` ->
    world positions ``[3, J, T]``.
    """
    depth = _depths(parents)
    g_rot = rot.copy()
    pos = trans.copy()
    for d in range(1, int(depth.max()) + 1):
        js = np.flatnonzero(depth == d)
        ps = parents[js]
        gp = g_rot[:, :, ps]
        t = trans[:, js]
        pos[:, js] = (gp[:, 0] * t[0] + gp[:, 1] * t[1] + gp[:, 2] * t[2]) + pos[:, ps]
        g_rot[:, :, js] = _mul33(gp, rot[:, :, js])
    return pos


def _depths(parents: np.ndarray) -> np.ndarray:
    depth = np.zeros(len(parents), dtype=np.int64)
    for j, p in enumerate(parents):  # over joints, not frames
        depth[j] = depth[p] + 1 if p >= 0 else 0
    return depth


# ----------------------------------------------------------------------- dataset reader

class BvhReader(DatasetReader):
    """A dataset of BVH files in one archive, labelled by JSON side-files or by folder.

    Parameters (from ``conf/dataset/<name>.yaml``, ``reader:`` section):

    pattern: members that are motions (``data/*.bvh``, ``*/*.bvh``).
    labels: ``json`` (a ``<stem>.json`` beside each motion holding ``content``/
        ``style`` indices into ``content_labels``/``style_labels``) or ``folder``
        (the first path component is the class).
    label_pattern: members that are labels (``json`` only); a label without a
        motion is rejected, a motion without its label too.
    content_labels / style_labels: text members, one name per line (0-based).
    label_prefix: stripped from label names (Bandai: ``dataset-1_``).
    classes: folder labels' classes, in label order; default the sorted folder names. A motion in
        another folder is filtered out (counted, not read).
    end_sites: keep End Sites as joints (CMU's 57 joints include them).
    scale: file units to metres.
    template: a member whose hierarchy is the dataset's skeleton (CMU: ``standard.bvh``).
    name_fields: split a stem on ``_`` into these meta fields (Bandai:
        ``[corpus, content, style, take]``).

    ``.bvh`` members that ``pattern`` does not match (the template aside) are filtered out.
    Class ids are the folder index or the label's ``content`` index; :meth:`classes` names
    those the archive's items carry (a label file without its motion included).
    """

    format_pattern = "**/*.bvh"

    def __init__(self, pattern: str, labels: str = "folder", label_pattern: str | None = None,
                 content_labels: str | None = None, style_labels: str | None = None,
                 label_prefix: str = "", classes: list[str] | None = None,
                 end_sites: bool = False, scale: float = 0.01, template: str | None = None,
                 name_fields: list[str] | None = None, subject_field: str | None = None):
        if labels not in ("json", "folder"):
            raise ValueError(f"reader.labels must be 'json' or 'folder', got {labels!r}")
        self.pattern, self.labels, self.label_pattern = pattern, labels, label_pattern
        self.content_labels, self.style_labels = content_labels, style_labels
        self.label_prefix, self.classes = label_prefix, classes
        self.end_sites, self.scale, self.template = end_sites, float(scale), template
        self.name_fields = list(name_fields or [])
        self.subject_field = subject_field
        self._names: dict[str, list[str]] = {}
        self._labels: dict[str, tuple[int, int] | InputError] = {}  # label member -> (content, style)
        self._fps: dict[str, list[float]] = {}  # header fps per class, for notes()

    # -- items
    def list_items(self, archive: Archive) -> tuple[list[Item], list[Rejected]]:
        motions = archive.glob(self.pattern)
        rejected: list[Rejected] = []
        if self.labels == "folder":
            classes = self.classes or sorted({m.split("/")[0] for m in motions if "/" in m})
            items = []
            for m in motions:
                folder = m.split("/")[0] if "/" in m else ""
                key = str(PurePosixPath(m).with_suffix("")).replace("/", "_")
                if folder not in classes:
                    if not self.classes:  # a motion outside any class folder
                        rejected.append(Rejected(m, f"class folder {folder!r} is not one of {classes}"))
                    continue  # else a folder the config leaves out: filtered (why_filtered)
                items.append(Item(key, {"motion": m}, {"label": classes.index(folder), "label_name": folder}))
            return items, rejected
        labels = archive.glob(self.label_pattern or "")
        stem = lambda n: str(PurePosixPath(n).with_suffix(""))  # noqa: E731
        by_stem: dict[str, dict[str, str]] = {}
        for m in motions:
            by_stem.setdefault(stem(m), {})["motion"] = m
        for lab in labels:
            by_stem.setdefault(stem(lab), {})["label"] = lab
        items = []
        for s, members in sorted(by_stem.items()):
            if "motion" not in members:
                rejected.append(Rejected(members["label"], "label without a motion file "
                                         f"({PurePosixPath(s).name}.bvh is missing)"))
            elif "label" not in members:
                rejected.append(Rejected(members["motion"], "motion file without its label .json"))
            else:
                items.append(Item(PurePosixPath(s).name, members, self._name_meta(PurePosixPath(s).name)))
        return items, rejected

    def _name_meta(self, stem: str) -> dict:
        if not self.name_fields:
            return {}
        parts = stem.split("_")
        if len(parts) != len(self.name_fields):
            return {}
        meta = dict(zip(self.name_fields, parts))
        if self.subject_field:
            meta["subject"] = meta.get(self.subject_field, "")
        return meta

    def _label_names(self, archive: Archive, member: str | None) -> list[str]:
        if member is None:
            return []
        if member not in self._names:
            lines = [ln.strip() for ln in archive.text(member).splitlines() if ln.strip()]
            self._names[member] = [ln[len(self.label_prefix):] if ln.startswith(self.label_prefix) else ln
                                   for ln in lines]
        return self._names[member]

    # -- reading
    def read(self, archive: Archive, item: Item) -> tuple[Sequence, Skeleton]:
        member = item.members["motion"]
        bvh = parse_bvh(archive.read(member), member)
        meta = {"member": member, **item.meta}
        if self.labels == "json":
            meta.update(self._read_label(archive, item.members["label"]))
        pos = bvh.positions(end_sites=self.end_sites) * self.scale
        seq = Sequence(pos.astype(np.float32), bvh.fps, meta)
        self._fps.setdefault(str(meta.get("label_name", "")), []).append(round(bvh.fps, 3))
        return seq, bvh.skeleton(end_sites=self.end_sites, scale=self.scale)

    def _label(self, archive: Archive, member: str) -> tuple[int, int]:
        """``(content, style)`` of a label file (parsed once: :meth:`classes` reads them all)."""
        import json

        if member not in self._labels:
            try:
                lab = json.loads(archive.text(member))
                self._labels[member] = (int(lab["content"]), int(lab["style"]))
            except InputError as e:
                self._labels[member] = e
            except (ValueError, KeyError, TypeError) as e:
                self._labels[member] = InputError(member, f"malformed label JSON: {e}")
        got = self._labels[member]
        if isinstance(got, InputError):
            raise got
        return got

    def _read_label(self, archive: Archive, member: str) -> dict:
        content, style = self._label(archive, member)
        contents = self._label_names(archive, self.content_labels)
        styles = self._label_names(archive, self.style_labels)
        if contents and not 0 <= content < len(contents):
            raise InputError(member, f"content index {content} outside the {len(contents)} labels")
        if styles and not 0 <= style < len(styles):
            raise InputError(member, f"style index {style} outside the {len(styles)} labels")
        return {"label": content, "label_name": contents[content] if contents else str(content),
                "style": styles[style] if styles else str(style), "style_id": style}

    def auxiliary_members(self) -> set[str]:
        return {self.template} if self.template else set()

    def why_filtered(self, member: str) -> str:
        folder = member.split("/")[0] if "/" in member else ""
        if self.labels == "folder" and self.classes and matches(member, self.pattern) and folder not in self.classes:
            return f"class folder {folder!r} is not in reader.classes"
        return super().why_filtered(member)

    def class_names(self, archive: Archive, items: list[Item]) -> dict[int, str]:
        """Folder labels: the listed items' classes. JSON labels: the content of every label file
        ``label_pattern`` matches, with or without its motion (unreadable ones are left to ``read``)."""
        if self.labels == "folder":
            return super().class_names(archive, items)
        try:
            names = self._label_names(archive, self.content_labels)
        except InputError:
            names = []
        out: dict[int, str] = {}
        for member in archive.glob(self.label_pattern or ""):
            try:
                content = self._label(archive, member)[0]
            except InputError:
                continue
            if not names or 0 <= content < len(names):
                out[content] = names[content] if names else str(content)
        return out

    def notes(self, archive: Archive) -> list[str]:
        """Frame-rate statements in text members, checked against the BVH headers read."""
        notes = []
        for name in sorted(set(archive.glob("*.txt") + archive.glob("readme*"))):
            for cls, rate in re.findall(r"(\w+)\s+framerate\s+(\d+(?:\.\d+)?)", archive.text(name), flags=re.I):
                headers = sorted(set(self._fps.get(cls, [])))
                if not headers:
                    continue
                n = len(self._fps[cls])
                if any(abs(h - float(rate)) > 0.01 for h in headers):
                    notes.append(f"frame-rate conflict: {name} says {cls} is {rate} fps, but the BVH "
                                 f"headers of its {n} files say {', '.join(f'{h:g}' for h in headers)} fps; "
                                 f"the header is used")
                else:
                    notes.append(f"{name} says {cls} is {rate} fps, in agreement with its {n} BVH headers")
        return notes

    def template_skeleton(self, archive: Archive) -> Skeleton | None:
        if not self.template:
            return None
        return parse_bvh(archive.read(self.template), self.template).skeleton(self.end_sites, self.scale)
