"""Closed-loop next-best-touch exploration on a mesh: active vs random vs uniform (thesis 7.2.4, 8.2.3).

This is the grid-only precursor of the ACTOR experiment of thesis Fig. 8.7 (``vtlearn bench
active-reconstruction``): no network is involved. An object mesh stands on the table; a tactile pad
touches it repeatedly, and after every touch the occupancy grid is updated with the measured rays.
The strategies differ only in how the next touch is chosen:

- ``active``: the candidate with the largest expected information gain (eq. 7.11-7.12 / 8.4-8.5) among
  ``n_candidates`` Monte-Carlo samples on the bounding-box faces (excluding the bottom);
- ``random``: one random candidate from the same sampler;
- ``uniform``: a fixed, evenly spread schedule over the faces (a lattice on every face, visited
  round-robin across faces), independent of what has been measured.

The simulated touch uses Open3D's RaycastingScene on the mesh. The pad is rigid: it advances along its
pressing axis until the first taxel meets the surface; taxels within ``compliance`` of that distance
report contact (hit rays, contact points), the others report free space up to where the pad stopped.
A pad that meets nothing sweeps free space over its whole ray length.

Reported after every touch: the grid entropy (eq. 7.9, nats), the surface coverage (fraction of points
sampled on the mesh surface within ``coverage_radius`` of a contact point) and the number of contact
points.

Shapes:
    ExplorationResult.entropy / coverage / n_points: ``(n_touches + 1,)``, index 0 before any touch.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vtlearn.active.actions import ActionSet, OrientedBox, sample_touch_actions
from vtlearn.active.occupancy import OccupancyGrid
from vtlearn.active.sensors import Rays, TactileArray, cast_rays_on_mesh
from vtlearn.geometry.sampling import sample_surface

__all__ = ["ExplorationResult", "STRATEGIES", "explore", "simulate_touch", "uniform_touch_schedule"]

STRATEGIES = ("active", "random", "uniform")


@dataclass
class ExplorationResult:
    strategy: str
    entropy: np.ndarray
    coverage: np.ndarray
    n_points: np.ndarray
    contacts: np.ndarray
    chosen_faces: list[int]


def simulate_touch(mesh, rays: Rays, compliance: float = 0.002) -> tuple[np.ndarray, np.ndarray]:
    """Measured ranges and contact flags of rigid-pad touches (see module docstring).

    Shapes:
        rays: ``R`` rays in ``A`` actions -> ranges ``(R,)``, hit ``(R,)`` bool.
    """
    if not (np.isfinite(compliance) and compliance >= 0):
        raise ValueError(f"compliance: need a non-negative distance in metres, got {compliance}")
    ranges, hit = cast_rays_on_mesh(mesh, rays)
    # Where the rigid pad stops: the nearest contact among the taxels of each action.
    stop = np.full(rays.n_actions, np.inf)
    np.minimum.at(stop, rays.action_index[hit], ranges[hit])
    stop_r = stop[rays.action_index]
    contact = hit & (ranges <= stop_r + compliance)
    swept = np.where(np.isfinite(stop_r), np.minimum(stop_r + compliance, rays.max_range), rays.max_range)
    return np.where(contact, ranges, swept), contact


def uniform_touch_schedule(box: OrientedBox, n: int, standoff: float) -> ActionSet:
    """``n`` touches spread evenly over the five faces: a square lattice per face (about ``n / 5``
    points, at cell centres), visited round-robin across faces so that any prefix is spread too."""
    per_face = int(np.ceil(n / 5))
    k = int(np.ceil(np.sqrt(per_face)))
    u = (np.arange(k) + 0.5) / k * 2 - 1  # lattice in [-1, 1]
    uu, vv = np.meshgrid(u, u, indexing="ij")
    # Visit lattice points in a bit-reversal-like order so early touches are far apart on each face.
    order = np.argsort(np.array([int(f"{i:08b}"[::-1], 2) for i in range(k * k)]))
    lattice = np.stack([uu.ravel(), vv.ravel()], axis=1)[order]
    from vtlearn.active.actions import _FACE_NORMALS, _FACE_U, _FACE_V, _frames_from_z

    half = box.extents / 2
    T_list, faces = [], []
    for j in range(per_face):
        for f in range(5):
            if len(T_list) == n:
                break
            s, t = lattice[j % len(lattice)]
            nrm, fu, fv = _FACE_NORMALS[f], _FACE_U[f], _FACE_V[f]
            point_b = nrm * half + s * fu * half + t * fv * half + standoff * nrm
            T = np.eye(4)
            T[:3, :3] = box.T_world_box[:3, :3] @ _frames_from_z(-nrm[None], fu[None])[0]
            T[:3, 3] = box.T_world_box[:3, :3] @ point_b + box.T_world_box[:3, 3]
            T_list.append(T)
            faces.append(f)
    T_all = np.stack(T_list)
    return ActionSet("touch", T_all, T_all[:, :3, 3].copy(), np.array(faces, dtype=np.int64))


def _coverage(surface: np.ndarray, contacts: np.ndarray, radius: float) -> float:
    if contacts.shape[0] == 0:
        return 0.0
    from scipy.spatial import cKDTree

    d, _ = cKDTree(contacts).query(surface, k=1)
    return float((d <= radius).mean())


def explore(
    mesh,
    strategy: str,
    n_touches: int = 20,
    *,
    n_candidates: int = 100,
    cells: int = 40,
    sensor: TactileArray | None = None,
    standoff: float = 0.02,
    n_init: int = 2,
    coverage_radius: float = 0.005,
    compliance: float = 0.002,
    gain_mode: str = "raycast",
    seed: int = 0,
) -> ExplorationResult:
    """Run one closed-loop exploration of ``mesh`` (a ``trimesh.Trimesh`` in metres, world frame z-up).

    The first ``n_init`` touches are random and identical for every strategy with the same ``seed``.
    """
    import trimesh

    if strategy not in STRATEGIES:
        raise ValueError(f"strategy: expected one of {STRATEGIES}, got {strategy!r}")
    if int(n_touches) < 1 or int(n_init) < 0 or int(n_init) > int(n_touches):
        raise ValueError(
            f"n_touches, n_init: need n_touches >= 1 and 0 <= n_init <= n_touches, got {n_touches}, {n_init}"
        )
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ValueError("mesh: expected a non-empty trimesh.Trimesh")
    box = OrientedBox.from_points(mesh.vertices, margin=0.003)
    side = float(box.extents.max()) + 2 * 0.006
    grid = OccupancyGrid(box.center - side / 2, side / int(cells), (int(cells),) * 3)
    sensor = sensor or TactileArray("xela_4x4", ray_length=standoff + float(box.extents.max()) + 0.01)
    surface = sample_surface(mesh, 2000, seed=seed)[0]

    rng_init = np.random.default_rng([seed, 0])
    rng = np.random.default_rng([seed, 1 + STRATEGIES.index(strategy)])
    schedule = uniform_touch_schedule(box, int(n_touches), standoff) if strategy == "uniform" else None

    contacts = np.zeros((0, 3))
    entropy, coverage, npts, faces = [grid.entropy()], [0.0], [0], []
    for step in range(int(n_touches)):
        if step < n_init:
            chosen = sample_touch_actions(box, 1, standoff=standoff, seed=rng_init)
        elif strategy == "uniform":
            chosen = schedule.subset([step])
        elif strategy == "random":
            chosen = sample_touch_actions(box, 1, standoff=standoff, seed=rng)
        else:
            cands = sample_touch_actions(box, n_candidates, standoff=standoff, seed=rng)
            r = sensor.rays(cands.T_world_sensor)
            gains = grid.expected_information_gain(
                r.origins, r.directions, r.max_range, r.action_index, r.n_actions, mode=gain_mode
            )
            chosen = cands.subset([int(np.argmax(gains))])
        rays = sensor.rays(chosen.T_world_sensor)
        ranges, hit = simulate_touch(mesh, rays, compliance)
        grid.insert_rays(rays.origins, rays.directions, ranges, hit)
        contacts = np.concatenate([contacts, rays.origins[hit] + ranges[hit, None] * rays.directions[hit]])
        entropy.append(grid.entropy())
        coverage.append(_coverage(surface, contacts, coverage_radius))
        npts.append(contacts.shape[0])
        faces.append(int(chosen.face[0]))
    return ExplorationResult(strategy, np.array(entropy), np.array(coverage), np.array(npts), contacts, faces)
