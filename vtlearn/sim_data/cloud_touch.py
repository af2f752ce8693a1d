"""Touches simulated on a point cloud: tactile-like clouds from visual ones, without a mesh.

The tactile clouds of thesis 7.3.1 are the contacts of flat taxel pads pressed onto the object by guarded
motions from the faces of its bounding box: a pad stops at the first contact and then compresses by
``τ_f / k`` (thesis 5.3.1), so only the parts of the surface that stand out towards the pad touch it, and
each contact is one taxel of a regular grid. :func:`touch_cloud` replays that on a point cloud (for example
several camera views of an object fused in its frame): a pad pressed along a horizontal direction at a
random azimuth or from above reports, for every taxel cell that holds a point within ``depth_tol`` of the
pad's first contact, one contact at the mean of those points. No tactile data are used, only the sensor's
pitch and layout, so a visual training cloud can be turned into a tactile-like one for the source stream
of cross-modal training (``CrossModalDataModule(source_touch=True)``).

Units: any, as long as ``points``, ``pitch`` and ``depth_tol`` share them (the datamodule converts the
pitch to the instance's canonical units).

Shapes:
    points (N, 3) -> (n, 3) with n <= the requested count (fewer when every touch missed).
"""

from __future__ import annotations

import numpy as np

from vtlearn.validation import as_int, as_real

__all__ = ["touch_cloud"]


def _pad_axes(rng: np.random.Generator, p_top: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(pressing direction d, pad axes u, v) for a touch from above or from a random azimuth, random roll."""
    if rng.uniform() < p_top:
        d, u0, v0 = np.array([0.0, 0.0, -1.0]), np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
    else:
        phi = rng.uniform(0.0, 2.0 * np.pi)
        d = -np.array([np.cos(phi), np.sin(phi), 0.0])
        u0, v0 = np.array([-np.sin(phi), np.cos(phi), 0.0]), np.array([0.0, 0.0, 1.0])
    roll = rng.uniform(0.0, np.pi)
    u = np.cos(roll) * u0 + np.sin(roll) * v0
    v = -np.sin(roll) * u0 + np.cos(roll) * v0
    return d, u, v


def touch_cloud(
    points: np.ndarray,
    n: int,
    rng: np.random.Generator,
    pitch: float,
    rows: int = 4,
    cols: int = 4,
    depth_tol: float | None = None,
    margin: float = 0.9,
    max_touches: int = 200,
) -> np.ndarray:
    """Press a ``rows x cols`` taxel pad onto ``points`` until ``n`` contacts are collected.

    Each touch draws a pressing direction (from above with probability equal to the top face's share of the
    five touchable box faces, else horizontal at a uniform azimuth), a random pad roll, and a pad centre
    uniform over ``margin`` of the cloud's extent across the direction (as thesis 7.2.4 samples touch points
    on the box faces). A touch whose footprint holds no point is a miss and costs one of ``max_touches``
(>= 1); ``margin`` is a fraction in [0, 1].

    Args:
        points: the cloud, z up (objects stand on a table; the bottom is never touched).
        n: contacts wanted; the first touches that reach it are kept and a random ``n`` of their contacts
            returned.
        pitch: taxel pitch (4.7 mm for the Xela 4x4 of thesis ch.3, in the units of ``points``).
        depth_tol: how far behind the first contact a point still touches the pad (default half a pitch,
            about the 2.2 mm compression of the simulator's pad at the 1.1 N threshold).

    Shapes:
        points (N, 3) -> (m, 3), m <= n.
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) == 0:
        raise ValueError(f"points: expected a non-empty (N, 3) cloud, got shape {pts.shape}")
    if not np.isfinite(pts).all():
        raise ValueError("points: contains NaN or inf")
    n = as_int(n, "n")
    pitch = as_real(pitch, "pitch", low=0.0, open_low=True)
    rows, cols = as_int(rows, "rows"), as_int(cols, "cols")
    max_touches = as_int(max_touches, "max_touches")
    margin = as_real(margin, "margin", low=0.0, high=1.0)
    tol = 0.5 * pitch if depth_tol is None else as_real(depth_tol, "depth_tol", low=0.0)
    ext = pts.max(0) - pts.min(0)
    top, sides = ext[0] * ext[1], 2.0 * (ext[0] + ext[1]) * ext[2]
    p_top = top / (top + sides) if top + sides > 0 else 0.5
    half_u, half_v = cols * pitch / 2.0, rows * pitch / 2.0
    out, total = [], 0
    for _ in range(int(max_touches)):
        d, u, v = _pad_axes(rng, p_top)
        pu, pv = pts @ u, pts @ v
        cu = (pu.min() + pu.max()) / 2 + margin * (pu.max() - pu.min()) / 2 * rng.uniform(-1, 1)
        cv = (pv.min() + pv.max()) / 2 + margin * (pv.max() - pv.min()) / 2 * rng.uniform(-1, 1)
        lu, lv = pu - cu, pv - cv
        inpad = (np.abs(lu) < half_u) & (np.abs(lv) < half_v)
        if not inpad.any():
            continue
        depth = pts @ d
        touched = inpad & (depth <= depth[inpad].min() + tol)
        col = np.clip(np.floor((lu[touched] + half_u) / pitch), 0, cols - 1).astype(np.int64)
        row = np.clip(np.floor((lv[touched] + half_v) / pitch), 0, rows - 1).astype(np.int64)
        cells, inv = np.unique(row * cols + col, return_inverse=True)
        sums = np.zeros((len(cells), 3))
        np.add.at(sums, inv.reshape(-1), pts[touched])
        out.append(sums / np.bincount(inv.reshape(-1), minlength=len(cells))[:, None])
        total += len(cells)
        if total >= n:
            break
    if not out:
        return np.zeros((0, 3))
    cloud = np.concatenate(out)
    return cloud[rng.permutation(len(cloud))[: int(n)]]
