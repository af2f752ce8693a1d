"""Closed-loop active perception on a simulated object in pybullet (thesis 5.2.3, 7.2.4, 8.2.3).

One loop serves the three experiments of the thesis that choose sensing actions by expected
information gain:

- reconstruction from touches and pinches (8.2.3, Fig. 8.7), scored by ACTOR's Chamfer distance;
- tactile recognition (7.2.4, eq. 7.9-7.12, Algorithm 5), scored by xAVTNet's confidence;
- shared visuo-tactile exploration (5.2.3, eq. 5.10, Fig. 5.13), views and touches on one grid.

An object (a procedural instance of :mod:`vtlearn.sim_data.shapes`) stands on the table of a pybullet
:class:`~vtlearn.sim_data.scene.Scene`. Touches and each pad of a pinch are guarded motions of
:class:`~vtlearn.sim_data.tactile.TactileSimulator` (force threshold, elastomer compression, a rigid
housing). Their outcome becomes occupancy evidence (eq. 5.7 / 7.10): a contacted taxel is a hit at its
contact point; every other taxel ray is free space up to where the pad stopped (or its whole length if
the pad met nothing). Views are ToF-camera beams cast on the mesh with Open3D; a transparent object
returns no depth (the camera failure that motivates touch in 5.2.3), so its views add nothing.

Strategies (same action space, same budget):

- ``active``: every step scores ``n_candidates`` Monte-Carlo candidates of every kind with budget left
  by the expected information gain (eq. 5.8 / 7.11 / 8.4) and takes ``argmax IG / D(a)`` (eq. 5.10,
  :class:`~vtlearn.active.selection.EnergyCosts`; with one kind this is eq. 7.12 / 8.5).
  ``gain_mode="raycast"`` is the thesis' expected measurement, ``"probabilistic"`` the extension of
  :meth:`~vtlearn.active.occupancy.OccupancyGrid.expected_information_gain`. ``"box_fit"`` (beyond the
  thesis, :mod:`vtlearn.active.reconstruction_nbt`) scores touches and pinches by how much ACTOR's
  reconstruction is expected to move towards the known bounding box. ``"novelty"`` (beyond the thesis,
  :mod:`vtlearn.active.recognition_novelty`) scores touches by how far from the measured points their
  contacts are expected to land on the templates of the most probable classes.
- ``random``: one random candidate of a random kind with budget left.
- ``random_pinch``: one random pinch (needs pinches and no views), a control that separates the choice
  of action kind from the choice of action (docs/active_perception.md).
- ``uniform``: fixed schedules independent of the measurements: views at evenly spaced azimuths first,
  then the face-lattice touch schedule (alternating with the footprint-lattice pinch schedule when
  pinches are allowed) of :mod:`vtlearn.active.exploration`.

The first ``n_init`` tactile actions are random touches shared by every strategy with the same seed
(thesis 7.2.4: the procedure starts from random touches).

Frames and units: metres, world z-up with the table at z = 0. ``T_world_object`` maps the metric
object frame (the canonical unit-cube frame times ``scale_m``) into the world. The canonical frame of
ACTOR and xAVTNet (bounding box centred, largest extent 1) is recovered from the object's bounding box,
which the action samplers assume known anyway (from the RGB segmentation in the thesis).

Shapes:
    Episode.points: ``(M, 3)`` world-frame measured points in the order measured;
    Episode.step: ``(M,)`` 0-based action that measured each point; Episode.tactile: ``(M,)`` bool;
    Episode.entropy: ``(n_steps + 1,)`` grid entropy (eq. 5.6, nats), index 0 before any action.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from vtlearn.active.actions import (
    ActionSet,
    OrientedBox,
    sample_pinch_actions,
    sample_touch_actions,
    sample_view_actions,
    view_rotation,
)
from vtlearn.active.exploration import uniform_pinch_schedule, uniform_touch_schedule
from vtlearn.active.occupancy import OccupancyGrid
from vtlearn.active.selection import EnergyCosts, energy_costs, select_next_best_action
from vtlearn.active.sensors import PinchSensor, Rays, TactileArray, ToFCamera, cast_rays_on_mesh
from vtlearn.validation import as_int

__all__ = [
    "STRATEGIES",
    "TOUCH_STRATEGIES",
    "Episode",
    "SimObject",
    "TouchWorld",
    "choose_action",
    "classify_clouds",
    "held_out_objects",
    "make_object",
    "run_episode",
]

STRATEGIES = ("active", "random", "uniform", "random_pinch")
# The strategies that also run without pinches or with views (random_pinch needs pinches and no views).
TOUCH_STRATEGIES = ("active", "random", "uniform")
GAIN_MODES = ("raycast", "probabilistic", "recognition", "box_fit", "novelty")
TACTILE_KINDS = ("touch", "pinch")
# Base seed of held-out instances; gen-data uses the dataset seed (0 by default), so these instance seeds
# come from another SeedSequence and differ from every training instance.
HELD_OUT_SEED = 1_000_003


@dataclass
class SimObject:
    """A procedural instance standing on the table (see module docstring for frames)."""

    category: str
    seed: int
    transparent: bool
    mesh: object  # trimesh.Trimesh, canonical unit-cube frame
    scale_m: float
    T_world_object: np.ndarray
    surface_world: np.ndarray  # (S, 3) ground-truth surface samples, world frame

    @property
    def mesh_world(self):
        import trimesh

        m = trimesh.Trimesh(self.mesh.vertices * self.scale_m, self.mesh.faces, process=False)
        return m.apply_transform(self.T_world_object)

    @property
    def bounds(self) -> np.ndarray:
        """``(2, 3)`` world-frame axis-aligned bounding box."""
        return self.mesh.bounds * self.scale_m + self.T_world_object[:3, 3]

    def to_canonical(self, points_world: np.ndarray) -> np.ndarray:
        """World points into the canonical frame of the box: centred, divided by the largest extent."""
        lo, hi = self.bounds
        return (np.asarray(points_world, dtype=np.float64).reshape(-1, 3) - (lo + hi) / 2) / float(
            (hi - lo).max()
        )

    def from_canonical(self, points_canonical: np.ndarray) -> np.ndarray:
        lo, hi = self.bounds
        return np.asarray(points_canonical, dtype=np.float64) * float((hi - lo).max()) + (lo + hi) / 2


def make_object(category: str, seed: int, sections: int = 32, n_surface: int = 2048) -> SimObject:
    """Instance ``seed`` of ``category`` (:func:`vtlearn.sim_data.shapes.generate_shape`) on the table."""
    from vtlearn.geometry.sampling import sample_surface
    from vtlearn.sim_data.shapes import generate_shape

    mesh, rec = generate_shape(category, int(seed), sections)
    T = np.eye(4)
    T[2, 3] = -mesh.bounds[0, 2] * rec.scale_m  # bottom on the table
    surf = sample_surface(mesh, int(n_surface), seed=int(seed) % (1 << 31))[0] * rec.scale_m + T[:3, 3]
    return SimObject(category, int(seed), bool(rec.transparent), mesh, float(rec.scale_m), T, surf)


def held_out_objects(
    categories,
    per_category: int,
    transparent: bool | None = None,
    base_seed: int = HELD_OUT_SEED,
    sections: int = 32,
    max_tries: int = 200,
) -> list[SimObject]:
    """``per_category`` unseen instances of each category, optionally only (non-)transparent ones.

    Instance seeds are :func:`~vtlearn.sim_data.shapes.instance_seed` of ``base_seed``; a category that
    cannot give a matching instance in ``max_tries`` draws (e.g. transparent cans) raises ValueError.
    """
    from vtlearn.sim_data.shapes import CATEGORIES, instance_seed

    per_category = as_int(per_category, "per_category")
    out = []
    for cat in categories:
        if cat not in CATEGORIES:
            raise ValueError(f"categories: unknown {cat!r}, expected some of {CATEGORIES}")
        got = 0
        for i in range(int(max_tries)):
            obj = make_object(cat, instance_seed(base_seed, cat, i), sections)
            if transparent is None or obj.transparent == transparent:
                out.append(obj)
                got += 1
                if got == per_category:
                    break
        if got < per_category:
            raise ValueError(f"categories: {cat!r} gave {got} instances with transparent={transparent}")
    return out


class TouchWorld:
    """A pybullet scene holding one :class:`SimObject` and a free-floating taxel sensor.

    Use as a context manager (it owns a pybullet connection).
    """

    def __init__(self, obj: SimObject, sensor: str = "xela_4x4"):
        from vtlearn.sim_data.scene import Scene
        from vtlearn.sim_data.tactile import TactileSimulator

        self.obj = obj
        self.scene = Scene()
        self.body = self.scene.add_mesh(
            obj.mesh, obj.scale_m, obj.T_world_object, transparent=obj.transparent
        )
        self.sim = TactileSimulator(self.scene, sensor, objects=[self.body])
        self._mesh_world = None

    def close(self) -> None:
        self.scene.close()

    def __enter__(self) -> TouchWorld:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def press(self, T_world_pad: np.ndarray, ray_length: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Guarded motions of pads at ``T_world_pad`` ``(P, 4, 4)``; the taxel rays' occupancy evidence.

        Returns:
            ranges ``(P * K,)`` (capped at ``ray_length``), hit ``(P * K,)`` bool, and the contact points
            ``(C, 3)`` in the world frame, in the ray order of :class:`~vtlearn.active.sensors.TactileArray`.
        """
        taxels = self.sim.sensor.taxel_positions()
        k = len(taxels)
        ranges, hits, points = [], [], []
        for T in np.asarray(T_world_pad).reshape(-1, 4, 4):
            res = self.sim.touch_from(T)
            d = T[:3, 2]
            origins = taxels @ T[:3, :3].T + T[:3, 3]
            travel = float((res.T_world_pad[:3, 3] - T[:3, 3]) @ d) if res.T_world_pad is not None else 0.0
            r = np.full(k, ray_length if travel <= 0 and res.num_contacts == 0 else min(travel, ray_length))
            h = np.zeros(k, dtype=bool)
            if res.num_contacts:
                along = np.einsum("ij,j->i", res.points - origins[res.taxel_ids], d)
                inside = along <= ray_length
                r[res.taxel_ids[inside]] = along[inside]
                h[res.taxel_ids[inside]] = True
                points.append(res.points)
            ranges.append(r)
            hits.append(h)
        pts = np.concatenate(points) if points else np.zeros((0, 3))
        return np.concatenate(ranges), np.concatenate(hits), pts

    def look(self, camera: ToFCamera, T_world_camera: np.ndarray) -> tuple[Rays, np.ndarray, np.ndarray]:
        """Depth beams of one view; a transparent object returns no valid depth (no rays)."""
        rays = camera.rays(T_world_camera[None])
        if self.obj.transparent:
            keep = np.zeros(len(rays), dtype=bool)
        else:
            if self._mesh_world is None:
                self._mesh_world = self.obj.mesh_world
            ranges, hit = cast_rays_on_mesh(self._mesh_world, rays)
            keep = np.ones(len(rays), dtype=bool)
        if not keep.any():
            empty = Rays(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0, dtype=np.int64), 1)
            return empty, np.zeros(0), np.zeros(0, dtype=bool)
        return rays, ranges, hit


