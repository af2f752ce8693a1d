r"""Interactive perception for articulation detection (thesis ch.6, 6.2.2 and 6.3.2, Fig. 6.2a, 6.3).

The robot tells a rigid object from one with a 1-DoF revolute or prismatic joint by acting on it and
tracking the pose of every part (ArtReg, :mod:`vtlearn.classical.artreg`). Two actions (thesis 6.2.2):

* push: part ``a`` is pushed 10 cm. The thesis's heuristic (:func:`push_heuristic`): if both parts
  moved with their relative pose unchanged, the joint is rigid or prismatic (pushing the other part
  confirms it, then a hold-pull decides); if only the pushed part moved, it is revolute.
* hold-pull: one part is held, the other grasped and pulled 5 cm (:func:`hold_pull_heuristic`): a
  change of the relative pose means prismatic, none means rigid.

One step beyond the heuristic, :func:`classify_relative_motion` classifies the change of the relative
pose ``T_a_b`` itself. With ``Delta = T_a_b' T_a_b^-1`` (the motion of part ``b`` seen from part
``a``, so ``p_a' = Delta p_a`` for a point fixed on ``b``), a rotation angle of ``Delta`` above a
threshold (3 deg, several times a tracker's rotation noise) means revolute, with the axis from the
rotation vector ``so3_log(R_Delta)`` and the pivot ``c`` on the axis from ``(I - R_Delta) c = t_Delta``
(least squares over every observation, plus ``u^T c = 0`` to pick the point of the axis closest to
the origin of frame ``a``). Otherwise a displacement of b's origin in frame a, ``t_a_b' - t_a_b``,
above a threshold (1 cm) means prismatic, along that displacement; neither means no relative
motion. The displacement of b's own origin, not ``t_Delta``, is thresholded because ``t_Delta``
grows with the distance of a's origin from the joint: a joint stopped by its limit after a few
degrees would otherwise read as a translation. b's frame should therefore sit on the part (link
frames and ArtReg model frames do): a rotation below the threshold about a far pivot can still read
as prismatic. This also recognises a prismatic joint from a push along its axis (a drawer pushed
shut moves alone, which the heuristic would call revolute). Axes and pivots are expressed in the
frame of part ``a``, where a joint is fixed whatever the whole object does;
:class:`ArticulationResult` also gives them in the world.

:class:`ArticulationBelief` holds the belief on the kinematic model of a pair of parts; it is
*explored* when three consecutive updates leave it unchanged (thesis 6.2.2, "Part Segmentation").
:func:`choose_action` picks the next action greedily in the thesis's order: push each part; if the
pushes are inconclusive (both parts moved together, or nothing moved), hold-pull. The action
parameters come from the oriented bounding boxes of the part clouds (thesis "Action Execution",
:mod:`vtlearn.runtime.obb`): :func:`push_action` and :func:`hold_pull_action`.

:class:`KinematicArticulationSim` executes the actions on a procedural object of
:mod:`vtlearn.sim_data.articulated` with its true kinematics (joint values and base pose), so that
:func:`detect_articulation` can be run on it from the part poses alone.

Shapes:
    T_world_part, T_before, T_after: (N, 4, 4) per-part poses T_world_part; T_a_b: (4, 4);
    part clouds: list of (M_i, 3) world points; axes, pivots, points, directions: (3,).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from vtlearn.geometry import rotation_error_deg, se3_inverse, so3_exp, so3_log, translation_error
from vtlearn.runtime.obb import check_object_cloud, oriented_bounding_box
from vtlearn.validation import as_int, as_points, as_real, as_transform

__all__ = [
    "RelativeMotion",
    "relative_pose",
    "classify_relative_motion",
    "revolute_axis",
    "prismatic_axis",
    "push_heuristic",
    "hold_pull_heuristic",
    "action_evidence",
    "ArticulationBelief",
    "PushAction",
    "HoldAction",
    "PullAction",
    "HoldPullAction",
    "push_action",
    "hold_pull_action",
    "choose_action",
    "ArticulationStep",
    "ArticulationResult",
    "detect_articulation",
    "KinematicArticulationSim",
    "TrackedArticulationSim",
]

# thesis 6.2.2: pushes of 10 cm, pulls of 5 cm
PUSH_DISTANCE, PULL_DISTANCE = 0.10, 0.05
ROT_THRESHOLD = np.deg2rad(3.0)  # a relative rotation above it is a revolute motion
TRANS_THRESHOLD = 0.01  # a relative translation above it (without rotation) is a prismatic motion
MOVE_ROT, MOVE_TRANS = np.deg2rad(2.0), 0.005  # a part moved if it turned or shifted more than this
BELIEFS = ("unknown", "rigid_or_prismatic", "rigid", "revolute", "prismatic")
EVIDENCE = ("none", "together", "rigid", "revolute", "prismatic")


# ---------------------------------------------------------------------------------- relative motion
def _poses(T, name: str, n: int | None = None) -> np.ndarray:
    arr = np.asarray(T, dtype=np.float64) if not hasattr(T, "detach") else T.detach().cpu().numpy()
    if arr.ndim != 3 or arr.shape[1:] != (4, 4) or len(arr) < 2:
        raise ValueError(f"{name}: expected (N, 4, 4) part poses with N >= 2, got shape {arr.shape}")
    if n is not None and len(arr) != n:
        raise ValueError(f"{name}: expected {n} part poses like T_before, got {len(arr)}")
    for i in range(len(arr)):
        as_transform(arr[i], f"{name}[{i}]")
    return arr


def _pair(parts, n: int, name: str = "parts") -> tuple[int, int]:
    try:
        a, b = (int(x) for x in parts)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: need two part indices, got {parts!r}") from None
    if a == b or not (0 <= a < n and 0 <= b < n):
        raise ValueError(f"{name}: need two different indices in 0..{n - 1}, got {parts!r}")
    return a, b


def relative_pose(T_world_a, T_world_b) -> np.ndarray:
    """``T_a_b = T_world_a^-1 T_world_b``, the pose of part b in the frame of part a.

    Shapes:
        T_world_a, T_world_b: (4, 4) -> (4, 4).
    """
    Ta, Tb = as_transform(T_world_a, "T_world_a"), as_transform(T_world_b, "T_world_b")
    return se3_inverse(Ta) @ Tb


@dataclass
class RelativeMotion:
    """The change ``Delta = T_a_b' T_a_b^-1`` of a relative pose and its classification.

    Attributes:
        joint_type: ``"revolute"``, ``"prismatic"`` or ``"rigid"`` (no relative motion).
        angle: rotation angle of ``Delta`` (rad).
        displacement: (3,) ``t_a_b' - t_a_b``, the motion of b's origin in frame a (m).
        translation: ``|displacement|`` (m).
        axis: (3,) unit joint axis in frame a (revolute: the rotation axis, oriented so that the
            observed motion is a positive rotation; prismatic: the direction moved), None if rigid.
        pivot: (3,) point of a revolute axis closest to the origin of frame a, else None.
        delta: (4, 4) ``Delta``.
    """

    joint_type: str
    angle: float
    displacement: np.ndarray
    translation: float
    axis: np.ndarray | None
    pivot: np.ndarray | None
    delta: np.ndarray


def revolute_axis(deltas: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Axis and pivot of a revolute joint from one or more relative motions ``Delta_k`` (frame a).

    The axis is the angle-weighted mean of the unit rotation vectors (signs aligned with the first);
    the pivot ``c`` solves ``(I - R_k) c = t_k`` for every k and ``u^T c = 0`` in least squares, i.e.
    the point of the axis closest to the frame origin (one observation fixes the axis line; more
    average the noise).

    Shapes:
        deltas: K x (4, 4), K >= 1 -> (axis (3,), pivot (3,)).
    """
    if len(deltas) == 0:
        raise ValueError("deltas: need at least one relative motion")
    D = [as_transform(d, f"deltas[{k}]") for k, d in enumerate(deltas)]
    phis = [np.asarray(so3_log(d[:3, :3])) for d in D]
    if max(np.linalg.norm(ph) for ph in phis) < 1e-9:
        raise ValueError("deltas: no rotation; a revolute axis needs a rotating relative motion")
    ref = phis[int(np.argmax([np.linalg.norm(ph) for ph in phis]))]
    u = sum(ph if ph @ ref >= 0 else -ph for ph in phis)
    u = u / np.linalg.norm(u)
    if u @ ref < 0:
        u = -u
    A = np.concatenate([np.eye(3) - d[:3, :3] for d in D] + [u[None]])
    b = np.concatenate([d[:3, 3] for d in D] + [np.zeros(1)])
    c = np.linalg.lstsq(A, b, rcond=None)[0]
    return u, c


