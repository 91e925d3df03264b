"""Human3.6M 3-D joint positions and cameras, read in place from the 3d-pose-baseline ``h36m.zip``.

Layout (see ``/work/shared/datasets/README.md``, section ``h36m.zip``)::

    h36m/S{1,5,6,7,8,9,11}/MyPoses/3D_positions/{Action}[ N].h5   dataset 3D_positions, (96, T) float64
    h36m/cameras.h5                                              subject{s}/camera{c}/{R,T,f,c,k,p,Name}

``3D_positions`` holds 32 joints x xyz in millimetres, world coordinates, 50 Hz;
column ``t`` is frame ``t`` and row ``3 * j + d`` is coordinate ``d`` of joint ``j``.

Conventions of this reader:

* Only the configured joints are kept (17 by default, hip first), in the configured order.
* ``Sequence.positions`` is in metres in the project's frame (Y up, right-handed).
  The H36M world frame is Z up, so ``(x, y, z)_h36m -> (x, z, -y)``: a rotation of
  -90 degrees about X (determinant +1), handedness is preserved.
* ``Sequence.views2d`` float32 ``[T, 4, J, 2]``: the ORIGINAL world millimetre
  coordinates projected through the subject's cameras 1..4 (always that order), in
  pixels, with the distortion model of 3d-pose-baseline (:func:`project_point_radial`).
* ``seq.view_depth`` float32 ``[T, 4]``: camera-space depth (metres) of the hip (the
  first configured joint) in each of the 4 views. It is set as an attribute after
  construction, because :class:`~motionsynth.data.types.Sequence` has no field for it.
* ``cameras.h5`` stores ``R`` transposed: the world-to-camera rotation is ``R.T`` of the
  stored matrix (as 3d-pose-baseline's ``load_camera_params`` does). :func:`load_cameras`
  returns the world-to-camera matrix, ready for :func:`project_point_radial`.
* Skeleton offsets (metres, Y up) are a rest-pose estimate: the mean bone vector
  (child - parent) over all frames of one reference sequence per subject, the
  subject's first readable item in the reader's sorted item order. So every sequence of
  a subject gets the same skeleton, whichever order the items are read in.

Licence: Human3.6M is for research use only; keep it inside the team, never publish it.
"""

from __future__ import annotations

import io
import re
from collections.abc import Mapping
from pathlib import PurePosixPath
from typing import Any

import numpy as np

from .archive import Archive, matches
from .readers import DatasetReader
from .types import InputError, Item, Rejected, Sequence, Skeleton

#: The 10 actions of the c-SkeletonGAN / SA-GCN / GlocalNet 2-D benchmark.
H36M_ACTIONS = ["Directions", "Discussion", "Eating", "Greeting", "Phoning",
                "Posing", "Sitting", "SittingDown", "Smoking", "Walking"]

#: The 17 meaningful joints of the 32 stored, by source index (hip first).
H36M_JOINTS: dict[int, str] = {
    0: "Hip", 1: "RHip", 2: "RKnee", 3: "RFoot", 6: "LHip", 7: "LKnee", 8: "LFoot",
    12: "Spine", 13: "Thorax", 14: "Neck/Nose", 15: "Head",
    17: "LShoulder", 18: "LElbow", 19: "LWrist", 25: "RShoulder", 26: "RElbow", 27: "RWrist",
}

#: Parent of each joint of :data:`H36M_JOINTS` (the hip is the root).
H36M_PARENTS: dict[str, str] = {
    "RHip": "Hip", "RKnee": "RHip", "RFoot": "RKnee",
    "LHip": "Hip", "LKnee": "LHip", "LFoot": "LKnee",
    "Spine": "Hip", "Thorax": "Spine", "Neck/Nose": "Thorax", "Head": "Neck/Nose",
    "LShoulder": "Thorax", "LElbow": "LShoulder", "LWrist": "LElbow",
    "RShoulder": "Thorax", "RElbow": "RShoulder", "RWrist": "RElbow",
}

NUM_SOURCE_JOINTS = 32
NUM_CAMERAS = 4
CAMERA_IDS = (1, 2, 3, 4)
DATASET = "3D_positions"
MM_TO_M = 1e-3

