"""Next-best-touch for recognition by the expected novelty of the contacts (beyond the thesis; compare
thesis 7.2.4, eq. 7.9-7.12, which scores touches by the occupancy-grid gain of eq. 7.11 and takes the
``argmax`` of eq. 7.12).

Thesis 7.2.4 keeps the procedure of Algorithm 5: start from random touches (eq. 7.9), update the grid
with every touch (eq. 7.10), score the candidate touches (eq. 7.11) and take the best (eq. 7.12), and
stop once the classifier is confident. Only the score of eq. 7.11 is replaced here.

Why: a greedy oracle that presses every candidate for real and keeps the one that raises the true
class's probability the most reaches the confidence stop in far fewer touches than random ones. Over the
candidates it scores, the touches that help while the classifier is still wrong are the ones whose
contacts land far from every point measured so far; the grid gain instead sends the next touch next to
the last one (docs/active_perception.md). Novelty needs no label, but it needs the contacts before the
touch is made, so they are predicted on class templates:

1. ``p₀ = p(c | P)``: the xAVTNet posterior of the tactile points ``P`` measured so far (uniform while
   fewer than 3 points are known).
2. Hypotheses: the ``top_m`` most probable classes. Each is a template shape, a procedural instance of
   that category from its own seed range (never a held-out object), fitted into the object's known
   bounding box (:class:`~vtlearn.active.recognition_nbt.ExpectedClassEntropyGain`).
3. ``ŷ(a, c)``: the guarded touch of candidate ``a`` replayed on the template of class ``c``
   (:meth:`~vtlearn.active.recognition_nbt.ExpectedClassEntropyGain.expected_contacts`).
4. The novelty of contacts ``Y`` given ``P``, in the canonical frame of the box (centred, largest extent
   1), is ``ν(Y | P) = (1/|Y|) Σ_{y∈Y} min_{x∈P} ‖y − x‖``; ``ν = 0`` for a miss (no contact) and
   ``ν = 1`` (one largest box extent) for any contact while ``P`` is empty. The gain is the mean over the
   hypotheses, ``G(a) = (1/m) Σ_c ν(ŷ(a, c) | P)``, and the touch with the largest gain is taken; with
   one sensor kind the energy cost of eq. 5.10 is a constant and does not change the choice.

Beyond the thesis: the classifier is used only to pick the hypotheses, and the touch is scored by where
its contacts are expected to land, not by a grid's information gain or by the classifier's output on the
predicted cloud (the latter is :mod:`~vtlearn.active.recognition_nbt`). Averaging over several class
shapes makes a touch that misses on some of them score lower. The measurements (the oracle's headroom,
the criteria tried, this one against random on objects it was not developed on) are in
docs/active_perception.md.

Frames and units: world frame, metres, as in :mod:`vtlearn.active.closed_loop`; novelty is in canonical
units (fractions of the largest box extent).

Shapes:
    points_world ``(M, 3)``; candidates ``A`` pad poses ``(A, 4, 4)``; gains ``(A,)``.
"""

from __future__ import annotations

import numpy as np
import torch

__all__ = ["ExpectedContactNovelty", "contact_novelty"]


def contact_novelty(measured: np.ndarray, contacts: np.ndarray) -> float:
    """``ν(Y | P)`` of step 4: mean distance of each contact to its nearest measured point.

    Args:
        measured: ``P``, the points measured so far (any frame; the canonical one in the criterion).
        contacts: ``Y``, the contacts of one touch, in the same frame.

    Returns:
        0 when ``contacts`` is empty, 1 when only ``measured`` is empty.

    Shapes:
        measured (M, 3), contacts (N, 3) -> scalar
    """
    P = np.asarray(measured, dtype=np.float64)
    Y = np.asarray(contacts, dtype=np.float64)
    for name, a in (("measured", P), ("contacts", Y)):
        if a.ndim != 2 or a.shape[1] != 3:
            raise ValueError(f"{name}: need shape (N, 3), got {a.shape}")
        if not np.isfinite(a).all():
            raise ValueError(f"{name}: contains NaN or inf")
    if len(Y) == 0:
        return 0.0
    if len(P) == 0:
        return 1.0
    d = torch.cdist(torch.from_numpy(Y), torch.from_numpy(P))  # N x M
    return float(d.min(1).values.mean())