def prismatic_axis(displacements) -> np.ndarray:
    """Unit prismatic axis (frame a): the sum of the displacements of b's origin, signs aligned.

    Oriented along the largest displacement.

    Shapes:
        displacements: (K, 3), K >= 1 -> (3,).
    """
    ts = as_points(displacements, "displacements", min_points=1)
    ref = ts[int(np.argmax(np.linalg.norm(ts, axis=1)))]
    s = (ts * np.where(ts @ ref >= 0, 1.0, -1.0)[:, None]).sum(0)
    n = float(np.linalg.norm(s))
    if n < 1e-12:
        raise ValueError("displacements: all zero; a prismatic axis needs a translating relative motion")
    return s / n


def classify_relative_motion(
    T_a_b_before, T_a_b_after, rot_threshold: float = ROT_THRESHOLD, trans_threshold: float = TRANS_THRESHOLD
) -> RelativeMotion:
    """Classify the change of the relative pose of part b in part a (module docstring).

    Args:
        T_a_b_before, T_a_b_after: pose of b in a before and after the action.
        rot_threshold: rotation angle (rad) above which the motion is revolute.
        trans_threshold: displacement of b's origin (m) above which a motion without rotation is
            prismatic.

    Shapes:
        T_a_b_before, T_a_b_after: (4, 4) -> :class:`RelativeMotion`.
    """
    T0 = as_transform(T_a_b_before, "T_a_b_before")
    T1 = as_transform(T_a_b_after, "T_a_b_after")
    rot_threshold = as_real(rot_threshold, "rot_threshold", low=0.0, open_low=True, unit="rad")
    trans_threshold = as_real(trans_threshold, "trans_threshold", low=0.0, open_low=True, unit="m")
    delta = T1 @ se3_inverse(T0)
    angle = float(np.deg2rad(rotation_error_deg(T0[:3, :3], T1[:3, :3])))
    disp = T1[:3, 3] - T0[:3, 3]
    trans = translation_error(T0[:3, 3], T1[:3, 3])
    if angle > rot_threshold:
        axis, pivot = revolute_axis([delta])
        return RelativeMotion("revolute", angle, disp, trans, axis, pivot, delta)
    if trans > trans_threshold:
        return RelativeMotion("prismatic", angle, disp, trans, disp / trans, None, delta)
    return RelativeMotion("rigid", angle, disp, trans, None, None, delta)