@dataclass
class Episode:
    """What one closed-loop run measured (see module docstring for shapes)."""

    strategy: str
    kinds: list[str] = field(default_factory=list)
    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    step: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    tactile: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    entropy: list[float] = field(default_factory=list)
    gains: list[float] = field(default_factory=list)  # chosen action's expected gain (NaN if not scored)
    T_world_sensor: list[np.ndarray] = field(default_factory=list)

    @property
    def n_steps(self) -> int:
        return len(self.kinds)

    def prefix(self, k: int, modality: str = "all") -> np.ndarray:
        """Points measured by the first ``k`` actions; ``modality`` ``all`` | ``tactile`` | ``visual``."""
        if modality not in ("all", "tactile", "visual"):
            raise ValueError(f"modality: expected 'all', 'tactile' or 'visual', got {modality!r}")
        m = self.step < int(k)
        if modality == "tactile":
            m &= self.tactile
        elif modality == "visual":
            m &= ~self.tactile
        return self.points[m]

    def n_points(self) -> np.ndarray:
        """``(n_steps + 1,)`` cumulative number of measured points after each action."""
        return np.array([int((self.step < k).sum()) for k in range(self.n_steps + 1)])

    def to_dict(self) -> dict:
        return {
            "strategy": self.strategy,
            "kinds": list(self.kinds),
            "n_points": self.n_points().tolist(),
            "entropy": [float(e) for e in self.entropy],
            "gains": [None if not np.isfinite(g) else float(g) for g in self.gains],
        }


