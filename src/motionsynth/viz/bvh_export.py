"""BVH export of joint positions (generated motion) onto a source skeleton.

Animation tools want joint *rotations* on a fixed skeleton; the models generate
joint *positions*. :func:`positions_to_bvh` solves the rotations from positions
and returns a :class:`~motionsynth.data.bvh.BvhData` whose ``to_text()`` is a
BVH file that reads back (through :func:`~motionsynth.data.bvh.parse_bvh`) to
the input positions, with the skeleton's bone lengths.

File layout
    * Hierarchy and OFFSETs from the :class:`~motionsynth.data.types.Skeleton`
      (metres) times ``scale``, so bone lengths are the skeleton's whatever the
      input's. Write the *source file's* units so the export overlays the
      original in an animation tool: the BVH datasets here are read with
      ``reader.scale: 0.01`` (centimetres -> metres), so pass
      ``scale=dataset_scale(cfg) == 100``; the default ``1.0`` writes metres.
    * Every root: 6 channels, ``Xposition Yposition Zposition`` then the three
      rotations. Joints named in ``translate``: the same 6 channels (their
      position channels hold the local translation, which replaces the OFFSET,
      as in the source Bandai files). Every other joint: 3 rotation channels.
    * One Euler order for all joints, ``order`` (default ``ZXY``, the order of
      every Bandai joint and every CMU joint but the root), listed in channel
      order and composed intrinsically, ``R = R_Z @ R_X @ R_Y`` for ``ZXY``:
      the convention of the reader and of Blender's importer.
    * Skeleton End Sites (``skeleton.end_sites``) become ``End Site`` blocks
      (no channels). A leaf joint that is not an End Site gets a zero-length
      ``End Site`` (``leaf_end_sites=True``), as the Bandai sources have, so the
      file is valid for importers that expect every chain to end in one.
    * Joints are written in depth-first order (the order the motion columns
      must follow), which need not be the skeleton's order; map by name.

Solving rotations (batched over frames; the only Python loop is over joints,
in hierarchy order, so each parent's global rotation ``G_p`` is known)
    A joint's *informative children* are its children with a non-zero rest
    OFFSET that are not in ``translate``. With ``o_c`` the child's rest offset
    and ``u_c = G_p^T (x_c - x_j)`` the observed bone in the parent's frame, the
    joint's local rotation ``L_j`` maps the rest offsets onto the observed
    directions; then ``G_j = G_p @ L_j`` (so ``L_j = G_p^T @ G_j``).

    * No informative child (a leaf, a zero-length End Site only, or children
      that are all translated): ``L_j = I``, the joint inherits its parent's
      orientation (its rotation moves no point of the skeleton).
    * One informative child (or several, all parallel at rest): the minimal
      ("swing") rotation taking ``o_c`` onto ``u_c``. Twist convention: zero
      twist relative to the parent, i.e. the shortest arc in the parent's frame;
      twist about a single bone is not observable from positions.
    * Several non-parallel children (hips, chest, head with eyes, hands with
      fingers): the best-fit proper rotation (Kabsch: SVD of
      ``sum_c o_c (|o_c| u_c/|u_c|)^T``, reflection removed so det = +1).
    * An observed bone of zero length carries no direction: it is left out of
      the fit (a lone one gives ``L_j = I``).

    Positions are then rebuilt down the chain from the root position and the
    skeleton's OFFSETs, so each bone keeps its observed *direction* and the
    skeleton's *length*. On positions that came from a BVH with these OFFSETs
    the result is exact (to float64 rounding and the text's 6 decimals).

Euler angles are extracted from the matrices in one vectorised pass; at gimbal
lock (middle angle +-90 deg) the third angle is set to 0 and the first absorbs
the whole rotation, so no NaN can appear. Angles are unwrapped over time (no
+-360 jumps between frames; the matrices are unchanged).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ..checks import positive_number
from ..data.bvh import BvhData, parse_bvh
from ..data.types import Skeleton

__all__ = ["positions_to_bvh", "write_bvh", "solve_rotations", "matrix_to_euler",
           "read_back_positions", "dataset_scale", "ORDERS"]

ORDERS = ("XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX")
_EPS_LEN = 1e-9  # metres: shorter rest offsets / observed bones carry no direction
_GIMBAL = 1e-9   # |cos(middle angle)| below which the Euler extraction is at gimbal lock


# ----------------------------------------------------------------------------- public API

def positions_to_bvh(positions: np.ndarray, skeleton: Skeleton, fps: float, order: str = "ZXY",
                     scale: float = 1.0, translate: Iterable[str] = (), leaf_end_sites: bool = True,
                     unwrap: bool = True, bone_tolerance: float | None = 0.5) -> BvhData:
    """Joint positions ``[T, J, 3]`` (world, metres) -> a :class:`BvhData` on ``skeleton``.

    ``fps``: frame rate of ``positions``. ``order``: Euler order of every joint's
    rotation channels (one of :data:`ORDERS`). ``scale``: file units per metre
    (100 writes centimetres, the units of the CMU and Bandai sources; see
    :func:`dataset_scale`). ``translate``: non-root joints that also get position
    channels because their distance to the parent is not a fixed bone (Bandai's
    ``Hips`` under the static ``joint_Root`` when exporting the full 22-node
    hierarchy). ``leaf_end_sites``: give leaf joints a zero-length End Site.
    ``unwrap``: remove +-360 deg jumps between frames. ``bone_tolerance``: reject
    positions whose per-bone median length, or 10-90 % length spread over frames,
    differs from the skeleton's bone length by more than this fraction (wrong
    units, another skeleton, a joint-order mismatch, a joint that is no bone);
    ``None`` disables the check.

    Raises ``ValueError`` naming the problem for bad positions (shape, NaN/Inf,
    joint count, bones that do not match the skeleton) or bad arguments.
    """
    pos = _check_positions(positions, skeleton)
    fps, scale = _check_positive(fps, "fps"), _check_positive(scale, "scale")
    order = _check_order(order)
    trans = _check_skeleton(skeleton, translate)
    if bone_tolerance is not None:
        _check_bones(pos, skeleton, trans, bone_tolerance)

    local, glob, fit = solve_rotations(pos, skeleton, trans)
    angles = matrix_to_euler(local, order)  # [T, J, 3] degrees
    if unwrap and len(angles) > 1:
        angles = np.unwrap(angles, axis=0, period=360.0)

    # Local translations of translated joints, in the parent's solved frame and relative
    # to the parent's exported position, so the joint lands on its input position.
    par = skeleton.parents
    tr_local = {j: np.einsum("tji,tj->ti", glob[:, par[j]], pos[:, j] - fit[:, par[j]]) for j in trans}

    # Depth-first node order (the order of the hierarchy text and so of the motion columns).
    end_set = {skeleton.index(n) for n in skeleton.end_sites}
    children = _children(par)
    nodes: list[tuple[int, bool]] = []  # (skeleton joint, is an added zero-length End Site)

    def visit(j: int) -> None:
        nodes.append((j, False))
        if leaf_end_sites and not children[j] and j not in end_set:
            nodes.append((j, True))
        for c in children[j]:
            visit(c)

    for r in np.flatnonzero(par < 0):
        visit(int(r))

    names, parents, offsets, channels, is_end, cols = [], [], [], [], [], []
    node_of_joint: dict[int, int] = {}
    rot_ch = [f"{a}rotation" for a in order]
    pos_ch = ["Xposition", "Yposition", "Zposition"]
    for j, added in nodes:
        if added:
            names.append(f"{skeleton.names[j]}_End")
            parents.append(node_of_joint[j])
            offsets.append(np.zeros(3))
            channels.append([])
            is_end.append(True)
            continue
        node_of_joint[j] = len(names)
        p = int(par[j])
        names.append(f"{skeleton.names[p]}_End" if j in end_set else skeleton.names[j])
        parents.append(node_of_joint[p] if p >= 0 else -1)
        offsets.append(skeleton.offsets[j].astype(np.float64) * scale)
        is_end.append(j in end_set)
        if j in end_set:
            channels.append([])
        elif p < 0:
            channels.append(pos_ch + rot_ch)
            cols += [pos[:, j] * scale, angles[:, j]]
        elif j in trans:
            channels.append(pos_ch + rot_ch)
            cols += [tr_local[j] * scale, angles[:, j]]
        else:
            channels.append(list(rot_ch))
            cols.append(angles[:, j])
    motion = np.concatenate(cols, axis=1) if cols else np.zeros((len(pos), 0))
    return BvhData(names, np.array(parents), np.array(offsets), channels, motion, 1.0 / fps,
                   np.array(is_end))


def write_bvh(path: str | Path, positions: np.ndarray, skeleton: Skeleton, fps: float,
              precision: int = 6, **kwargs: Any) -> Path:
    """:func:`positions_to_bvh` then write the text to ``path`` (``kwargs`` go to it).

    ``precision``: decimals in the file; 6 is 1e-8 m when writing centimetres
    (``scale=100``), pass 8 when writing metres."""
    bvh = positions_to_bvh(positions, skeleton, fps, **kwargs)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(bvh.to_text(precision=precision))
    return path


def read_back_positions(bvh: BvhData | str | bytes, skeleton: Skeleton, scale: float = 1.0) -> np.ndarray:
    """Re-read an exported file with our BVH reader: positions ``[T, J, 3]`` in metres,
    in ``skeleton``'s joint order (End Sites matched by their parent)."""
    b = parse_bvh(bvh.to_text() if isinstance(bvh, BvhData) else bvh, "<exported>")
    pos = b.positions(dtype=np.float64) / scale
    idx = b.names.index
    end_set = set(skeleton.end_sites)
    sel = [idx(f"{skeleton.names[skeleton.parents[j]]}_End") if n in end_set else idx(n)
           for j, n in enumerate(skeleton.names)]
    return pos[:, sel]