def _moved(T0: np.ndarray, T1: np.ndarray, rot: float, trans: float) -> bool:
    return bool(
        np.deg2rad(rotation_error_deg(T0[:3, :3], T1[:3, :3])) > rot
        or translation_error(T0[:3, 3], T1[:3, 3]) > trans
    )


def push_heuristic(
    T_before,
    T_after,
    pushed: int,
    move_rot: float = MOVE_ROT,
    move_trans: float = MOVE_TRANS,
    rot_threshold: float = ROT_THRESHOLD,
    trans_threshold: float = TRANS_THRESHOLD,
) -> str:
    """The thesis's joint-type inference after pushing part ``pushed`` (6.2.2, Fig. 6.3a).

    Returns ``"no_motion"`` (the pushed part did not move), ``"revolute"`` (only the pushed part
    moved), ``"rigid_or_prismatic"`` (every part moved, relative poses unchanged) or
    ``"inconclusive"`` (every part moved but some relative pose changed, a case the heuristic does
    not cover). A part moved if it turned more than ``move_rot`` rad or shifted more than
    ``move_trans`` m; a relative pose changed as in :func:`classify_relative_motion`.

    Shapes:
        T_before, T_after: (N, 4, 4) T_world_part, N >= 2 -> str.
    """
    T0 = _poses(T_before, "T_before")
    T1 = _poses(T_after, "T_after", len(T0))
    n = len(T0)
    if not (isinstance(pushed, (int, np.integer)) and 0 <= pushed < n):
        raise ValueError(f"pushed: need a part index in 0..{n - 1}, got {pushed!r}")
    moved = [_moved(T0[i], T1[i], move_rot, move_trans) for i in range(n)]
    if not moved[pushed]:
        return "no_motion"
    if not any(moved[i] for i in range(n) if i != pushed):
        return "revolute"
    if all(moved):
        kept = all(
            classify_relative_motion(
                relative_pose(T0[pushed], T0[i]),
                relative_pose(T1[pushed], T1[i]),
                rot_threshold,
                trans_threshold,
            ).joint_type
            == "rigid"
            for i in range(n)
            if i != pushed
        )
        if kept:
            return "rigid_or_prismatic"
    return "inconclusive"


def hold_pull_heuristic(
    T_before,
    T_after,
    hold: int,
    pull: int,
    rot_threshold: float = ROT_THRESHOLD,
    trans_threshold: float = TRANS_THRESHOLD,
) -> str:
    """The thesis's inference after holding part ``hold`` and pulling part ``pull`` (6.2.2, Fig. 6.3b).

    Returns ``"prismatic"`` if the relative pose of the two parts changed, else ``"rigid"``.

    Shapes:
        T_before, T_after: (N, 4, 4) T_world_part -> str.
    """
    T0 = _poses(T_before, "T_before")
    T1 = _poses(T_after, "T_after", len(T0))
    h, p = _pair((hold, pull), len(T0), "hold, pull")
    m = classify_relative_motion(
        relative_pose(T0[h], T0[p]), relative_pose(T1[h], T1[p]), rot_threshold, trans_threshold
    )
    return "rigid" if m.joint_type == "rigid" else "prismatic"


# ---------------------------------------------------------------------------------- actions
@dataclass
class PushAction:
    """Push ``part`` at ``point`` along ``direction`` (unit, horizontal) for ``distance`` metres."""

    part: int
    point: np.ndarray
    direction: np.ndarray
    distance: float = PUSH_DISTANCE
    kind: str = field(default="push", init=False)


@dataclass
class HoldAction:
    """Hold ``part`` at ``point`` by pressing along ``direction`` (parallel to the part's minor axis V_z)."""

    part: int
    point: np.ndarray
    direction: np.ndarray


@dataclass
class PullAction:
    """Grasp ``part`` at ``point`` and pull it along ``direction`` for ``distance`` metres."""

    part: int
    point: np.ndarray
    direction: np.ndarray
    distance: float = PULL_DISTANCE


@dataclass
class HoldPullAction:
    """A bimanual hold (one robot) and pull (the other robot) of two different parts."""

    hold: HoldAction
    pull: PullAction
    kind: str = field(default="hold_pull", init=False)


def _clouds(clouds, name: str = "clouds") -> list[np.ndarray]:
    if not isinstance(clouds, (list, tuple)) or len(clouds) < 2:
        raise ValueError(f"{name}: need a list of at least two part clouds")
    return [check_object_cloud(c, f"{name}[{i}]") for i, c in enumerate(clouds)]


def _unit(v: np.ndarray) -> np.ndarray:
    n = float(np.linalg.norm(v))
    return v / n if n > 1e-12 else v