# world (Z up, mm) -> project (Y up): new = old @ _ZUP_TO_YUP.T, i.e. (x, y, z) -> (x, z, -y)
_ZUP_TO_YUP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])

_SUBJECT_RE = re.compile(r"^S(\d+)$")
_STEM_RE = re.compile(r"^(?P<action>.+?)(?: (?P<trial>\d+))?$")
_CAM_FIELDS = {"R": 9, "T": 3, "f": 2, "c": 2, "k": 3, "p": 2}


# ----------------------------------------------------------------------------- camera model

def project_point_radial(P, R, T, f, c, k, p) -> tuple[np.ndarray, np.ndarray]:
    """Project world points through one camera with radial and tangential distortion.

    The camera model of 3d-pose-baseline's ``cameras.project_point_radial``, vectorised
    over any leading shape. With ``p1, p2 = p`` and ``k1, k2, k3 = k``::

        X       = R @ (P - T)                      # camera frame
        x, y    = X[0] / X[2], X[1] / X[2]         # normalised image plane
        r2      = x**2 + y**2
        radial  = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
        tan     = p1 * y + p2 * x
        x'      = x * (radial + tan) + p2 * r2
        y'      = y * (radial + tan) + p1 * r2
        u, v    = fx * x' + cx, fy * y' + cy       # pixels

    (This is that code's formula, which differs from OpenCV's Brown-Conrady tangential
    term; it is reproduced as is so that 2-D data matches the published benchmarks.)

    Args:
        P: ``[..., 3]`` world points (millimetres or metres; ``T`` in the same unit).
        R: ``[3, 3]`` world-to-camera rotation (for ``cameras.h5``: the transpose of the
            stored matrix; :func:`load_cameras` returns it already transposed).
        T: ``[3]`` (or ``[3, 1]``) camera centre in world coordinates.
        f: ``[2]`` (or ``[2, 1]``, or a scalar) focal lengths in pixels.
        c: ``[2]`` (or ``[2, 1]``) principal point in pixels.
        k: ``[3]`` radial distortion coefficients.
        p: ``[2]`` tangential distortion coefficients.

    Returns:
        ``(uv, depth)``: ``uv`` ``[..., 2]`` pixel coordinates and ``depth`` ``[...]`` the
        camera-space ``Z`` (in the unit of ``P``).
    """
    P = np.asarray(P, dtype=np.float64)
    R = np.asarray(R, dtype=np.float64).reshape(3, 3)
    T = np.asarray(T, dtype=np.float64).reshape(3)
    f = np.broadcast_to(np.asarray(f, dtype=np.float64).reshape(-1), (2,))
    c = np.asarray(c, dtype=np.float64).reshape(2)
    k1, k2, k3 = np.asarray(k, dtype=np.float64).reshape(3)
    p1, p2 = np.asarray(p, dtype=np.float64).reshape(2)
    if P.shape[-1] != 3:
        raise ValueError(f"points must be [..., 3], got shape {P.shape}")
    lead = P.shape[:-1]
    # one BLAS product on [3, N] keeps each coordinate contiguous (much faster than a
    # broadcast [..., 3] @ [3, 3] matmul)
    X = R @ (P.reshape(-1, 3) - T).T
    depth = X[2]
    x = X[0] / depth
    y = X[1] / depth
    r2 = x * x + y * y
    radial_tan = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3)) + (p1 * y + p2 * x)
    uv = np.empty((x.size, 2), dtype=np.float64)
    uv[:, 0] = f[0] * (x * radial_tan + p2 * r2) + c[0]
    uv[:, 1] = f[1] * (y * radial_tan + p1 * r2) + c[1]
    return uv.reshape(*lead, 2), depth.reshape(lead)


