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

With ``pinch=True`` the action space holds touches and pinches in equal numbers, as in thesis 8.2.3.

The simulated touch uses Open3D's RaycastingScene on the mesh. The pad is rigid: it advances along its
pressing axis until the first taxel meets the surface; taxels within ``compliance`` of that distance
report contact (hit rays, contact points), the others report free space up to where the pad stopped.
A pad that meets nothing sweeps free space over its whole ray length. Each of the two pads of a pinch
stops on its own.

Reported after every touch: the grid entropy (eq. 7.9, nats), the surface coverage (fraction of points
sampled on the mesh surface within ``coverage_radius`` of a contact point) and the number of contact
points.

Shapes:
    ExplorationResult.entropy / coverage / n_points: ``(n_touches + 1,)``, index 0 before any touch.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vtlearn.active.actions import ActionSet, OrientedBox, sample_pinch_actions, sample_touch_actions
from vtlearn.active.occupancy import OccupancyGrid
from vtlearn.active.sensors import PinchSensor, Rays, TactileArray, cast_rays_on_mesh
from vtlearn.geometry.sampling import sample_surface
from vtlearn.validation import as_int, as_real

__all__ = [
    "ExplorationResult",
    "STRATEGIES",
    "explore",
    "simulate_touch",
    "uniform_pinch_schedule",
    "uniform_touch_schedule",
]

STRATEGIES = ("active", "random", "uniform")


@dataclass
class ExplorationResult:
    """One episode of :func:`explore`: the ``strategy``; the grid ``entropy`` (eq. 7.9, nats), surface
    ``coverage`` and contact count ``n_points`` before any action and after each; every ``contacts`` point
    (world frame, m); and each action's box face (-1 for a pinch) and kind (``"touch"`` or ``"pinch"``).

    Shapes:
        entropy, coverage, n_points (n_touches + 1,); contacts (M, 3); chosen_faces, chosen_kinds: n_touches.
    """

    strategy: str
    entropy: np.ndarray
    coverage: np.ndarray
    n_points: np.ndarray
    contacts: np.ndarray
    chosen_faces: list[int]
    chosen_kinds: list[str]