def push_action(
    clouds, part: int, zeta: float = 0.01, distance: float = PUSH_DISTANCE, other: int | None = None
) -> PushAction:
    """Push parameters for ``part`` from the table-plane OBB of its cloud (thesis 6.2.2).

    The push direction is the middle eigenvector ``V_y``; its sign points away from the other part's
    centroid (the pad then comes from the side between the parts; fixed so that the choice is
    deterministic). The push point lies on the face the pad enters, at mid height, shifted along
    ``V_x`` to ``zeta`` from the box end farther from the other part, so that the push line runs
    along the part's free edge (largest lever arm about a hinge near the other part).

    Args:
        clouds: world clouds of every part.
        part: index of the pushed part.
        zeta: tolerance distance from the box edge (m).
        distance: push length (m); the thesis's 10 cm.
        other: the reference part (default: the nearest other part by centroid).

    Shapes:
        clouds: list of (M_i, 3) -> :class:`PushAction`.
    """
    C = _clouds(clouds)
    n = len(C)
    if not (isinstance(part, (int, np.integer)) and 0 <= part < n):
        raise ValueError(f"part: need a part index in 0..{n - 1}, got {part!r}")
    if other is None:
        others = [i for i in range(n) if i != part]
        other = min(others, key=lambda i: np.linalg.norm(C[i].mean(0) - C[part].mean(0)))
    part, other = _pair((part, other), n, "part, other")
    zeta = as_real(zeta, "zeta", low=0.0)
    distance = as_real(distance, "distance", low=0.0, open_low=True)
    obb = oriented_bounding_box(C[part], planar=True)
    away = obb.centre - C[other].mean(0)
    vy, vx = obb.V_y, obb.V_x
    d = vy if vy[:2] @ away[:2] >= 0 else -vy
    s = 1.0 if vx[:2] @ away[:2] >= 0 else -1.0
    a, b = obb.half_extents[:2]
    point = obb.centre - b * d + s * max(a - zeta, 0.0) * vx
    return PushAction(part, point, d.copy(), float(distance))


def hold_pull_action(
    clouds,
    hold: int,
    pull: int,
    zeta: float = 0.01,
    distance: float = PULL_DISTANCE,
    min_alignment: float = np.cos(np.pi / 4),
) -> HoldPullAction:
    """Hold and pull parameters from the OBBs of the two part clouds (thesis 6.2.2, Fig. 6.3b).

    Hold: direction parallel to the hold part's minor eigenvector ``V_z`` (sign pressing down, onto
    the table), point on the face it presses, at the end of the box along ``V_x`` away from the pulled
    part, ``zeta`` from the edge (the robots act near diametrically opposite edges). Pull: direction
    parallel to the pulled part's major eigenvector ``V_x2`` and pointing away from the held part;
    point the centroid shifted along it to ``zeta`` from the box edge. When ``V_x2`` is more than
    45 deg (``min_alignment``) off the line between the parts' centroids, e.g. a drawer wider than deep,
    the pull takes the eigenvector of the pulled part closest to that line instead (a deviation from
    the thesis, whose objects slide along their length).

    Shapes:
        clouds: list of (M_i, 3) -> :class:`HoldPullAction`.
    """
    C = _clouds(clouds)
    h, p = _pair((hold, pull), len(C), "hold, pull")
    zeta = as_real(zeta, "zeta", low=0.0)
    distance = as_real(distance, "distance", low=0.0, open_low=True)
    ob_h, ob_p = oriented_bounding_box(C[h]), oriented_bounding_box(C[p])
    sep = _unit(C[p].mean(0) - C[h].mean(0))
    # hold
    dz = ob_h.V_z if ob_h.V_z[2] <= 0 else -ob_h.V_z
    sx = -1.0 if ob_h.V_x @ sep >= 0 else 1.0
    hp = ob_h.centre + sx * max(ob_h.half_extents[0] - zeta, 0.0) * ob_h.V_x - ob_h.half_extents[2] * dz
    # pull
    k = 0 if abs(ob_p.V_x @ sep) >= min_alignment else int(np.argmax(np.abs(ob_p.axes.T @ sep)))
    dp = ob_p.axes[:, k] if ob_p.axes[:, k] @ sep >= 0 else -ob_p.axes[:, k]
    pp = ob_p.centre + max(ob_p.half_extents[k] - zeta, 0.0) * dp
    return HoldPullAction(HoldAction(h, hp, dz.copy()), PullAction(p, pp, dp.copy(), float(distance)))


# ---------------------------------------------------------------------------------- belief
def action_evidence(
    action,
    T_before,
    T_after,
    parts: tuple[int, int] = (0, 1),
    rot_threshold: float = ROT_THRESHOLD,
    trans_threshold: float = TRANS_THRESHOLD,
    move_rot: float = MOVE_ROT,
    move_trans: float = MOVE_TRANS,
) -> tuple[str, RelativeMotion]:
    """What an executed action says about the joint between ``parts`` (a, b).

    Returns one of :data:`EVIDENCE` and the relative motion of b in a: ``"revolute"`` or
    ``"prismatic"`` when the relative pose changed (:func:`classify_relative_motion`); otherwise
    ``"none"`` for a push that did not move the pushed part, ``"together"`` for a push that moved the
    parts together (the heuristic's rigid-or-prismatic) and ``"rigid"`` for a hold-pull.

    Shapes:
        T_before, T_after: (N, 4, 4) T_world_part -> (str, :class:`RelativeMotion`).
    """
    T0 = _poses(T_before, "T_before")
    T1 = _poses(T_after, "T_after", len(T0))
    a, b = _pair(parts, len(T0))
    m = classify_relative_motion(
        relative_pose(T0[a], T0[b]), relative_pose(T1[a], T1[b]), rot_threshold, trans_threshold
    )
    if isinstance(action, PushAction):
        if not 0 <= action.part < len(T0):
            raise ValueError(f"action: pushed part {action.part} is not one of the {len(T0)} parts")
        if not _moved(T0[action.part], T1[action.part], move_rot, move_trans):
            return "none", m
        return ("together" if m.joint_type == "rigid" else m.joint_type), m
    if isinstance(action, HoldPullAction):
        return ("rigid" if m.joint_type == "rigid" else m.joint_type), m
    raise ValueError(f"action: need a PushAction or HoldPullAction, got {type(action).__name__}")


