"""Next-best-touch for recognition by expected class-entropy reduction (beyond the thesis; compare
thesis 7.2.4, eq. 7.11-7.12, which scores touches by the occupancy-grid gain).

The grid gain of eq. 7.11 rewards touches that explain the most unknown space; for recognition that is
the wrong target (docs/active_perception.md: the chosen touches cluster, and the classifier is then at
chance). This module scores a touch by how much it is expected to reduce the entropy of the classifier's
own posterior, in the style of model-based active recognition (Denzler & Brown 2002, "Information
theoretic sensor data selection for active object recognition and state estimation", IEEE TPAMI):

1. ``p₀ = p(c | P)``: the xAVTNet posterior of the tactile points ``P`` measured so far (uniform while
   fewer than 3 points are known).
2. Hypotheses: the ``top_m`` classes under ``p₀``. Each class ``c`` has ``templates_per_class`` template
   shapes, procedural instances of that category from their own seed range (the robot's library of class
   models, never a held-out object), fitted into the object's known bounding box (the box the action
   samplers use). Every (class, template) pair is a hypothesis ``h``; a class's weight is shared equally
   by its templates, so several templates marginalise the instance shape out of the class hypothesis.
3. The expected measurement ``ŷ(a, c)`` of candidate ``a`` under hypothesis ``c`` is the guarded touch of
   :class:`~vtlearn.sim_data.tactile.TactileSimulator` replayed on the template: the taxel rays are cast,
   the pad stops ``τ_f / k`` past the first contact, and every taxel pressed with at least the minimum
   force reports its ray's hit point.
4. With ``q_c = p(· | P ∪ ŷ(a, c))`` and hypothesis weights ``w_c``, two criteria (nats):

   - ``"mutual_information"`` (default): ``I(a) = H[Σ_h w_h q_h] − Σ_h w_h H[q_h]``, the information the
     touch carries about which hypothesis is true, as judged by the classifier. It is zero when every
     hypothesis leads to the same posterior (the touch cannot tell them apart), and it does not reward
     a touch for making an already confident classifier more confident.
   - ``"expected_entropy"``: ``IG(a) = H[p₀] − Σ_h w_h H[q_h]``, the expected entropy reduction of
     Denzler & Brown. With an over-confident classifier it locks in its first guess (gains ≈ 0 once
     ``p₀`` is peaked), which docs/active_perception.md measures.

   ``weights="uniform"`` (default) gives every hypothesis the same weight, ``"posterior"`` uses the
   renormalised ``p₀``. The touch with the largest gain is taken; with one sensor kind the energy cost
   of eq. 5.10 is a constant and does not change the choice.

All candidate hypotheses are scored in one batched forward pass of the classifier.

Frames and units: world frame, metres, as in :mod:`vtlearn.active.closed_loop`; the classifier sees the
canonical, centred cloud of :func:`~vtlearn.active.closed_loop.classify_clouds`.

Shapes:
    points_world ``(M, 3)``; candidates ``A`` pad poses ``(A, 4, 4)``; gains ``(A,)``.
"""

from __future__ import annotations

import numpy as np

from vtlearn.validation import as_int

__all__ = ["CRITERIA", "TEMPLATE_SEED", "ExpectedClassEntropyGain", "fit_to_box"]

CRITERIA = ("mutual_information", "expected_entropy")

# Base seed of the class templates: another SeedSequence than the training data (dataset seeds) and the
# held-out objects (closed_loop.HELD_OUT_SEED), so a template is never the object being recognised.
TEMPLATE_SEED = 2_000_029


