"""Root trajectory, facing normalisation and control signals (VAE-LSTM paper, sec. 4).

Conventions (Y up, right-handed):

* The *root* is the skeleton's root joint (Bandai: ``Hips``) projected on the
  ground plane: ``(x, z)``.
* The *facing* direction is horizontal and perpendicular to the across-body
  vector ``a = (hip_L - hip_R) + (shoulder_L - shoulder_R)``:
  ``f = normalise(a x up) = normalise((-a_z, 0, a_x))``, smoothed over time with
  a Gaussian of ``sigma`` seconds (as in Holden et al. 2016, which the paper
  builds on). ``heading = atan2(f_x, f_z)``: 0 faces +Z, positive turns towards +X.
* Controls, per frame, in the body's own frame, from forward differences of the
  root trajectory (last frame repeats the previous value):
  ``forward`` = v . f (m/s), ``sideways`` = v . l (m/s, positive to the body's
  left, l = up x f), ``turn`` = d(heading)/dt (rad/s, wrapped to (-pi, pi]).

All functions are vectorised over frames: shapes ``[T, J, 3]`` -> ``[T, ...]``.
"""

from __future__ import annotations

import numpy as np


def gaussian_smooth(x: np.ndarray, sigma_frames: float) -> np.ndarray:
    """Gaussian filter along axis 0 with edge padding (``x`` ``[T, ...]``)."""
    if sigma_frames <= 0 or len(x) < 2:
        return x
    r = int(np.ceil(3 * sigma_frames))
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma_frames) ** 2)
    k /= k.sum()
    flat = x.reshape(len(x), -1)
    padded = np.concatenate([np.repeat(flat[:1], r, 0), flat, np.repeat(flat[-1:], r, 0)])
    # one sliding-window product over time for all channels at once
    win = np.lib.stride_tricks.sliding_window_view(padded, len(k), axis=0)  # [T, C, K]
    return (win @ k).reshape(x.shape).astype(x.dtype, copy=False)


def facing(positions: np.ndarray, hips: tuple[int, int], shoulders: tuple[int, int] | None,
           sigma_frames: float = 0.0) -> np.ndarray:
    """Unit horizontal facing directions ``[T, 3]`` from ``positions`` ``[T, J, 3]``."""
    a = positions[:, hips[0]] - positions[:, hips[1]]
    if shoulders is not None:
        a = a + positions[:, shoulders[0]] - positions[:, shoulders[1]]
    f = np.stack([-a[:, 2], np.zeros(len(a), a.dtype), a[:, 0]], axis=-1)
    f = gaussian_smooth(f, sigma_frames)
    n = np.linalg.norm(f, axis=-1, keepdims=True)
    return f / np.maximum(n, 1e-8)


def heading_angle(f: np.ndarray) -> np.ndarray:
    """Heading ``[T]`` (radians) of facing directions ``[T, 3]``."""
    return np.arctan2(f[:, 0], f[:, 2])


def rotate_y(v: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rotate vectors ``[T, ..., 3]`` about +Y by ``angle`` ``[T]`` (radians)."""
    c = np.cos(angle).reshape((-1,) + (1,) * (v.ndim - 2))
    s = np.sin(angle).reshape((-1,) + (1,) * (v.ndim - 2))
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    return np.stack([x * c + z * s, y, -x * s + z * c], axis=-1)


def wrap_angle(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


def root_and_controls(positions: np.ndarray, root: int, hips: tuple[int, int],
                      shoulders: tuple[int, int] | None, fps: float, sigma_s: float = 0.0
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Split global motion into a local pose, a root trajectory and control signals.

    ``positions`` ``[T, J, 3]`` (metres, Y up) ->
    ``pose`` ``[T, J, 3]`` root-relative on the ground plane (height kept) and
    rotated so the body faces +Z; ``root`` ``[T, 3]`` = ``(x, z, heading)``;
    ``controls`` ``[T, 3]`` = ``(forward, sideways, turn)``.
    """
    f = facing(positions, hips, shoulders, sigma_s * fps)
    theta = np.unwrap(heading_angle(f))
    rxz = positions[:, root, [0, 2]]
    ground = np.stack([rxz[:, 0], np.zeros(len(rxz), rxz.dtype), rxz[:, 1]], -1)
    pose = rotate_y(positions - ground[:, None, :], -theta)
    root_traj = np.stack([rxz[:, 0], rxz[:, 1], wrap_angle(theta)], axis=-1)
    controls = controls_from_root(rxz, theta, fps)
    return pose.astype(np.float32), root_traj.astype(np.float32), controls.astype(np.float32)


def controls_from_root(rxz: np.ndarray, theta: np.ndarray, fps: float) -> np.ndarray:
    """``(forward, sideways, turn)`` ``[T, 3]`` from ground positions ``[T, 2]`` and unwrapped heading ``[T]``."""
    if len(rxz) < 2:
        return np.zeros((len(rxz), 3), np.float32)
    v = np.diff(rxz, axis=0) * fps                     # [T-1, 2] world (x, z) velocity
    th = theta[:-1]
    fwd = v[:, 0] * np.sin(th) + v[:, 1] * np.cos(th)
    side = v[:, 0] * np.cos(th) - v[:, 1] * np.sin(th)
    turn = wrap_angle(np.diff(theta)) * fps
    c = np.stack([fwd, side, turn], axis=-1)
    return np.concatenate([c, c[-1:]], axis=0)


def integrate_controls(controls: np.ndarray, fps: float, start: np.ndarray | None = None) -> np.ndarray:
    """Inverse of :func:`controls_from_root`: root trajectories ``[..., T, 3]`` = ``(x, z, heading)``
    from controls ``[..., T, 3]``, starting at ``start`` ``[..., 3]`` (default: the origin facing +Z)."""
    controls = np.asarray(controls, dtype=np.float64)
    lead = controls.shape[:-2]
    x0, z0, th0 = np.moveaxis(np.broadcast_to(np.zeros(3) if start is None else np.asarray(start, np.float64),
                                              lead + (3,)), -1, 0)

    def run(v: np.ndarray, v0: np.ndarray) -> np.ndarray:      # v0 + [0, v_0, v_0 + v_1, ...] along time
        c = np.cumsum(v[..., :-1], axis=-1)
        return v0[..., None] + np.concatenate([np.zeros(lead + (1,)), c], axis=-1)

    theta = run(controls[..., 2] / fps, th0)
    dx = (controls[..., 0] * np.sin(theta) + controls[..., 1] * np.cos(theta)) / fps
    dz = (controls[..., 0] * np.cos(theta) - controls[..., 1] * np.sin(theta)) / fps
    return np.stack([run(dx, x0), run(dz, z0), wrap_angle(theta)], axis=-1)

def to_global(local: np.ndarray, root: np.ndarray) -> np.ndarray:
    """Global positions from root-relative, facing-normalised poses: the inverse of the pose part of
    :func:`root_and_controls`. ``local`` ``[..., T, J, 3]``, ``root`` ``[..., T, 3]`` = ``(x, z, heading)``
    (leading axes broadcast) -> ``[..., T, J, 3]``: each frame rotated to its heading about +Y,
    then moved to the root's ground position (heights stay as in ``local``)."""
    local, root = np.asarray(local), np.asarray(root)[..., None, :]     # root [..., T, 1, 3]
    c, s = np.cos(root[..., 2]), np.sin(root[..., 2])
    x, y, z = local[..., 0], local[..., 1], local[..., 2]
    gx, gz = x * c + z * s + root[..., 0], -x * s + z * c + root[..., 1]
    return np.stack([gx, np.broadcast_to(y, gx.shape), gz], axis=-1)