class ArticulationBelief:
    """Belief on the kinematic model of the pair of parts ``parts = (a, b)``, updated per action.

    States (:data:`BELIEFS`): ``unknown`` -> ``rigid_or_prismatic`` after pushes that move the parts
    together; ``rigid`` after a hold-pull without relative motion; ``revolute`` / ``prismatic`` as soon
    as a relative motion of that kind is observed (the latest wins). Evidence of no relative motion
    never overrides an observed joint: a joint at its limit, or one that a pull cannot move, keeps
    the parts together. The belief is :attr:`explored` once ``patience`` (3 in the thesis) consecutive
    updates leave it unchanged. The joint axis (and pivot) is estimated from every relative motion of
    the believed type, in the frame of part a.
    """

    def __init__(self, parts: tuple[int, int] = (0, 1), patience: int = 3):
        try:
            a, b = (int(x) for x in parts)
        except (TypeError, ValueError):
            raise ValueError(f"parts: need two part indices, got {parts!r}") from None
        if a == b or a < 0 or b < 0:
            raise ValueError(f"parts: need two different non-negative indices, got {parts!r}")
        self.parts, self.patience = (a, b), as_int(patience, "patience")
        self.state = "unknown"
        self.unchanged = 0
        self.history: list[tuple[str, str]] = []  # (evidence, state after)
        self.pushed: list[int] = []  # parts pushed, in order
        self._motions: dict[str, list[RelativeMotion]] = {"revolute": [], "prismatic": []}

    @property
    def explored(self) -> bool:
        return self.unchanged >= self.patience

    def update(self, evidence: str, motion: RelativeMotion | None = None, pushed: int | None = None) -> bool:
        """Fold in one action's evidence; returns whether the belief changed."""
        if evidence not in EVIDENCE:
            raise ValueError(f"evidence: must be one of {EVIDENCE}, got {evidence!r}")
        if evidence in ("revolute", "prismatic") and motion is not None:
            if motion.joint_type != evidence:
                raise ValueError(f"motion: a {motion.joint_type} motion cannot support {evidence!r}")
            self._motions[evidence].append(motion)
        if pushed is not None:
            self.pushed.append(int(pushed))
        old = self.state
        if evidence in ("revolute", "prismatic"):
            new = evidence
        elif evidence == "together":
            new = old if old in ("rigid", "revolute", "prismatic") else "rigid_or_prismatic"
        elif evidence == "rigid":
            new = old if old in ("revolute", "prismatic") else "rigid"
        else:
            new = old
        self.state = new
        self.unchanged = self.unchanged + 1 if new == old else 0
        self.history.append((evidence, new))
        return new != old

    @property
    def axis(self) -> np.ndarray | None:
        """(3,) joint axis in frame a, from every observed motion of the believed type, else None."""
        if self.state == "revolute" and self._motions["revolute"]:
            return revolute_axis([m.delta for m in self._motions["revolute"]])[0]
        if self.state == "prismatic" and self._motions["prismatic"]:
            return prismatic_axis(np.stack([m.displacement for m in self._motions["prismatic"]]))
        return None

    @property
    def pivot(self) -> np.ndarray | None:
        """(3,) a point of a revolute axis in frame a (least squares over the observations), else None."""
        if self.state == "revolute" and self._motions["revolute"]:
            return revolute_axis([m.delta for m in self._motions["revolute"]])[1]
        return None

    def __repr__(self) -> str:
        return (
            f"ArticulationBelief(parts={self.parts}, state={self.state!r}, unchanged={self.unchanged}, "
            f"explored={self.explored})"
        )


def choose_action(belief: ArticulationBelief) -> tuple[str, int | None]:
    """The next action, greedily in the thesis's order (6.2.2, Fig. 6.2a).

    Returns ``("push", part)`` or ``("hold_pull", None)``: a revolute belief is confirmed by pushing
    the parts in turn; an unknown or rigid-or-prismatic belief pushes each part of the pair once
    (``a`` first, then the other than the last pushed), then hold-pulls; rigid and prismatic beliefs
    are confirmed by hold-pulls.
    """
    if not isinstance(belief, ArticulationBelief):
        raise ValueError(f"belief: need an ArticulationBelief, got {type(belief).__name__}")
    a, b = belief.parts
    nxt = a if not belief.pushed or belief.pushed[-1] == b else b
    if belief.state == "revolute":
        return "push", nxt
    if belief.state in ("rigid", "prismatic"):
        return "hold_pull", None
    if {a, b} <= set(belief.pushed):
        return "hold_pull", None
    return "push", nxt


# ---------------------------------------------------------------------------------- the loop
@dataclass
class ArticulationStep:
    """One executed action: the action, its evidence, the relative motion and the belief after it."""

    action: PushAction | HoldPullAction
    evidence: str
    motion: RelativeMotion
    heuristic: str
    belief: str