def load_cameras(archive_or_bytes: Archive | bytes, member: str = "h36m/cameras.h5"
                 ) -> dict[tuple[int, int], dict[str, Any]]:
    """Read ``cameras.h5`` (from an :class:`Archive`, or its raw bytes).

    Returns ``{(subject, camera): {"R", "T", "f", "c", "k", "p", "name"}}`` with
    ``subject`` an int (1, 5, ...) and ``camera`` an int in 1..4. Arrays are float64:
    ``R`` ``[3, 3]`` world-to-camera (the stored matrix transposed, as 3d-pose-baseline
    does), ``T`` ``[3]`` camera centre (mm, world), ``f``/``c`` ``[2]`` pixels,
    ``k`` ``[3]``, ``p`` ``[2]``; ``name`` is the camera serial, e.g. ``"54138969"``.
    Groups other than ``subject<N>`` (the file has a ``3dtest`` entry) are ignored.

    Raises :class:`InputError` naming ``member`` when it is missing or corrupt.
    """
    import h5py

    if isinstance(archive_or_bytes, (bytes, bytearray, memoryview)):
        data = bytes(archive_or_bytes)
    else:
        if member not in getattr(archive_or_bytes, "names", [member]):
            raise InputError(member, "camera file missing from the archive")
        data = archive_or_bytes.read(member)
    cams: dict[tuple[int, int], dict[str, Any]] = {}
    try:
        with h5py.File(io.BytesIO(data), "r") as hf:
            for sname in hf.keys():
                ms = re.fullmatch(r"subject(\d+)", sname)
                if not ms or not isinstance(hf[sname], h5py.Group):
                    continue
                for cname in hf[sname].keys():
                    mc = re.fullmatch(r"camera(\d+)", cname)
                    if not mc:
                        continue
                    cams[(int(ms.group(1)), int(mc.group(1)))] = _camera(hf[sname][cname], f"{sname}/{cname}",
                                                                         member)
    except InputError:
        raise
    except (OSError, ValueError, KeyError, TypeError, RuntimeError) as e:
        raise InputError(member, f"not a readable HDF5 camera file: {e}") from None
    if not cams:
        raise InputError(member, "no subject<N>/camera<M> groups in the camera file")
    return dict(sorted(cams.items()))


def _camera(group, path: str, member: str) -> dict[str, Any]:
    import h5py

    out: dict[str, Any] = {}
    for key, n in _CAM_FIELDS.items():
        if key not in group or not isinstance(group[key], h5py.Dataset):
            raise InputError(member, f"{path}/{key} is missing")
        arr = np.asarray(group[key][()], dtype=np.float64)
        if arr.size != n:
            raise InputError(member, f"{path}/{key} must hold {n} values, got shape {arr.shape}")
        if not np.isfinite(arr).all():
            raise InputError(member, f"{path}/{key} holds NaN or Inf")
        out[key] = arr.reshape(3, 3).T.copy() if key == "R" else arr.reshape(n)
    if "Name" not in group:
        raise InputError(member, f"{path}/Name is missing")
    codes = np.asarray(group["Name"][()]).reshape(-1)
    try:
        out["name"] = "".join(chr(int(x)) for x in codes)
    except (ValueError, OverflowError, TypeError) as e:
        raise InputError(member, f"{path}/Name is not a string of character codes: {e}") from None
    return out


# ----------------------------------------------------------------------------- reader