def simulate_touch(
    mesh, rays: Rays, compliance: float = 0.002, pad_size: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Measured ranges and contact flags of rigid-pad touches (see module docstring).

    Args:
        pad_size: rays per rigid pad, for sensors whose action has several pads (a pinch has two, each
            stopping on its own); consecutive runs of ``pad_size`` rays form a pad. None: one pad per action.

    Shapes:
        rays: ``R`` rays in ``A`` actions -> ranges ``(R,)``, hit ``(R,)`` bool.
    """
    compliance = as_real(compliance, "compliance", low=0.0, unit="m")
    if pad_size is None:
        pad, n_pads = rays.action_index, rays.n_actions
    else:
        if len(rays) % as_int(pad_size, "pad_size"):
            raise ValueError(f"pad_size: must be >= 1 and divide the {len(rays)} rays, got {pad_size}")
        pad, n_pads = np.arange(len(rays)) // int(pad_size), len(rays) // int(pad_size)
    ranges, hit = cast_rays_on_mesh(mesh, rays)
    # Where each rigid pad stops: the nearest contact among its taxels.
    stop = np.full(n_pads, np.inf)
    np.minimum.at(stop, pad[hit], ranges[hit])
    stop_r = stop[pad]
    contact = hit & (ranges <= stop_r + compliance)
    swept = np.where(np.isfinite(stop_r), np.minimum(stop_r + compliance, rays.max_range), rays.max_range)
    return np.where(contact, ranges, swept), contact


def uniform_touch_schedule(box: OrientedBox, n: int, standoff: float) -> ActionSet:
    """``n`` touches spread evenly over the five faces: a square lattice per face (about ``n / 5``
    points, at cell centres), visited round-robin across faces so that any prefix is spread too.

    Args:
        box: the object's box (world frame, metres); the bottom face is never touched.
        n: number of touches, >= 1.
        standoff: distance of each pad from its face before the approach (m, >= 0).

    Shapes:
        -> ActionSet of ``n`` touches: ``T_world_sensor`` (n, 4, 4), ``face`` (n,).
    """
    n = as_int(n, "n")
    standoff = as_real(standoff, "standoff", low=0.0, unit="m")
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


def uniform_pinch_schedule(box: OrientedBox, n: int) -> ActionSet:
    """``n`` pinches on a square lattice over the box footprint at mid-height, visited in a spread-out
    order, with the closing axis alternating between the box x and y axes.

    Shapes:
        -> ActionSet of ``n`` >= 1 pinches: ``T_world_sensor`` (n, 4, 4), face -1 each.
    """
    from vtlearn.active.actions import _frames_from_z

    n = as_int(n, "n")
    k = int(np.ceil(np.sqrt(n)))
    u = (np.arange(k) + 0.5) / k * 2 - 1
    uu, vv = np.meshgrid(u, u, indexing="ij")
    order = np.argsort(np.array([int(f"{i:08b}"[::-1], 2) for i in range(k * k)]))
    lattice = np.stack([uu.ravel(), vv.ravel()], axis=1)[order][:n]
    half = box.extents / 2
    R_wb, t_wb = box.T_world_box[:3, :3], box.T_world_box[:3, 3]
    T = np.tile(np.eye(4), (n, 1, 1))
    closing = np.where((np.arange(n) % 2 == 0)[:, None], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    T[:, :3, :3] = R_wb @ _frames_from_z(np.tile([0.0, 0.0, -1.0], (n, 1)), closing)
    centre_b = np.concatenate([lattice * half[:2], np.zeros((n, 1))], axis=1)
    T[:, :3, 3] = centre_b @ R_wb.T + t_wb
    start_b = centre_b + [0.0, 0.0, half[2] + 0.1]
    return ActionSet("pinch", T, start_b @ R_wb.T + t_wb, np.full(n, -1, dtype=np.int64))


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
    pinch: bool = False,
    pinch_opening: float = 0.14,
    seed: int = 0,
) -> ExplorationResult:
    """Run one closed-loop exploration of ``mesh`` (a ``trimesh.Trimesh`` in metres, world frame z-up).

    The first ``n_init`` touches are random and identical for every strategy with the same ``seed``.
    With ``pinch`` the action space holds touches and pinches in equal numbers (thesis 8.2.3): active
    scores both, random draws either with probability 1/2, uniform alternates the two schedules. The
    active strategy takes the candidate of largest expected information gain (eq. 7.11-7.12 / 8.4-8.5)
    on the occupancy grid, whose entropy (eq. 7.9) is reported.

    Args:
        mesh: the object standing on the table (metres, world frame, z up).
        strategy: ``"active"``, ``"random"`` or ``"uniform"`` (module docstring).
        n_touches: actions in the episode, >= 1 (touches, or touches and pinches).
        n_candidates: Monte-Carlo candidates scored per active step (>= 2 with ``pinch``: half of each).
        cells: occupancy-grid cells per axis (>= 2), over the box's largest side plus 12 mm.
        sensor: the touch sensor (default a Xela 4x4 whose rays reach across the box).
        standoff: pad distance from a face before a touch (m, >= 0).
        n_init: random first touches shared by every strategy, ``0 <= n_init <= n_touches``.
        coverage_radius: a surface point is covered within this of a contact (m, > 0).
        compliance: taxels within this of their pad's stop report contact (m, >= 0).
        gain_mode: ``"raycast"`` (thesis) or ``"probabilistic"``, see
            :meth:`~vtlearn.active.occupancy.OccupancyGrid.expected_information_gain`.
        pinch: touches and pinches in equal numbers (thesis 8.2.3).
        pinch_opening: gripper opening before a pinch closes (m, > 0).
        seed: seed of the candidates, the random choices and the coverage surface samples.

    Shapes:
        result.entropy, result.coverage, result.n_points (n_touches + 1,); result.contacts (M, 3) world
        frame, m; result.chosen_faces, result.chosen_kinds: n_touches entries.
    """
    import trimesh

    if strategy not in STRATEGIES:
        raise ValueError(f"strategy: expected one of {STRATEGIES}, got {strategy!r}")
    n_touches, n_init = as_int(n_touches, "n_touches"), as_int(n_init, "n_init", minimum=0)
    if n_init > n_touches:
        raise ValueError(
            f"n_touches, n_init: need n_touches >= 1 and 0 <= n_init <= n_touches, got {n_touches}, {n_init}"
        )
    # every argument is checked here, before any ray is cast (a bad one used to surface mid-episode as
    # "n: ..." from a sampler, or as a ZeroDivisionError for cells=0)
    n_candidates = as_int(n_candidates, "n_candidates", minimum=2 if pinch else 1)
    cells = as_int(cells, "cells", minimum=2)
    standoff = as_real(standoff, "standoff", low=0.0, unit="m")
    coverage_radius = as_real(coverage_radius, "coverage_radius", low=0.0, open_low=True, unit="m")
    compliance = as_real(compliance, "compliance", low=0.0, unit="m")
    pinch_opening = as_real(pinch_opening, "pinch_opening", low=0.0, open_low=True, unit="m")
    if gain_mode not in ("raycast", "probabilistic"):
        raise ValueError(f"gain_mode: expected 'raycast' or 'probabilistic', got {gain_mode!r}")
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ValueError("mesh: expected a non-empty trimesh.Trimesh")
    box = OrientedBox.from_points(mesh.vertices, margin=0.003)
    side = float(box.extents.max()) + 2 * 0.006
    grid = OccupancyGrid(box.center - side / 2, side / int(cells), (int(cells),) * 3)
    sensor = sensor or TactileArray("xela_4x4", ray_length=standoff + float(box.extents.max()) + 0.01)
    surface = sample_surface(mesh, 2000, seed=seed)[0]

    rng_init = np.random.default_rng([seed, 0])
    rng = np.random.default_rng([seed, 1 + STRATEGIES.index(strategy)])
    sensors = {"touch": sensor, "pinch": PinchSensor(sensor.layout, opening=pinch_opening)}
    n = int(n_touches)
    touch_plan = uniform_touch_schedule(box, n, standoff) if strategy == "uniform" else None
    pinch_plan = uniform_pinch_schedule(box, n) if strategy == "uniform" and pinch else None

    contacts = np.zeros((0, 3))
    entropy, coverage, npts, faces, kinds = [grid.entropy()], [0.0], [0], [], []
    for step in range(n):
        if step < n_init:
            chosen = sample_touch_actions(box, 1, standoff=standoff, seed=rng_init)
        elif strategy == "uniform":
            chosen = pinch_plan.subset([step // 2]) if pinch and step % 2 else touch_plan.subset([step])
        elif strategy == "random":
            if pinch and rng.uniform() < 0.5:
                chosen = sample_pinch_actions(box, 1, seed=rng)
            else:
                chosen = sample_touch_actions(box, 1, standoff=standoff, seed=rng)
        else:
            n_touch = n_candidates // 2 if pinch else n_candidates
            sets = [sample_touch_actions(box, n_touch, standoff=standoff, seed=rng)]
            if pinch:
                sets.append(sample_pinch_actions(box, n_candidates - n_touch, seed=rng))
            r = Rays.concatenate([sensors[a.kind].rays(a.T_world_sensor) for a in sets])
            gains = grid.expected_information_gain(
                r.origins, r.directions, r.max_range, r.action_index, r.n_actions, mode=gain_mode
            )
            best = int(np.argmax(gains))
            chosen = sets[0].subset([best]) if best < len(sets[0]) else sets[1].subset([best - len(sets[0])])
        rays = sensors[chosen.kind].rays(chosen.T_world_sensor)
        ranges, hit = simulate_touch(mesh, rays, compliance, pad_size=sensor.layout.num_taxels)
        grid.insert_rays(rays.origins, rays.directions, ranges, hit)
        contacts = np.concatenate([contacts, rays.origins[hit] + ranges[hit, None] * rays.directions[hit]])
        entropy.append(grid.entropy())
        coverage.append(_coverage(surface, contacts, coverage_radius))
        npts.append(contacts.shape[0])
        faces.append(int(chosen.face[0]))
        kinds.append(chosen.kind)
    return ExplorationResult(
        strategy, np.array(entropy), np.array(coverage), np.array(npts), contacts, faces, kinds
    )
