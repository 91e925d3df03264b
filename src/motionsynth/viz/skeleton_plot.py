"""Static skeleton figures: a pose from two sides and the root trajectory from above."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ..data.types import Skeleton  # noqa: E402


def draw_bones(ax, pose: np.ndarray, parents: np.ndarray, dims: tuple[int, int], color="C0", joints=None) -> None:
    """Draw one pose ``[J, D]`` on ``ax`` using coordinates ``dims`` (e.g. (0, 1) = X-Y)."""
    a, b = dims
    sel = np.arange(len(parents)) if joints is None else np.asarray(joints)
    sset = set(sel.tolist())
    segs = [(j, p) for j, p in enumerate(parents) if p >= 0 and j in sset and p in sset]
    for j, p in segs:
        ax.plot([pose[p, a], pose[j, a]], [pose[p, b], pose[j, b]], "-", color=color, lw=1.5)
    ax.plot(pose[sel, a], pose[sel, b], ".", color="k", ms=3)


def dataset_figure(positions: np.ndarray, skeleton: Skeleton, title: str, path: str | Path,
                   body_mask: np.ndarray | None = None, frame: int | None = None,
                   views2d: np.ndarray | None = None) -> Path:
    """Save a PNG: the pose at ``frame`` (front and side), the root trajectory from above,
    and the first 2-D camera view when the dataset has one.

    ``positions`` ``[T, J, 3]`` metres, Y up.
    """
    T = len(positions)
    frame = T // 2 if frame is None else frame
    n = 4 if views2d is not None else 3
    fig, axes = plt.subplots(1, n, figsize=(3.6 * n, 3.8))
    pose = positions[frame]
    parents = skeleton.parents
    bodies = body_mask.shape[1] if body_mask is not None else 1
    per = len(parents) // bodies
    for k in range(bodies):
        if body_mask is not None and not body_mask[frame, k]:
            continue
        js = np.arange(k * per, (k + 1) * per)
        for ax, dims, lab in ((axes[0], (0, 1), ("X (m)", "Y (m)")), (axes[1], (2, 1), ("Z (m)", "Y (m)"))):
            draw_bones(ax, pose, parents, dims, color=f"C{k}", joints=js)
            ax.set_xlabel(lab[0])
            ax.set_ylabel(lab[1])
    axes[0].set_title(f"pose, frame {frame} (front)")
    axes[1].set_title("pose (side)")
    root = skeleton.index(skeleton.root) if skeleton.root else 0
    traj = positions[:, root]
    ok = body_mask[:, 0] if body_mask is not None else np.ones(T, bool)
    axes[2].plot(traj[ok, 0], traj[ok, 2], "-", color="C3", lw=1)
    axes[2].plot(traj[ok, 0][:1], traj[ok, 2][:1], "o", color="g", label="start")
    axes[2].plot(traj[ok, 0][-1:], traj[ok, 2][-1:], "s", color="r", label="end")
    axes[2].set_title(f"root trajectory ({skeleton.root}), top")
    axes[2].set_xlabel("X (m)")
    axes[2].set_ylabel("Z (m)")
    axes[2].legend(fontsize=7)
    for ax in axes[:3]:
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.3)
    if views2d is not None:
        ax = axes[3]
        for k in range(bodies):
            js = np.arange(k * per, (k + 1) * per)
            if body_mask is None or body_mask[frame, k]:
                draw_bones(ax, views2d[frame, 0], parents, (0, 1), color=f"C{k}", joints=js)
        ax.invert_yaxis()
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_title("2-D view 1 (pixels)")
        ax.grid(alpha=0.3)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