class H36MReader(DatasetReader):
    """Human3.6M 3-D positions (the 3d-pose-baseline layout), with 4-view 2-D projections.

    Parameters (from ``conf/dataset/h36m.yaml``, ``reader:`` section):

    actions: the actions that are items, in label order (label = index here). Files of
        other actions are not items: they are counted as filtered out. The action is the file
        stem without an optional trailing ``" N"`` and must equal a name here exactly
        (``WalkDog`` is not ``Walking``).
    joints: source joint index (0..31) -> name, in the kept order; the first is the root.
        Default :data:`H36M_JOINTS`.
    parents: joint name -> parent name; a joint without an entry is a root. Every parent
        must come before its child in ``joints``. Default :data:`H36M_PARENTS`.
    subjects: subject numbers to keep (default: every ``S<N>`` folder); others are filtered out.
    pattern: archive members that are motions (other ``.h5`` members but the cameras: filtered out).
    cameras_member: the ``cameras.h5`` member.
    fps: frame rate of the source (50 Hz).
    """

    expected_trials = 2
    format_pattern = "**/*.h5"

    def __init__(self, actions: list[str], joints: Mapping[int, str] | None = None,
                 parents: Mapping[str, str] | None = None, subjects: list[int] | None = None,
                 pattern: str = "h36m/S*/MyPoses/3D_positions/*.h5",
                 cameras_member: str = "h36m/cameras.h5", fps: float = 50.0):
        self.actions = [str(a) for a in actions]
        if not self.actions:
            raise ValueError("reader.actions must list at least one action")
        if len(set(self.actions)) != len(self.actions):
            raise ValueError(f"reader.actions has duplicates: {self.actions}")
        joints = H36M_JOINTS if joints is None else joints
        self.joints = {int(i): str(n) for i, n in joints.items()}
        self.source_index = np.array(list(self.joints), dtype=np.int64)
        self.names = list(self.joints.values())
        if not self.names:
            raise ValueError("reader.joints must name at least one joint")
        bad = [i for i in self.source_index if not 0 <= i < NUM_SOURCE_JOINTS]
        if bad:
            raise ValueError(f"reader.joints: source indices {bad} outside 0..{NUM_SOURCE_JOINTS - 1}")
        if len(set(self.names)) != len(self.names):
            raise ValueError(f"reader.joints: duplicate joint names {self.names}")
        parents = H36M_PARENTS if parents is None else parents
        self.parent_names = {str(c): str(p) for c, p in parents.items()}
        unknown = sorted(set(self.parent_names) - set(self.names))
        if unknown:
            raise ValueError(f"reader.parents names joints not in reader.joints: {unknown}")
        pidx = []
        for j, name in enumerate(self.names):
            par = self.parent_names.get(name)
            if par is None:
                pidx.append(-1)
                continue
            if par not in self.names:
                raise ValueError(f"reader.parents: parent {par!r} of {name!r} is not a kept joint")
            if self.names.index(par) >= j:
                raise ValueError(f"reader.joints: parent {par!r} must come before its child {name!r}")
            pidx.append(self.names.index(par))
        self.parents = np.array(pidx, dtype=np.int64)
        self.subjects = None if subjects is None else sorted(int(s) for s in subjects)
        self.pattern = str(pattern)
        self.cameras_member = str(cameras_member)
        self.fps = float(fps)
        if not self.fps > 0:
            raise ValueError(f"reader.fps must be positive, got {fps}")
        self._cams: dict[tuple, dict[tuple[int, int], dict[str, Any]]] = {}
        self._items: dict[tuple, list[Item]] = {}
        self._rest: dict[tuple, np.ndarray] = {}

    # -- items
    def _parse(self, member: str) -> tuple[int, str, str] | str:
        """``(subject_id, action, trial)``; a string says why the name is unusable."""
        parts = PurePosixPath(member).parts
        sids = [int(m.group(1)) for m in map(_SUBJECT_RE.match, parts[:-1]) if m]
        if not sids:
            return "no subject folder S<N> in the member path"
        m = _STEM_RE.match(PurePosixPath(member).stem)
        if not m:
            return "file name is not '<Action>[ N].h5'"
        return sids[0], m.group("action"), m.group("trial") or ""

    def list_items(self, archive: Archive) -> tuple[list[Item], list[Rejected]]:
        items: list[Item] = []
        rejected: list[Rejected] = []
        for member in archive.glob(self.pattern):
            parsed = self._parse(member)
            if isinstance(parsed, str):
                rejected.append(Rejected(member, parsed))
                continue
            sid, action, trial = parsed
            if action not in self.actions:
                continue  # another action: not an item of this dataset
            if self.subjects is not None and sid not in self.subjects:
                continue
            key = f"S{sid}_{action}" + (f"_{trial}" if trial else "")
            items.append(Item(key, {"motion": member}, {
                "subject": f"S{sid}", "subject_id": sid, "action": action, "label_name": action,
                "label": self.actions.index(action), "trial": trial, "view": "all", "member": member,
            }))
        items.sort(key=lambda it: (it.meta["subject_id"], it.meta["label"],
                                   int(it.meta["trial"]) if it.meta["trial"] else -1, it.member))
        return items, rejected

    def auxiliary_members(self) -> set[str]:
        return {self.cameras_member}

    def why_filtered(self, member: str) -> str:
        parsed = self._parse(member) if matches(member, self.pattern) else None
        if parsed is None or isinstance(parsed, str):
            return super().why_filtered(member)
        sid, action, _ = parsed
        if action not in self.actions:
            return f"action {action!r} is not in reader.actions"
        return f"subject S{sid} is not in reader.subjects"

    def _cached_items(self, archive: Archive) -> list[Item]:
        key = _archive_key(archive)
        if key not in self._items:
            self._items[key] = self.list_items(archive)[0]
        return self._items[key]

    def cameras(self, archive: Archive) -> dict[tuple[int, int], dict[str, Any]]:
        """The archive's cameras (cached per archive), as :func:`load_cameras` returns them."""
        key = _archive_key(archive)
        if key not in self._cams:
            self._cams[key] = load_cameras(archive, self.cameras_member)
        return self._cams[key]

    # -- reading
    def read_world_mm(self, archive: Archive, member: str) -> np.ndarray:
        """The kept joints of one member in source world coordinates: float64 ``[T, J, 3]``, mm, Z up.

        Raises :class:`InputError` naming ``member`` on any bad input.
        """
        import h5py

        data = archive.read(member)
        try:
            with h5py.File(io.BytesIO(data), "r") as hf:
                if DATASET not in hf:
                    raise InputError(member, f"no dataset {DATASET!r} in the HDF5 file "
                                             f"(found {sorted(hf.keys())})")
                ds = hf[DATASET]
                if not isinstance(ds, h5py.Dataset):
                    raise InputError(member, f"{DATASET!r} is a group, not a dataset")
                if ds.ndim != 2 or ds.shape[0] != 3 * NUM_SOURCE_JOINTS:
                    raise InputError(member, f"{DATASET!r} must be (96, T) = 32 joints x xyz, "
                                             f"got shape {ds.shape}")
                if ds.shape[1] == 0:
                    raise InputError(member, f"{DATASET!r} has no frames")
                if ds.dtype.kind not in "fiu":
                    raise InputError(member, f"{DATASET!r} is not numeric (dtype {ds.dtype})")
                raw = np.asarray(ds[()], dtype=np.float64)
        except InputError:
            raise
        except (OSError, ValueError, KeyError, TypeError, RuntimeError) as e:
            raise InputError(member, f"not a readable HDF5 file: {e}") from None
        pos = raw.T.reshape(raw.shape[1], NUM_SOURCE_JOINTS, 3)[:, self.source_index]
        finite = np.isfinite(pos).reshape(pos.shape[0], -1).all(1)
        if not finite.all():
            bad = np.flatnonzero(~finite)
            raise InputError(member, f"NaN or Inf in {len(bad)} frame(s) of {DATASET!r}, "
                                     f"first at frame {bad[0]}")
        return pos

    @staticmethod
    def to_project_frame(world_mm: np.ndarray) -> np.ndarray:
        """Source world (mm, Z up) -> project frame (m, Y up): ``(x, y, z) -> (x, z, -y) / 1000``."""
        out = world_mm[..., [0, 2, 1]] * MM_TO_M  # same as (world_mm @ _ZUP_TO_YUP.T) / 1000
        out[..., 2] *= -1.0
        return out

    def read(self, archive: Archive, item: Item) -> tuple[Sequence, Skeleton]:
        member = item.members["motion"]
        parsed = self._parse(member)
        if isinstance(parsed, str):
            raise InputError(member, parsed)
        sid = parsed[0]
        world = self.read_world_mm(archive, member)
        cams = self.cameras(archive)
        missing = [c for c in CAMERA_IDS if (sid, c) not in cams]
        if missing:
            raise InputError(member, f"no parameters for S{sid} camera(s) {missing} in {self.cameras_member}")
        T, J = world.shape[:2]
        views = np.empty((T, NUM_CAMERAS, J, 2), dtype=np.float32)
        depth = np.empty((T, NUM_CAMERAS), dtype=np.float32)
        for v, cid in enumerate(CAMERA_IDS):
            cam = cams[(sid, cid)]
            uv, d = project_point_radial(world, cam["R"], cam["T"], cam["f"], cam["c"], cam["k"], cam["p"])
            views[:, v] = uv
            depth[:, v] = d[:, 0] * MM_TO_M
        if not (np.isfinite(views).all() and (depth > 0).all()):
            raise InputError(member, "joints behind or on the plane of a camera: projection undefined")
        positions = self.to_project_frame(world)
        meta = {"sequence_id": item.key, **item.meta, "member": member}
        seq = Sequence(positions.astype(np.float32), self.fps, meta, views2d=views)
        seq.view_depth = depth
        return seq, self._skeleton(self._subject_offsets(archive, item, sid, positions))

    def _subject_offsets(self, archive: Archive, item: Item, sid: int, positions: np.ndarray) -> np.ndarray:
        """Rest offsets of subject ``sid``: mean bone vectors of its first readable item."""
        key = (_archive_key(archive), sid)
        if key in self._rest:
            return self._rest[key]
        for ref in (it for it in self._cached_items(archive) if it.meta["subject_id"] == sid):
            if ref.member == item.members["motion"]:
                pos = positions
            else:
                try:
                    pos = self.to_project_frame(self.read_world_mm(archive, ref.member))
                except InputError:
                    continue
            self._rest[key] = self._mean_offsets(pos)
            return self._rest[key]
        return self._mean_offsets(positions)  # an item outside list_items: its own frames

    def _mean_offsets(self, positions: np.ndarray) -> np.ndarray:
        has = self.parents >= 0
        off = np.zeros((len(self.names), 3), dtype=np.float64)
        off[has] = (positions[:, has] - positions[:, self.parents[has]]).mean(axis=0)
        return off.astype(np.float32)

    def _skeleton(self, offsets: np.ndarray) -> Skeleton:
        names = set(self.names)
        pair = lambda a, b: (a, b) if {a, b} <= names else None  # noqa: E731
        roots = [n for n, p in zip(self.names, self.parents) if p < 0]
        return Skeleton(
            names=list(self.names), parents=self.parents.copy(), offsets=offsets,
            root="Hip" if "Hip" in names else roots[0],
            hips=pair("LHip", "RHip"), shoulders=pair("LShoulder", "RShoulder"),
            feet=[f for f in ("LFoot", "RFoot") if f in names],
        )

    # -- dataset-level
    def _archive_subjects(self, archive: Archive) -> list[int]:
        sids = set()
        for member in archive.glob(self.pattern):
            parsed = self._parse(member)
            if not isinstance(parsed, str):
                sids.add(parsed[0])
        if self.subjects is not None:
            sids &= set(self.subjects)
        return sorted(sids)

    def extras(self, archive: Archive) -> dict[str, Any]:
        """Camera parameters of the archive's subjects, JSON-serialisable.

        ``{"cameras": {"S1": {"1": {"name", "R", "T", "f", "c", "k", "p"}, ...}, ...},
        "camera_model": ...}``; ``R`` is world-to-camera, ``T`` the camera centre in mm.
        """
        cams = self.cameras(archive)
        out: dict[str, dict[str, dict[str, Any]]] = {}
        for sid in self._archive_subjects(archive):
            for cid in CAMERA_IDS:
                cam = cams.get((sid, cid))
                if cam is None:
                    continue
                out.setdefault(f"S{sid}", {})[str(cid)] = {
                    "name": cam["name"], **{k: cam[k].tolist() for k in ("R", "T", "f", "c", "k", "p")}}
        return {"cameras": out,
                "camera_model": "3d-pose-baseline project_point_radial; R world-to-camera "
                                "(cameras.h5 stores its transpose), T camera centre in world mm, "
                                "f/c pixels, k radial, p tangential; views2d from world mm (Z up)"}

    def notes(self, archive: Archive) -> list[str]:
        """A note for each (subject, action) that lacks the expected 2 trials."""
        items = self.list_items(archive)[0]
        found: dict[tuple[int, str], list[str]] = {}
        for it in items:
            found.setdefault((it.meta["subject_id"], it.meta["action"]), []).append(
                PurePosixPath(it.member).stem)
        notes = []
        for sid in self._archive_subjects(archive):
            for action in self.actions:
                present = found.get((sid, action), [])
                n, want = len(present), self.expected_trials
                if n != want:
                    note = f"S{sid} {action}: {n} trial(s) present, {want} expected"
                    note += f" ({want - n} missing in source)" if n < want else " (extra trials kept)"
                    if present:
                        note += f"; present: {', '.join(repr(p) for p in present)}"
                    notes.append(note)
        return notes


def _archive_key(archive: Archive) -> tuple:
    path = getattr(archive, "path", None)
    try:
        st = path.stat()
        return (str(path.resolve()), st.st_mtime_ns, st.st_size)
    except (AttributeError, OSError):
        return (id(archive),)