def fit_to_box(vertices: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Scale and shift ``vertices`` per axis so that their bounding box becomes ``[lo, hi]``.

    Shapes:
        vertices (V, 3), lo (3,), hi (3,) -> (V, 3)
    """
    v = np.asarray(vertices, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) < 4:
        raise ValueError(f"vertices: need shape (V >= 4, 3), got {v.shape}")
    vlo, vhi = v.min(0), v.max(0)
    if np.any(vhi - vlo <= 0):
        raise ValueError("vertices: degenerate bounding box (zero extent along an axis)")
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    if np.any(hi - lo <= 0):
        raise ValueError(f"lo, hi: need hi > lo on every axis, got {lo}, {hi}")
    return lo + (v - vlo) / (vhi - vlo) * (hi - lo)


def _entropy(p: np.ndarray) -> np.ndarray:
    p = np.clip(p, 1e-12, 1.0)
    return -(p * np.log(p)).sum(-1)


class ExpectedClassEntropyGain:
    """Expected reduction of the class entropy for candidate touches (module docstring, steps 1-4).

    Args:
        model: an :class:`~vtlearn.models.xavtnet.XAVTNet` (eval mode is set here).
        class_names: the model's class names, in output order; a class whose procedural category is
            unknown gets no template and is never a hypothesis.
        top_m: hypotheses per step (the most probable classes).
        max_points: classifier input size (:func:`~vtlearn.active.closed_loop.network_input`).
        criterion: ``"mutual_information"`` or ``"expected_entropy"`` (module docstring, step 4).
        weights: ``"uniform"`` or ``"posterior"`` hypothesis weights.
        template_seed: base seed of the class templates.
        sections: mesh resolution of the templates.
        templates_per_class: template instances per class hypothesis (step 2); the classifier is run
            ``top_m · templates_per_class`` times per candidate.
    """

    def __init__(self, model, class_names, top_m: int = 4, max_points: int = 256,
                 criterion: str = "mutual_information", weights: str = "uniform",
                 template_seed: int = TEMPLATE_SEED, sections: int = 32,
                 templates_per_class: int = 1) -> None:
        from vtlearn.sim_data.shapes import CATEGORIES

        top_m = as_int(top_m, "top_m")
        templates_per_class = as_int(templates_per_class, "templates_per_class")
        max_points = as_int(max_points, "max_points", minimum=3)
        if criterion not in CRITERIA:
            raise ValueError(f"criterion: expected one of {CRITERIA}, got {criterion!r}")
        if weights not in ("uniform", "posterior"):
            raise ValueError(f"weights: expected 'uniform' or 'posterior', got {weights!r}")
        self.criterion, self.weights = criterion, weights
        names = list(class_names)
        if len(names) != int(model.hparams.num_classes):
            raise ValueError(
                f"class_names: the model has {model.hparams.num_classes} classes, got {len(names)} names"
            )
        self.model = model.eval()
        self.class_names = names
        self.top_m, self.max_points = int(top_m), int(max_points)
        self.template_seed, self.sections = int(template_seed), int(sections)
        self.templates_per_class = int(templates_per_class)
        self.template_classes = [i for i, c in enumerate(names) if c in CATEGORIES]
        if not self.template_classes:
            raise ValueError(f"class_names: none of {names} is a procedural category, so no templates")
        self._templates: dict[tuple[int, int], object] = {}  # (class, template) -> canonical trimesh
        self._scenes: dict = {}  # (object key, class, template) -> Open3D RaycastingScene, world frame

    def _template(self, c: int, j: int = 0):
        if (c, j) not in self._templates:
            from vtlearn.sim_data.shapes import generate_shape, instance_seed

            name = self.class_names[c]
            mesh, _ = generate_shape(name, instance_seed(self.template_seed, name, j), self.sections)
            self._templates[(c, j)] = mesh
        return self._templates[(c, j)]

    def _scene(self, obj, c: int, j: int = 0):
        import open3d as o3d

        key = (obj.category, obj.seed, c, j)
        if key not in self._scenes:
            mesh = self._template(c, j)
            lo, hi = obj.bounds
            v = fit_to_box(mesh.vertices, lo, hi)
            scene = o3d.t.geometry.RaycastingScene()
            scene.add_triangles(o3d.core.Tensor(v.astype(np.float32)),
                                o3d.core.Tensor(np.asarray(mesh.faces).astype(np.uint32)))
            if len(self._scenes) > 64:
                self._scenes.clear()
            self._scenes[key] = scene
        return self._scenes[key]

    def posterior(self, obj, points_world: np.ndarray) -> np.ndarray:
        """``p(c | P)`` of the measured tactile points; uniform with fewer than 3 points. Shapes: (C,)"""
        from vtlearn.active.closed_loop import classify_clouds

        p = classify_clouds(self.model, obj, [points_world], self.max_points)[0]
        if not np.isfinite(p).all():
            return np.full(len(self.class_names), 1.0 / len(self.class_names))
        return p

    def expected_contacts(
        self, obj, c: int, sensor, T_world_pad: np.ndarray, touch_config, template: int = 0
    ) -> list[np.ndarray]:
        """Contact points ``ŷ(a, c)`` (world) of each pad pose on class ``c``'s template number
        ``template`` (step 3).

        Replays :meth:`~vtlearn.sim_data.tactile.TactileSimulator.touch_from` on the template standing on
        the table plane z = 0: taxel and housing rays up to ``max_travel``; the pad stops ``τ_f / k``
        past the first surface any of them meets; a taxel whose ray met the template at most that far
        (and within ``sensor.ray_length``, as :meth:`~vtlearn.active.closed_loop.TouchWorld.press`
        reports) with at least ``min_force`` reports its hit point. Rays that start inside the table slab
        (a pad pressed sideways at the foot of the object) are not stopped by it here; Bullet stops some
        of them at once, so near the table the prediction can have contacts the simulator does not.

        Shapes:
            T_world_pad (A, 4, 4) -> A arrays (n_a, 3)
        """
        import open3d as o3d

        T = np.asarray(T_world_pad, dtype=np.float64).reshape(-1, 4, 4)
        taxels = sensor.layout.taxel_positions()
        local = np.concatenate([taxels, sensor.layout.housing_positions()])
        k, n = len(taxels), len(local)
        R, o = T[:, :3, :3], T[:, :3, 3]
        d = np.repeat(R[:, :, 2], n, axis=0)  # (A*n, 3)
        starts = (np.einsum("nj,aij->ani", local, R) + o[:, None]).reshape(-1, 3)
        q = np.concatenate([starts, d], 1).astype(np.float32)
        hits = self._scene(obj, c, template).cast_rays(o3d.core.Tensor(q))
        t_obj = hits["t_hit"].numpy().astype(np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            t_table = np.where(d[:, 2] < 0, -starts[:, 2] / d[:, 2], np.inf)
        t_obj = np.where(np.isfinite(t_obj) & (t_obj <= touch_config.max_travel), t_obj, np.inf)
        t_table = np.where(t_table >= 0, t_table, np.inf)
        t_obj, t_any = t_obj.reshape(-1, n), np.minimum(t_obj, t_table).reshape(-1, n)
        first = t_any.min(1, keepdims=True)  # inf where the pad meets nothing
        stop = np.minimum(np.where(np.isfinite(first), first, -np.inf)
                          + touch_config.force_threshold / touch_config.stiffness, touch_config.max_travel)
        tk = t_obj[:, :k]
        on_object = np.isfinite(tk) & (tk <= t_table.reshape(-1, n)[:, :k])
        pressed = on_object & (touch_config.stiffness * (stop - tk) >= touch_config.min_force)
        pressed &= tk <= sensor.ray_length
        along = np.where(pressed, tk, 0.0)[..., None] * d.reshape(-1, n, 3)[:, :k]
        pts = starts.reshape(-1, n, 3)[:, :k] + along
        return [pts[a][pressed[a]] for a in range(len(T))]

    def gains(self, obj, points_world: np.ndarray, sensor, T_world_pad: np.ndarray, touch_config,
              seed: int = 0) -> np.ndarray:
        """The criterion of step 4 for every candidate pad pose (nats).

        Args:
            points_world: the tactile points measured so far (world frame).
            sensor: the :class:`~vtlearn.active.sensors.TactileArray` of the candidates.
            T_world_pad: ``(A, 4, 4)`` candidate pad poses.
            touch_config: the simulator's contact model (``force_threshold``, ``stiffness``, ``min_force``).

        Shapes:
            points_world (M, 3), T_world_pad (A, 4, 4) -> (A,)
        """
        from vtlearn.active.closed_loop import classify_clouds

        P = np.asarray(points_world, dtype=np.float64).reshape(-1, 3)
        T = np.asarray(T_world_pad, dtype=np.float64)
        if T.ndim != 3 or T.shape[1:] != (4, 4) or len(T) == 0:
            raise ValueError(f"T_world_pad: need shape (A >= 1, 4, 4), got {T.shape}")
        p0 = self.posterior(obj, P)
        hyp = [c for c in np.argsort(-p0) if c in self.template_classes][: self.top_m]
        if self.weights == "uniform":
            w = np.full(len(hyp), 1.0 / len(hyp))
        else:
            w = p0[hyp] / max(p0[hyp].sum(), 1e-12)
        k = self.templates_per_class
        w = np.repeat(w / k, k)  # (class, template) hypotheses share their class's weight
        clouds = []
        for c in hyp:
            for j in range(k):
                for y in self.expected_contacts(obj, int(c), sensor, T, touch_config, template=j):
                    clouds.append(np.concatenate([P, y]) if len(y) else P)
        probs = classify_clouds(self.model, obj, clouds, self.max_points, seed=seed)
        probs = np.where(np.isfinite(probs).all(1, keepdims=True), probs, p0[None])  # < 3 points: no change
        q = probs.reshape(len(w), len(T), -1)
        expected = (w[:, None] * _entropy(q)).sum(0)
        if self.criterion == "expected_entropy":
            return _entropy(p0) - expected
        return _entropy(np.einsum("h,hac->ac", w, q)) - expected