def dataset_scale(dataset_cfg: Mapping[str, Any]) -> float:
    """File units per metre of a dataset's source files: ``1 / reader.scale``
    (``conf/dataset/<name>.yaml``; 100 for the CMU and Bandai BVH sources)."""
    s = float((dataset_cfg.get("reader") or {}).get("scale", 1.0))
    return 1.0 / _check_positive(s, "reader.scale")


# ----------------------------------------------------------------------------- solver

def solve_rotations(positions: np.ndarray, skeleton: Skeleton,
                    translate: Iterable[int | str] = ()) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Local and global rotations ``[T, J, 3, 3]`` solved from positions ``[T, J, 3]``, and
    the positions the skeleton reaches with them ``[T, J, 3]`` (its bone lengths, the
    input's bone directions, the input's root and translated-joint positions).

    No input checks (see :func:`positions_to_bvh`); loops over joints only.
    """
    pos = np.asarray(positions, dtype=np.float64)
    T, J = pos.shape[:2]
    par = skeleton.parents
    off = skeleton.offsets.astype(np.float64)
    trans = {skeleton.index(t) if isinstance(t, str) else int(t) for t in translate}
    children = _children(par)
    eye = np.broadcast_to(np.eye(3), (T, 3, 3))
    local = np.empty((T, J, 3, 3))
    glob = np.empty((T, J, 3, 3))
    fit = np.empty((T, J, 3))
    rest_len = np.linalg.norm(off, axis=1)
    for j in range(J):
        p = int(par[j])
        gp = glob[:, p] if p >= 0 else eye
        if p < 0 or j in trans:
            fit[:, j] = pos[:, j]
        else:
            fit[:, j] = fit[:, p] + gp @ off[j]
        kids = [c for c in children[j] if c not in trans and rest_len[c] > _EPS_LEN]
        if not kids:
            rot = eye
        else:
            # Observed bones in the parent's frame: u = G_p^T (x_c - x_j)   [T, K, 3]
            u = np.einsum("tji,tkj->tki", gp, pos[:, kids] - pos[:, j:j + 1])
            a = off[kids]
            if len(kids) == 1 or np.linalg.matrix_rank(a, tol=1e-6 * rest_len[kids].max()) < 2:
                k = int(np.argmax(rest_len[kids]))
                rot = _swing(a[k] / rest_len[kids][k], u[:, k])
            else:
                rot = _kabsch(a, u)
        local[:, j] = rot
        glob[:, j] = rot if p < 0 else gp @ rot
    return local, glob, fit


def _swing(a: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Minimal rotations ``[T, 3, 3]`` taking the unit vector ``a`` ``[3]`` to the directions
    of ``u`` ``[T, 3]`` (identity where ``u`` is ~0).

    Two reflections: ``R = (I - 2 h h^T)(I - 2 a a^T)`` with ``h`` the unit bisector of
    ``a`` and ``b = u/|u|``: exact at ``b = a`` and well conditioned up to ``b ~ -a``; at
    exactly ``b = -a`` (no unique minimal rotation) ``h`` is any unit vector normal to ``a``,
    giving a half turn about a fixed axis."""
    n = np.linalg.norm(u, axis=-1, keepdims=True)
    b = np.where(n > _EPS_LEN, u / np.maximum(n, _EPS_LEN), a)
    h = a + b
    hn = np.linalg.norm(h, axis=-1, keepdims=True)
    perp = np.cross(a, np.eye(3)[int(np.argmin(np.abs(a)))])
    perp /= np.linalg.norm(perp)
    h = np.where(hn > 1e-12, h / np.maximum(hn, 1e-12), perp)
    ha = h @ a  # [T]
    aa = np.outer(a, a)
    R = np.eye(3) - 2.0 * aa - 2.0 * h[:, :, None] * h[:, None, :]
    R += 4.0 * ha[:, None, None] * h[:, :, None] * a[None, None, :]
    return R