def choose_action(
    grid: OccupancyGrid,
    candidates,
    transparent: bool,
    gain_mode: str = "raycast",
    costs: EnergyCosts | None = None,
) -> tuple[str, int, np.ndarray]:
    """``argmax IG / D(a)`` (eq. 5.10) over ``candidates``, a list of ``(ActionSet, sensor)``.

    :func:`~vtlearn.active.selection.next_best_action` with a choice of ``gain_mode``.

    Returns:
        the chosen set's position in ``candidates``, the index within it, and the gains ``(A,)`` of all
        candidates in order.
    """
    if not candidates or all(len(a) == 0 for a, _ in candidates):
        raise ValueError("candidates: need at least one non-empty (ActionSet, sensor) pair")
    parts = [s.rays(a.T_world_sensor) for a, s in candidates if len(a)]
    rays = Rays.concatenate(parts)
    gains = grid.expected_information_gain(
        rays.origins, rays.directions, rays.max_range, rays.action_index, rays.n_actions, mode=gain_mode
    )
    kinds = [a.kind for a, _ in candidates for _ in range(len(a))]
    best = select_next_best_action(gains, energy_costs(kinds, transparent, costs))
    return (*_locate(candidates, best), gains)


def _locate(candidates, flat: int) -> tuple[int, int]:
    """The set in ``candidates`` (``(ActionSet, sensor)`` pairs) holding the ``flat``-th action of all of
    them in order, and the action's index within that set."""
    sizes = np.cumsum([len(a) for a, _ in candidates])
    which = int(np.searchsorted(sizes, flat, side="right"))
    return which, int(flat - (sizes[which - 1] if which else 0))