@dataclass
class ArticulationResult:
    """Outcome of :func:`detect_articulation`.

    Attributes:
        joint_type: the final belief (one of :data:`BELIEFS`).
        explored: the belief met the stopping rule (else ``max_actions`` ran out).
        axis_a, pivot_a: (3,) joint axis and pivot in the frame of part a (None when not applicable).
        axis_world, pivot_world: the same in the world, at the last observed pose of part a.
        steps: the actions in order.
    """

    joint_type: str
    explored: bool
    axis_a: np.ndarray | None
    pivot_a: np.ndarray | None
    axis_world: np.ndarray | None
    pivot_world: np.ndarray | None
    steps: list[ArticulationStep]
    belief: ArticulationBelief

    @property
    def n_actions(self) -> int:
        return len(self.steps)


def _hold_part(clouds: list[np.ndarray], a: int, b: int) -> tuple[int, int]:
    """Hold the part with the larger OBB footprint (the heavier, harder to pull), pull the other."""

    def area(i):
        e = oriented_bounding_box(clouds[i]).half_extents
        return e[0] * e[1]

    return (a, b) if area(a) >= area(b) else (b, a)


def detect_articulation(
    observe: Callable[[], tuple[list[np.ndarray], np.ndarray]],
    execute: Callable[[PushAction | HoldPullAction], None],
    parts: tuple[int, int] = (0, 1),
    max_actions: int = 12,
    zeta: float = 0.01,
    push_distance: float = PUSH_DISTANCE,
    pull_distance: float = PULL_DISTANCE,
    rot_threshold: float = ROT_THRESHOLD,
    trans_threshold: float = TRANS_THRESHOLD,
    patience: int = 3,
) -> ArticulationResult:
    """Interactive articulation detection (thesis 6.2.2, Fig. 6.2a): act, track, update, until explored.

    Args:
        observe: returns the world clouds of every part and their poses ``T_world_part`` (the part
            segmentation and ArtReg of the thesis; any tracker will do).
        execute: performs an action (robot or simulation).
        parts: the pair (a, b) whose joint is sought; axes are expressed in part a.
        max_actions: stop after this many actions even if not explored.
        zeta, push_distance, pull_distance: action parameters (thesis: 10 cm push, 5 cm pull).
        rot_threshold, trans_threshold: relative-motion thresholds of :func:`classify_relative_motion`.
        patience: unchanged updates for the belief to be explored (thesis: 3).

    Shapes:
        observe() -> (list of (M_i, 3), (N, 4, 4)) -> :class:`ArticulationResult`.
    """
    if not (callable(observe) and callable(execute)):
        raise ValueError("observe, execute: need two callables")
    max_actions = as_int(max_actions, "max_actions")
    belief = ArticulationBelief(parts, patience)
    a, b = belief.parts
    steps: list[ArticulationStep] = []
    clouds, T0 = observe()
    T0 = _poses(T0, "observe()[1]")
    _pair(parts, len(T0))
    while len(steps) < max_actions and not belief.explored:
        kind, part = choose_action(belief)
        if kind == "push":
            action = push_action(clouds, part, zeta, push_distance, other=b if part == a else a)
        else:
            action = hold_pull_action(clouds, *_hold_part(_clouds(clouds), a, b), zeta, pull_distance)
        execute(action)
        clouds, T1 = observe()
        T1 = _poses(T1, "observe()[1]", len(T0))
        evidence, motion = action_evidence(action, T0, T1, (a, b), rot_threshold, trans_threshold)
        if kind == "push":
            heur = push_heuristic(T0, T1, part, rot_threshold=rot_threshold, trans_threshold=trans_threshold)
        else:
            h, p = action.hold.part, action.pull.part
            heur = hold_pull_heuristic(T0, T1, h, p, rot_threshold, trans_threshold)
        belief.update(evidence, motion, pushed=part if kind == "push" else None)
        steps.append(ArticulationStep(action, evidence, motion, heur, belief.state))
        T0 = T1
    axis, pivot = belief.axis, belief.pivot
    R, t = T0[a][:3, :3], T0[a][:3, 3]
    return ArticulationResult(
        belief.state,
        belief.explored,
        axis,
        pivot,
        None if axis is None else R @ axis,
        None if pivot is None else R @ pivot + t,
        steps,
        belief,
    )