def _kabsch(a: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Best-fit proper rotations ``[T, 3, 3]`` with ``R a_k ~ |a_k| u_k/|u_k|``.

    ``a`` ``[K, 3]`` rest offsets, ``u`` ``[T, K, 3]`` observed bones. Minimises
    ``sum_k |R a_k - b_k|^2`` over rotations (det = +1): SVD of ``H = sum_k a_k b_k^T``.
    Observed bones of ~zero length are left out; a frame with none left gets I."""
    n = np.linalg.norm(u, axis=-1, keepdims=True)
    ok = n > _EPS_LEN
    b = np.where(ok, u / np.maximum(n, _EPS_LEN), 0.0) * np.linalg.norm(a, axis=-1)[None, :, None]
    H = np.einsum("ki,tkj->tij", a, b)
    U, _, Vt = np.linalg.svd(H)
    V = np.swapaxes(Vt, -1, -2)
    d = np.sign(np.linalg.det(V @ np.swapaxes(U, -1, -2)))
    d = np.where(d == 0, 1.0, d)
    V[:, :, 2] *= d[:, None]
    R = V @ np.swapaxes(U, -1, -2)
    return np.where(ok.any(axis=1)[:, :, None], R, np.eye(3))


def _children(parents: np.ndarray) -> list[list[int]]:
    out: list[list[int]] = [[] for _ in parents]
    for j, p in enumerate(parents):
        if p >= 0:
            out[int(p)].append(j)
    return out


# ----------------------------------------------------------------------------- Euler

def matrix_to_euler(R: np.ndarray, order: str = "ZXY") -> np.ndarray:
    """Intrinsic Euler angles (degrees, ``[..., 3]`` in ``order``) of rotations ``[..., 3, 3]``:
    the inverse of :func:`motionsynth.data.bvh.euler_to_matrix`.

    With axes ``i, j, k`` (``order``) and ``s = +1`` for the cyclic orders (XYZ, YZX,
    ZXY), ``-1`` otherwise: middle angle ``b = atan2(s R_ik, hypot(R_ii, R_ij))`` in
    [-90, 90]; first ``a = atan2(-s R_jk, R_kk)``; third ``c = atan2(-s R_ij, R_ii)``.
    At gimbal lock (``cos b ~ 0``) ``c = 0`` and ``a = atan2(s R_kj, R_jj)``. No NaN.
    """
    order = _check_order(order)
    R = np.asarray(R, dtype=np.float64)
    i, j, k = ("XYZ".index(ch) for ch in order)
    s = 1.0 if (i, j, k) in ((0, 1, 2), (1, 2, 0), (2, 0, 1)) else -1.0
    cb = np.hypot(R[..., i, i], R[..., i, j])
    b = np.arctan2(s * R[..., i, k], cb)
    lock = cb < _GIMBAL
    a = np.where(lock, np.arctan2(s * R[..., k, j], R[..., j, j]),
                 np.arctan2(-s * R[..., j, k], R[..., k, k]))
    c = np.where(lock, 0.0, np.arctan2(-s * R[..., i, j], R[..., i, i]))
    return np.rad2deg(np.stack([a, b, c], axis=-1))


# ----------------------------------------------------------------------------- checks

_check_positive = positive_number


def _check_order(order: str) -> str:
    o = str(order).upper()
    if o not in ORDERS:
        raise ValueError(f"Euler order must be one of {', '.join(ORDERS)}, got {order!r}")
    return o


def _check_positions(positions: np.ndarray, skeleton: Skeleton) -> np.ndarray:
    try:
        pos = np.asarray(positions, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise ValueError(f"positions must be a numeric [T, J, 3] array: {e}") from None
    if pos.ndim != 3 or pos.shape[-1] != 3:
        raise ValueError(f"positions must be [T, J, 3], got shape {pos.shape}")
    if pos.shape[0] == 0:
        raise ValueError("positions have no frames")
    J = skeleton.num_joints
    if pos.shape[1] != J:
        raise ValueError(f"positions have {pos.shape[1]} joints but the skeleton has {J} "
                         f"({', '.join(skeleton.names[:4])}, ...): positions and skeleton do not match")
    bad = ~np.isfinite(pos)
    if bad.any():
        frames = np.flatnonzero(bad.any(axis=(1, 2)))
        joint = skeleton.names[int(np.flatnonzero(bad[frames[0]].any(axis=1))[0])]
        raise ValueError(f"positions contain NaN or Inf in {len(frames)} frame(s), first at frame "
                         f"{frames[0]} (joint {joint!r})")
    return pos


def _check_skeleton(skeleton: Skeleton, translate: Iterable[str]) -> set[int]:
    names = skeleton.names
    par = skeleton.parents
    if not np.isfinite(skeleton.offsets).all():
        raise ValueError("skeleton offsets contain NaN or Inf")
    for n in names:
        if not n or any(ch.isspace() or ch in "{}" for ch in n):
            raise ValueError(f"skeleton joint name {n!r} cannot be written to BVH (empty, "
                             f"whitespace or braces)")
    children = _children(par)
    end_idx = []
    for e in skeleton.end_sites:
        if e not in names:
            raise ValueError(f"skeleton end site {e!r} is not one of its joints")
        j = names.index(e)
        if par[j] < 0:
            raise ValueError(f"skeleton end site {e!r} is a root")
        if children[j]:
            raise ValueError(f"skeleton end site {e!r} has children "
                             f"{[names[c] for c in children[j]]}")
        end_idx.append(j)
    out_names = [f"{names[par[j]]}_End" if j in set(end_idx) else n for j, n in enumerate(names)]
    seen: dict[str, int] = {}
    for n in out_names:
        seen[n] = seen.get(n, 0) + 1
    dup = [n for n, k in seen.items() if k > 1]
    if dup:
        raise ValueError(f"BVH node names would repeat (End Sites are named '<parent>_End'): {dup}")
    trans = set()
    for t in translate:
        if t not in names:
            raise ValueError(f"translate: unknown joint {t!r}")
        j = names.index(t)
        if j in set(end_idx):
            raise ValueError(f"translate: {t!r} is an End Site, which has no channels")
        if par[j] >= 0:
            trans.add(j)
    return trans


def _check_bones(pos: np.ndarray, skeleton: Skeleton, trans: set[int], tol: float) -> None:
    """Observed bone lengths vs the skeleton's, per bone over frames: the median must be
    within ``tol`` of the rest length (catches wrong units, another skeleton, a joint-order
    mismatch) and the 10-90 % spread within ``tol`` of it (a real bone has a near-constant
    length; a joint that moves freely under a static root has not: use ``translate``)."""
    par = skeleton.parents
    js = np.array([j for j in range(skeleton.num_joints) if par[j] >= 0 and j not in trans], dtype=int)
    if len(js) == 0:
        return
    lengths = np.linalg.norm(pos[:, js] - pos[:, par[js]], axis=-1)  # [T, B]
    p10, obs, p90 = np.percentile(lengths, [10, 50, 90], axis=0)
    rest = np.linalg.norm(skeleton.offsets[js].astype(np.float64), axis=-1)
    real = rest > _EPS_LEN
    ref = np.maximum(rest, float(np.median(rest[real])) if real.any() else 1.0)
    dev = np.maximum(np.abs(obs - rest), p90 - p10) / ref
    bad = np.flatnonzero(dev > tol)
    if not len(bad):
        return
    worst = bad[np.argsort(-dev[bad])][:5]
    ratio = float(np.median(obs[real] / rest[real])) if real.any() else float("nan")
    detail = ", ".join(f"{skeleton.names[par[js[b]]]}->{skeleton.names[js[b]]}: {obs[b]:.4g} "
                       f"({p10[b]:.4g}..{p90[b]:.4g}) vs {rest[b]:.4g}" for b in worst)
    hint = (f"; bones are {ratio:.3g}x the skeleton's overall (units? positions must be metres)"
            if abs(ratio - 1) > tol else
            "; a joint whose distance to its parent is not a fixed bone (e.g. Bandai's Hips under the "
            "static joint_Root) can be passed in translate=, or bone_tolerance=None skips this check")
    raise ValueError(f"positions do not match the skeleton: {len(bad)} bone(s) differ from the "
                     f"skeleton's length by more than {tol:.0%} (median (10..90 %) over frames vs rest, "
                     f"metres): {detail}{hint}")