class ExpectedContactNovelty:
    """The gain ``G(a)`` of the module docstring (steps 1-4) for an xAVTNet ``model``.

    Args:
        model: an :class:`~vtlearn.models.xavtnet.XAVTNet` (eval mode is set here).
        class_names: the model's class names, in output order; a class whose procedural category is
            unknown gets no template and is never a hypothesis.
        top_m: class hypotheses per step (step 2).
        max_points: classifier input size for the posterior of step 1.
        template_seed: base seed of the class templates
            (:data:`~vtlearn.active.recognition_nbt.TEMPLATE_SEED` by default).
        sections: mesh resolution of the templates.
        library: an :class:`~vtlearn.active.recognition_nbt.ExpectedClassEntropyGain` of the same model to
            take the posterior and templates from (its template 0 of each class), so that a run with both
            criteria builds each template once; ``template_seed`` and ``sections`` are then its own.
    """

    def __init__(self, model, class_names, top_m: int = 4, max_points: int = 256,
                 template_seed: int | None = None, sections: int = 32, library=None) -> None:
        from vtlearn.active.recognition_nbt import TEMPLATE_SEED, ExpectedClassEntropyGain

        # The template library, the posterior and the replayed touch are those of the recognition
        # criterion; its argument checks (top_m, max_points, class_names) apply here too.
        if library is None:
            library = ExpectedClassEntropyGain(
                model, class_names, top_m=top_m, max_points=max_points,
                template_seed=TEMPLATE_SEED if template_seed is None else template_seed, sections=sections,
            )
        elif not isinstance(library, ExpectedClassEntropyGain):
            raise ValueError(f"library: need an ExpectedClassEntropyGain, got {type(library).__name__}")
        elif library.model is not model or (library.top_m, library.max_points) != (int(top_m),
                                                                                     int(max_points)):
            raise ValueError("library: must wrap the same model with the same top_m and max_points")
        self.templates = library
        self.top_m = library.top_m

    def hypotheses(self, obj, points_world: np.ndarray) -> list[int]:
        """Step 2: the ``top_m`` most probable classes that have a template, most probable first."""
        p0 = self.templates.posterior(obj, points_world)
        return [int(c) for c in np.argsort(-p0) if c in self.templates.template_classes][: self.top_m]

    def gains(self, obj, points_world: np.ndarray, sensor, T_world_pad: np.ndarray, touch_config,
              seed: int = 0) -> np.ndarray:
        """``G(a)`` for every candidate pad pose (canonical units).

        Args:
            obj: the :class:`~vtlearn.active.closed_loop.SimObject` (its bounding box and frames).
            points_world: the tactile points measured so far (world frame).
            sensor: the :class:`~vtlearn.active.sensors.TactileArray` of the candidates.
            T_world_pad: ``(A, 4, 4)`` candidate pad poses.
            touch_config: the simulator's contact model (``force_threshold``, ``stiffness``, ``min_force``).
            seed: unused (the criterion has no random step); kept so that ``run_episode`` calls every
                recognition criterion alike.

        Shapes:
            points_world (M, 3), T_world_pad (A, 4, 4) -> (A,)
        """
        P = np.asarray(points_world, dtype=np.float64)
        if P.ndim != 2 or P.shape[1] != 3 or not np.isfinite(P).all():
            raise ValueError(f"points_world: need finite (M, 3), got shape {P.shape}")
        T = np.asarray(T_world_pad, dtype=np.float64)
        if T.ndim != 3 or T.shape[1:] != (4, 4) or len(T) == 0:
            raise ValueError(f"T_world_pad: need shape (A >= 1, 4, 4), got {T.shape}")
        P_canonical = obj.to_canonical(P)
        novelty = np.zeros((0, len(T)))
        for c in self.hypotheses(obj, P):
            ys = self.templates.expected_contacts(obj, c, sensor, T, touch_config)
            row = [contact_novelty(P_canonical, obj.to_canonical(y) if len(y) else np.zeros((0, 3)))
                   for y in ys]
            novelty = np.concatenate([novelty, np.asarray(row)[None]])
        return novelty.mean(0)