# ---------------------------------------------------------------------------------- simulation
class KinematicArticulationSim:
    """Executes push and hold-pull actions on an :class:`~vtlearn.sim_data.articulated.ArticulatedObject`
    with its true kinematics (a stand-in for the robots, not a contact simulation).

    * push on the base link, or on a link with a fixed joint: the whole object translates by the push;
    * push on a revolute link: its joint turns by the angle that moves the push point ``distance``
      along the push direction to first order (``dphi = s (v . d) / |v|^2``, ``v = u x (p - c)``);
    * push on a prismatic link: the component along the joint axis moves the joint, the rest (and
      whatever a joint limit blocks) moves the whole object;
    * hold-pull: on a prismatic joint the pull moves the pulled part along the axis by the pull's
      component along it (the held part stays); a revolute or fixed joint does not move.

    Joint values are clipped to their limits; a push that a limit blocks moves the whole object.
    Hold-pulls need a pair that includes the base link (index 0).

    Args:
        obj: the object (loaded in its scene).
        T_world_base: (4, 4) initial base pose.
        q: (J,) initial normalised joint values in [0, 1] (ignored for fixed joints).
        pose_noise: (translation std in m, rotation std in rad) of Gaussian noise on observed poses.
        seed: seed of the observation noise.

    Shapes:
        observe() -> (list of (K_i, 3) world clouds, (N, 4, 4) T_world_part).
    """

    def __init__(
        self, obj, T_world_base, q=None, pose_noise: tuple[float, float] = (0.0, 0.0), seed: int = 0
    ):
        self.obj = obj
        self.T_base = as_transform(T_world_base, "T_world_base").copy()
        J = obj.spec.n_joints
        self.q = np.zeros(J) if q is None else np.asarray(q, dtype=np.float64).copy()
        if self.q.shape != (J,) or not np.all((self.q >= 0) & (self.q <= 1)):
            raise ValueError(f"q: need {J} values in [0, 1], got {q}")
        sig = np.asarray(pose_noise, dtype=np.float64)
        if sig.shape != (2,) or not (np.isfinite(sig).all() and (sig >= 0).all()):
            raise ValueError(f"pose_noise: need (translation std, rotation std) >= 0, got {pose_noise}")
        self.pose_noise, self.rng = sig, np.random.default_rng(seed)
        self._apply()

    def _apply(self) -> None:
        self.obj.set_state(self.T_base, self.q)

    def true_poses(self) -> np.ndarray:
        """(N, 4, 4) noiseless T_world_part."""
        return self.obj.part_poses()

    def observe(self) -> tuple[list[np.ndarray], np.ndarray]:
        T = self.true_poses()
        clouds = [m @ Ti[:3, :3].T + Ti[:3, 3] for m, Ti in zip(self.obj.models, T, strict=True)]
        if self.pose_noise.any():
            T = T.copy()
            for i in range(len(T)):
                dR = so3_exp(self.rng.normal(scale=self.pose_noise[1], size=3))
                T[i, :3, :3] = np.asarray(dR) @ T[i, :3, :3]
                T[i, :3, 3] += self.rng.normal(scale=self.pose_noise[0], size=3)
        return clouds, T

    def _joint(self, part: int) -> tuple[object, np.ndarray, np.ndarray, float]:
        link = self.obj.spec.links[part]
        u = self.T_base[:3, :3] @ _unit(np.asarray(link.axis, dtype=np.float64))
        c = self.T_base[:3, :3] @ np.asarray(link.joint_xyz, dtype=np.float64) + self.T_base[:3, 3]
        return link, u, c, float(link.upper - link.lower)

    def _move_joint(self, j: int, dq_metric: float, rng_: float) -> float:
        """Advance joint ``j`` by ``dq_metric`` (rad or m), clipped; returns the realised amount."""
        q_new = float(np.clip(self.q[j] + dq_metric / rng_, 0.0, 1.0))
        done = (q_new - self.q[j]) * rng_
        self.q[j] = q_new
        return done

    def execute(self, action) -> None:
        if isinstance(action, PushAction):
            self._push(action)
        elif isinstance(action, HoldPullAction):
            self._hold_pull(action)
        else:
            raise ValueError(f"action: need a PushAction or HoldPullAction, got {type(action).__name__}")
        self._apply()

    def _push(self, a: PushAction) -> None:
        n = self.obj.n_parts
        if not 0 <= a.part < n:
            raise ValueError(f"action: part {a.part} is not one of the {n} parts")
        move = a.distance * _unit(np.asarray(a.direction, dtype=np.float64))
        if a.part > 0:
            link, u, c, rng_ = self._joint(a.part)
            j = a.part - 1
            if link.joint_type == "revolute" and rng_ > 0:
                v = np.cross(u, np.asarray(a.point) - c)
                if v @ v > 1e-10 and abs(self._move_joint(j, float(move @ v) / float(v @ v), rng_)) > 1e-9:
                    return
            elif link.joint_type == "prismatic" and rng_ > 0:
                move = move - self._move_joint(j, float(move @ u), rng_) * u
        self.T_base[:3, 3] += move

    def _hold_pull(self, a: HoldPullAction) -> None:
        h, p = a.hold.part, a.pull.part
        n = self.obj.n_parts
        _pair((h, p), n, "action: hold, pull")
        if 0 not in (h, p):
            raise ValueError(f"action: the hold-pull simulation needs the base link (0) among {(h, p)}")
        child = p if p != 0 else h
        link, u, _, rng_ = self._joint(child)
        if link.joint_type != "prismatic" or rng_ <= 0:
            return
        along = a.pull.distance * float(_unit(np.asarray(a.pull.direction, dtype=np.float64)) @ u)
        if p == child:
            self._move_joint(child - 1, along, rng_)
        else:  # the base is pulled, the child held: the base slides, the joint closes by as much
            self.T_base[:3, 3] -= self._move_joint(child - 1, -along, rng_) * u