def _uniform_views(center: np.ndarray, radius: float, n: int, elevation_deg: float = 40.0) -> ActionSet:
    az = 2 * np.pi * np.arange(n) / max(n, 1)
    el = np.radians(elevation_deg)
    p = center + radius * np.stack(
        [np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.full(n, np.sin(el))], 1
    )
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = view_rotation(p, center)
    T[:, :3, 3] = p
    return ActionSet("view", T, p.copy(), np.full(n, -1, dtype=np.int64))


def run_episode(
    world: TouchWorld,
    strategy: str,
    n_tactile: int = 20,
    *,
    n_views: int = 0,
    pinch: bool = True,
    n_candidates: int = 100,
    n_view_candidates: int = 20,
    cells: int = 40,
    gain_mode: str = "probabilistic",
    n_init: int = 1,
    standoff: float = 0.02,
    camera: ToFCamera | None = None,
    view_radius: float = 0.45,
    seed: int = 0,
    progress=None,
    recognizer=None,
    feasible=None,
    reconstructor=None,
) -> Episode:
    """Explore ``world.obj`` with ``strategy`` for ``n_views`` views and ``n_tactile`` touches/pinches.

    Args:
        pinch: the tactile action space holds pinches as well as touches (thesis 8.2.3).
        n_candidates: Monte-Carlo tactile candidates per active step (half pinches with ``pinch``).
        n_view_candidates: hemisphere view candidates per active step while views are left.
        cells: grid cells per axis over a cube around the bounding box.
        gain_mode: ``"raycast"`` (thesis) or ``"probabilistic"``, see the module docstring, or
            ``"recognition"``: touches by the classifier's expected information with ``recognizer``
            (:class:`~vtlearn.active.recognition_nbt.ExpectedClassEntropyGain`; touch only, no views or
            pinches), or ``"box_fit"``: touches and pinches by the expected box-fit gain of ACTOR's
            reconstruction with ``reconstructor``
            (:class:`~vtlearn.active.reconstruction_nbt.ExpectedBoxFitGain`, thesis 8.2.3 action space,
            criterion beyond the thesis; no views), or ``"novelty"``: touches by the expected novelty of
            their contacts with ``recognizer``
            (:class:`~vtlearn.active.recognition_novelty.ExpectedContactNovelty`, thesis 7.2.4 procedure,
            criterion beyond the thesis; touch only, no views or pinches). ``"auto"`` resolves to
            ``"box_fit"`` for an episode without views when a ``reconstructor`` is given (the grid gain
            saturates on a transparent object that only touch can explore; docs/active_perception.md),
            and to ``"probabilistic"`` otherwise.
        n_init: leading random touches shared by every strategy (not with views).
        feasible: the kinematic-feasibility hook of :mod:`vtlearn.active.actions` for the sampled
            candidates: one callable for every kind, or a mapping ``{"touch"|"pinch"|"view": callable}``
            (a kind left out is unconstrained). The robot runtime fills it with IK queries
            (:class:`vtlearn.runtime.robot.IKFeasibility`). The fixed ``uniform`` schedules ignore it.
        progress: optional callable ``(step, n_steps)`` after every action (e.g. a tqdm update).
    """
    if strategy not in STRATEGIES:
        raise ValueError(f"strategy: expected one of {STRATEGIES}, got {strategy!r}")
    n_tactile, n_views = as_int(n_tactile, "n_tactile", minimum=0), as_int(n_views, "n_views", minimum=0)
    if n_tactile + n_views < 1:
        raise ValueError(
            f"n_tactile, n_views: need non-negative budgets with a positive sum, got {n_tactile}, {n_views}"
        )
    if as_int(n_init, "n_init", minimum=0) > n_tactile:
        raise ValueError(f"n_init: need 0 <= n_init <= n_tactile, got {n_init}")
    n_candidates = as_int(n_candidates, "n_candidates", minimum=2)
    if gain_mode == "auto":
        gain_mode = "box_fit" if int(n_views) == 0 and reconstructor is not None else "probabilistic"
    if gain_mode not in GAIN_MODES:
        raise ValueError(f"gain_mode: expected one of {GAIN_MODES}, got {gain_mode!r}")
    if gain_mode == "recognition" and strategy == "active":
        if recognizer is None:
            raise ValueError("recognizer: gain_mode='recognition' needs an ExpectedClassEntropyGain")
        if pinch or int(n_views):
            raise ValueError("gain_mode: 'recognition' scores touches only; set pinch=False and n_views=0")
    if gain_mode == "novelty" and strategy == "active":
        if recognizer is None:
            raise ValueError("recognizer: gain_mode='novelty' needs an ExpectedContactNovelty")
        if pinch or int(n_views):
            raise ValueError("gain_mode: 'novelty' scores touches only; set pinch=False and n_views=0")
    if gain_mode == "box_fit" and strategy == "active":
        if reconstructor is None:
            raise ValueError("reconstructor: gain_mode='box_fit' needs an ExpectedBoxFitGain")
        if int(n_views):
            raise ValueError("gain_mode: 'box_fit' scores touches and pinches only; set n_views=0")
    if strategy not in TOUCH_STRATEGIES and (not pinch or int(n_views)):
        raise ValueError(f"strategy: {strategy!r} needs pinch=True and n_views=0")
    if isinstance(feasible, Mapping):
        unknown = set(feasible) - {"touch", "pinch", "view"}
        if unknown:
            raise ValueError(f"feasible: unknown action kinds {sorted(unknown)}; use touch, pinch, view")
    elif feasible is not None and not callable(feasible):
        raise ValueError(f"feasible: need a callable or a mapping of kind -> callable, got {feasible!r}")

    def feas(kind: str):
        return feasible.get(kind) if isinstance(feasible, Mapping) else feasible

    obj = world.obj
    lo, hi = obj.bounds
    box = OrientedBox.from_aabb(lo - 0.003, hi + 0.003)
    side = float(box.extents.max()) + 0.012
    grid = OccupancyGrid(box.center - side / 2, side / int(cells), (int(cells),) * 3)
    touch = TactileArray(world.sim.sensor, ray_length=standoff + float(box.extents.max()) + 0.01)
    opening = 2 * float(np.linalg.norm(box.extents[:2])) + 0.02  # pads start outside the footprint
    sensors = {
        "touch": touch,
        "pinch": PinchSensor(world.sim.sensor, opening=opening),
        "view": camera or ToFCamera(),
    }
    rng_init = np.random.default_rng([seed, 0])
    rng = np.random.default_rng([seed, 1 + STRATEGIES.index(strategy)])
    budget = {"view": int(n_views), "tactile": int(n_tactile)}
    plans = {}
    if strategy == "uniform":
        plans["view"] = _uniform_views(box.center, view_radius, max(int(n_views), 1))
        plans["touch"] = uniform_touch_schedule(box, max(int(n_tactile), 1), standoff)
        plans["pinch"] = uniform_pinch_schedule(box, max(int(n_tactile), 1))
    ep = Episode(strategy, entropy=[grid.entropy()])
    pts, steps, tac = [], [], []
    n_total = int(n_views) + int(n_tactile)
    tactile_done = 0
    for step in range(n_total):
        gain = np.nan
        if tactile_done < int(n_init) and n_views == 0:
            chosen = sample_touch_actions(box, 1, standoff=standoff, seed=rng_init, feasible=feas("touch"))
        elif strategy == "uniform":
            if budget["view"]:
                chosen = plans["view"].subset([int(n_views) - budget["view"]])
            elif pinch and tactile_done % 2:
                chosen = plans["pinch"].subset([tactile_done // 2])
            else:
                chosen = plans["touch"].subset([tactile_done // 2 if pinch else tactile_done])
        elif strategy == "random_pinch":
            chosen = sample_pinch_actions(box, 1, seed=rng, feasible=feas("pinch"))
        elif strategy == "random":
            kinds = (["view"] if budget["view"] else []) + (["tactile"] if budget["tactile"] else [])
            kind = kinds[int(rng.integers(len(kinds)))]
            if kind == "view":
                chosen = sample_view_actions(
                    box.center, view_radius, 1, min_elevation_deg=15.0, seed=rng, feasible=feas("view")
                )
            elif pinch and rng.uniform() < 0.5:
                chosen = sample_pinch_actions(box, 1, seed=rng, feasible=feas("pinch"))
            else:
                chosen = sample_touch_actions(box, 1, standoff=standoff, seed=rng, feasible=feas("touch"))
        elif gain_mode in ("recognition", "novelty"):
            cands_t = sample_touch_actions(
                box, int(n_candidates), standoff=standoff, seed=rng, feasible=feas("touch")
            )
            measured = np.concatenate(pts) if pts else np.zeros((0, 3))
            gains_r = recognizer.gains(
                obj, measured, touch, cands_t.T_world_sensor, world.sim.config, seed=step
            )
            best = int(np.argmax(gains_r))
            chosen, gain = cands_t.subset([best]), float(gains_r[best])
        else:
            cands = []
            if budget["tactile"]:
                n_touch = int(n_candidates) // 2 if pinch else int(n_candidates)
                touches = sample_touch_actions(
                    box, n_touch, standoff=standoff, seed=rng, feasible=feas("touch")
                )
                cands.append((touches, touch))
                if pinch:
                    cands.append(
                        (
                            sample_pinch_actions(
                                box, int(n_candidates) - n_touch, seed=rng, feasible=feas("pinch")
                            ),
                            sensors["pinch"],
                        )
                    )
            if budget["view"]:
                views = sample_view_actions(
                    box.center,
                    view_radius,
                    int(n_view_candidates),
                    min_elevation_deg=15.0,
                    seed=rng,
                    feasible=feas("view"),
                )
                cands.append((views, sensors["view"]))
            if gain_mode == "box_fit":
                measured = np.concatenate(pts) if pts else np.zeros((0, 3))
                gains = reconstructor.gains(obj, measured, cands, world.sim.config, seed=step + 1)
                which, idx = _locate(cands, int(np.argmax(gains)))
            else:
                which, idx, gains = choose_action(grid, cands, obj.transparent, gain_mode)
            chosen = cands[which][0].subset([idx])
            gain = float(gains[int(np.sum([len(a) for a, _ in cands[:which]])) + idx])
        if not len(chosen):
            raise ValueError(f"feasible: rejected every candidate action at step {step}")
        if chosen.kind == "view":
            rays, ranges, hit = world.look(sensors["view"], chosen.T_world_sensor[0])
            budget["view"] -= 1
            new = rays.origins[hit] + ranges[hit, None] * rays.directions[hit]
        else:
            rays = sensors[chosen.kind].rays(chosen.T_world_sensor)
            pads = (
                sensors["pinch"].pad_transforms(chosen.T_world_sensor)[0]
                if chosen.kind == "pinch"
                else chosen.T_world_sensor
            )
            ranges, hit, new = world.press(pads, float(rays.max_range[0]))
            budget["tactile"] -= 1
            tactile_done += 1
        if len(rays):
            grid.insert_rays(rays.origins, rays.directions, ranges, hit)
        pts.append(new)
        steps.append(np.full(len(new), step, dtype=np.int64))
        tac.append(np.full(len(new), chosen.kind != "view"))
        ep.kinds.append(chosen.kind)
        ep.entropy.append(grid.entropy())
        ep.gains.append(gain)
        ep.T_world_sensor.append(chosen.T_world_sensor[0].copy())
        if progress is not None:
            progress(step + 1, n_total)
    ep.points = np.concatenate(pts) if pts else np.zeros((0, 3))
    ep.step = np.concatenate(steps) if steps else np.zeros(0, dtype=np.int64)
    ep.tactile = np.concatenate(tac) if tac else np.zeros(0, dtype=bool)
    return ep


# ------------------------------------------------------------------ scoring an episode with the networks
def network_input(
    obj: SimObject, points_world: np.ndarray, max_points: int = 120, seed: int = 0
) -> np.ndarray:
    """Measured world points as a network input: canonical frame (see module docstring), and at most
    ``max_points`` points by random voxel-grid subsampling (the sparse-input distribution ACTOR is
    trained on, :class:`~vtlearn.datamodules.ReconstructionDataModule`)."""
    from vtlearn.datamodules.shards import random_voxel_subsample

    max_points = as_int(max_points, "max_points")
    c = obj.to_canonical(points_world)
    if len(c) > int(max_points):
        c = random_voxel_subsample(c, int(max_points), int(max_points), np.random.default_rng(seed))
    return c


def _pad(clouds: list[np.ndarray]):
    import torch

    n = max(max(len(c) for c in clouds), 1)
    x = np.zeros((len(clouds), n, 3), dtype=np.float32)
    for i, c in enumerate(clouds):
        x[i, : len(c)] = c
        if len(c) < n and len(c):
            x[i, len(c) :] = c[0]  # pad with a real point; lengths mask it anyway
    return torch.from_numpy(x), torch.tensor([len(c) for c in clouds], dtype=torch.long)


def reconstruct_prefixes(
    model, obj: SimObject, ep: Episode, ks, modality: str = "all", max_points: int = 120, min_points: int = 3
) -> tuple[list[np.ndarray | None], np.ndarray]:
    """ACTOR reconstructions (world frame) from the points of the first ``k`` actions, for each k in ``ks``.

    Returns the dense clouds (None where fewer than ``min_points`` were measured) and the Chamfer
    distance (eq. 8.1, mm) of each to the object's surface samples (NaN where not reconstructed).
    """
    from vtlearn.geometry.metrics import chamfer_distance
    from vtlearn.models.actor import reconstruct

    clouds = [network_input(obj, ep.prefix(k, modality), max_points, seed=k) for k in ks]
    ok = [i for i, c in enumerate(clouds) if len(c) >= int(min_points)]
    out: list[np.ndarray | None] = [None] * len(clouds)
    cd = np.full(len(clouds), np.nan)
    if ok:
        x, lengths = _pad([clouds[i] for i in ok])
        dense = reconstruct(model, x, lengths)
        for j, i in enumerate(ok):
            out[i] = obj.from_canonical(dense[j])
            cd[i] = 1000.0 * float(chamfer_distance(out[i], obj.surface_world))
    return out, cd


def classify_clouds(
    model, obj: SimObject, clouds_world, max_points: int = 256, seed: int = 0, seeds=None
) -> np.ndarray:
    """xAVTNet class probabilities ``(len(clouds_world), C)`` of world-frame tactile clouds: the object's
    canonical frame, then the per-cloud normalisation the checkpoint was trained with (the crossmodal
    datamodule's ``normalize``, :func:`~vtlearn.models.xavtnet_inference.checkpoint_normalize`: centred by
    default, left in the object frame for ``"none"``), at most ``max_points`` points each, subsampled with
    ``seeds[i]`` (default ``seed + i``). Rows of clouds with fewer than 3 points are NaN. One batched
    forward pass."""
    import torch

    from vtlearn.datamodules.shards import normalize_cloud
    from vtlearn.models.xavtnet_inference import checkpoint_normalize

    mode = checkpoint_normalize(dict(model.hparams))
    seeds = [seed + i for i in range(len(clouds_world))] if seeds is None else list(seeds)
    clouds = [network_input(obj, c, max_points, seed=s) for c, s in zip(clouds_world, seeds, strict=True)]
    clouds = [normalize_cloud(c, mode) if len(c) else c for c in clouds]
    probs = np.full((len(clouds), int(model.hparams.num_classes)), np.nan)
    ok = [i for i, c in enumerate(clouds) if len(c) >= 3]
    if ok:
        x, lengths = _pad([clouds[i] for i in ok])
        model.eval()
        with torch.no_grad():
            p = torch.softmax(model(x, lengths).logits, dim=-1).numpy()
        probs[ok] = p
    return probs


def classify_prefixes(model, obj: SimObject, ep: Episode, ks, max_points: int = 256) -> np.ndarray:
    """xAVTNet class probabilities ``(len(ks), C)`` of the tactile points of the first ``k`` actions
    (:func:`classify_clouds`). Rows with no point are NaN."""
    return classify_clouds(model, obj, [ep.prefix(k, "tactile") for k in ks], max_points, seeds=ks)


def load_xavtnet(ckpt, data: dict | None = None):
    """:func:`vtlearn.models.xavtnet.load_xavtnet`, also importable from here, beside the closed loop."""
    from vtlearn.models.xavtnet import load_xavtnet as load

    return load(ckpt, data)