class TrackedArticulationSim:
    """A :class:`KinematicArticulationSim` seen through a simulated depth camera and tracked by ArtReg,
    the thesis's loop (6.2.2: "the object(s) were tracked using ArtReg, and the change in relative pose
    after performing the action was used to infer the joint type").

    Every action is replayed as ``frames_per_action`` intermediate states, with the joint values and the
    base position interpolated linearly, as the robot moves the part. Each state is rendered by an
    RGB-D camera 45 degrees above the object (:func:`~vtlearn.sim_data.articulated.look_at_45`, Kinect-like
    noise), the table is removed, and the cloud is one step of an
    :class:`~vtlearn.classical.artreg.ArtRegTracker`. The tracker starts from the link model clouds at
    the true initial poses: the part segmentation at t = 0, as in the tracking benchmark.
    :meth:`observe` returns the *tracked* poses, so :func:`detect_articulation` sees what the tracker
    sees, its errors included.

    Args:
        sim: the kinematic simulation that executes the actions (its ``pose_noise`` is not used).
        frames_per_action: camera frames during an action (a 10 cm push at 25 frames moves 4 mm a frame,
            within ArtReg's default random walk of 5 mm).
        settle_frames: frames of the object at rest after the action, before it is observed: the
            random-walk filter lags a moving part and catches up once it stops.
        camera: the :class:`~vtlearn.sim_data.camera.RGBDCamera` (default 320 x 240, 50 deg, noisy).
        T_world_camera: the camera pose (default: 45 deg above the base, far enough for a few pushes).
        seed: seed of the camera noise and of the tracker's subsampling.
        **tracker_kwargs: passed to :class:`~vtlearn.classical.artreg.ArtRegTracker`.

    Shapes:
        observe() -> (list of (K_i, 3) model clouds at the tracked poses, (N, 4, 4) tracked T_world_part).
    """

    def __init__(
        self,
        sim: KinematicArticulationSim,
        *,
        frames_per_action: int = 25,
        settle_frames: int = 8,
        camera=None,
        T_world_camera: np.ndarray | None = None,
        seed: int = 0,
        **tracker_kwargs,
    ):
        from vtlearn.classical.artreg import ArtRegTracker
        from vtlearn.sim_data.articulated import look_at_45
        from vtlearn.sim_data.camera import RGBDCamera

        if not isinstance(sim, KinematicArticulationSim):
            raise ValueError(f"sim: need a KinematicArticulationSim, got {type(sim).__name__}")
        frames_per_action = as_int(frames_per_action, "frames_per_action")
        settle_frames = as_int(settle_frames, "settle_frames", minimum=0)
        self.sim, self.frames_per_action, self.settle_frames = sim, frames_per_action, settle_frames
        self.camera = camera if camera is not None else RGBDCamera(320, 240, fov_y_deg=50.0)
        size = float(np.max(sim.obj.spec.links[0].mesh().extents))
        self.T_world_camera = (
            look_at_45(sim.T_base[:3, 3] + [0.0, 0.0, 0.3 * size], distance=max(0.5, 3.0 * size))
            if T_world_camera is None
            else as_transform(T_world_camera, "T_world_camera")
        )
        self.rng = np.random.default_rng(seed)
        T0 = sim.true_poses()
        self.models = self._visible_models(T0)
        self.tracker = ArtRegTracker(self.models, list(T0), seed=seed, **tracker_kwargs)
        self.frames = 0
        self.errors_mm: list[float] = []  # per frame: the largest part-origin error of the tracker
        self._T = np.stack(self.tracker.poses)
        self._track()

    def _visible_models(self, T0: np.ndarray, tol: float = 0.005) -> list[np.ndarray]:
        """Each link's model points that the camera sees at t = 0 (within ``tol`` of the rendered depth),
        in the link frame: the segmented cloud at t = 0 that ArtReg takes as its model (thesis 6.2.3).
        Matching a whole-surface model to a one-sided view biases the closest-point measurement."""
        frame = self.camera.render(self.sim.obj.scene, self.T_world_camera, np.random.default_rng(0))
        T_cam_world = np.linalg.inv(self.T_world_camera)
        H, W = frame.depth.shape
        out = []
        for m, T in zip(self.sim.obj.models, T0, strict=True):
            pc = (m @ T[:3, :3].T + T[:3, 3]) @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
            uv = pc[:, :2] / pc[:, 2:3] * np.diag(frame.K)[:2] + frame.K[:2, 2] - 0.5
            u, v = np.round(uv[:, 0]).astype(int), np.round(uv[:, 1]).astype(int)
            inside = (pc[:, 2] > 0) & (u >= 0) & (u < W) & (v >= 0) & (v < H)
            seen = np.zeros(len(m), dtype=bool)
            seen[inside] = np.abs(frame.depth[v[inside], u[inside]] - pc[inside, 2]) < tol
            out.append(m[seen] if seen.sum() >= 3 else m)
        return out

    def _track(self) -> None:
        from vtlearn.sim_data.articulated import render_cloud

        scene = self.sim.obj.scene
        cloud = render_cloud(scene, self.camera, self.T_world_camera, {scene.table_id}, self.rng)
        self._T = np.stack(self.tracker.step(cloud))
        self.frames += 1
        err = np.linalg.norm(self._T[:, :3, 3] - self.sim.true_poses()[:, :3, 3], axis=1)
        self.errors_mm.append(1000.0 * float(err.max()))

    def observe(self) -> tuple[list[np.ndarray], np.ndarray]:
        T = self._T.copy()
        clouds = [m @ Ti[:3, :3].T + Ti[:3, 3] for m, Ti in zip(self.sim.obj.models, T, strict=True)]
        return clouds, T

    def execute(self, action) -> None:
        base0, q0 = self.sim.T_base.copy(), self.sim.q.copy()
        self.sim.execute(action)
        base1, q1 = self.sim.T_base.copy(), self.sim.q.copy()
        for k in range(1, self.frames_per_action + self.settle_frames + 1):
            s = min(k / self.frames_per_action, 1.0)
            T = base1.copy()
            T[:3, 3] = (1 - s) * base0[:3, 3] + s * base1[:3, 3]  # the kinematic sim only translates the base
            self.sim.obj.set_state(T, (1 - s) * q0 + s * q1)
            self._track()
