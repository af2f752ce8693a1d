"""The classical vision-to-touch baseline of thesis Table 7.4: a hand-crafted global descriptor of each
cloud, the Geodesic Flow Kernel between the visual and tactile descriptor subspaces, and a 1-NN or SVM
classifier trained on the labelled visual clouds (Falco et al. 2019's CLUE+GFK+1NN / +SVM, which the thesis
re-implemented with PCL and a MATLAB toolbox and scored at 26.72 % and 15.05 %).

Falco et al.'s CLUE descriptor is not public, so PCL's global descriptor for partial views,
Wohlkinger and Vincze's ESF (:mod:`vtlearn.geometry.esf`), stands in its place. The transfer step is
:class:`~vtlearn.classical.gfk.GeodesicFlowKernel` (Gong et al. 2012), with each domain standardised on its
own statistics, as in Gong et al.'s code. The rows without ``gfk`` are the same descriptors and classifiers
with no transfer (each descriptor standardised with the visual clouds' statistics): the classical
pipeline's no-DA. The ``_oracle`` rows train the classifier on the labelled tactile training clouds
instead, the ceiling of the descriptor on touch (the network's ``tactile_oracle``).

``vtlearn bench crossmodal --variants esf_1nn,esf_gfk_1nn,esf_svm,esf_gfk_svm`` runs these rows beside the
network's, on the same data, splits and seeds (:func:`classical_runs`). The seed moves the clouds' yaw
augmentation, as for the network's rows, and ESF's random triplets.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

#: row name -> its settings (recorded in the bench JSON's ``variant_settings``)
CLASSICAL_ROWS: dict[str, dict] = {
    "esf_1nn": {"descriptor": "esf", "gfk": False, "classifier": "1nn"},
    "esf_svm": {"descriptor": "esf", "gfk": False, "classifier": "svm"},
    "esf_gfk_1nn": {"descriptor": "esf", "gfk": True, "gfk_dim": 20, "classifier": "1nn"},
    "esf_gfk_svm": {"descriptor": "esf", "gfk": True, "gfk_dim": 20, "classifier": "svm"},
    # the same with Gong et al.'s own choice of the subspace dimension, the subspace disagreement measure
    "esf_gfk_sdm_1nn": {"descriptor": "esf", "gfk": True, "gfk_dim": "sdm", "classifier": "1nn"},
    "esf_gfk_sdm_svm": {"descriptor": "esf", "gfk": True, "gfk_dim": "sdm", "classifier": "svm"},
    # not Table 7.4 rows: the descriptors' own ceiling on touch, the classifier trained on the *labelled*
    # tactile training clouds (as the network's tactile_oracle row)
    "esf_1nn_oracle": {"descriptor": "esf", "gfk": False, "classifier": "1nn", "train_on": "tactile"},
    "esf_svm_oracle": {"descriptor": "esf", "gfk": False, "classifier": "svm", "train_on": "tactile"},
}
#: thesis Table 7.4's figures for the rows that reproduce its CLUE+GFK rows (either choice of GFK's dimension)
THESIS_TABLE_7_4 = {"esf_gfk_1nn": 26.72, "esf_gfk_svm": 15.05,
                    "esf_gfk_sdm_1nn": 26.72, "esf_gfk_sdm_svm": 15.05}
#: ESF's random triplets per cloud (PCL's sample count)
ESF_SAMPLES = 20000


def _dataset_clouds(ds) -> tuple[list[np.ndarray], np.ndarray | None]:
    """Every item of a :class:`~vtlearn.datamodules.crossmodal.CloudDataset`, as the network's loaders give
    it (normalised, and yaw-augmented where the dataset is a training one), with its labels if it has them."""
    items = [ds[i] for i in range(len(ds))]
    clouds = [np.asarray(it["points"], dtype=np.float64) for it in items]
    labels = np.array([it["label"] for it in items], dtype=np.int64) if "label" in items[0] else None
    return clouds, labels


def _classifier(kind: str, seed: int):
    from sklearn.neighbors import KNeighborsClassifier
    from sklearn.svm import LinearSVC

    if kind == "1nn":
        return KNeighborsClassifier(n_neighbors=1)
    return LinearSVC(C=1.0, max_iter=20000, random_state=seed)


def gfk_dim(settings: dict, n_source: int, n_target: int) -> int | str:
    """The subspace dimension a GFK row asks for: its ``gfk_dim`` (20, a common choice with Gong et al.'s
    benchmarks), less where a domain has too few clouds for that many principal directions (a PCA of n
    centred rows has at most n - 1); ``"sdm"`` as it is (the fit chooses, within the same bounds)."""
    if settings["gfk_dim"] == "sdm":
        return "sdm"
    return max(1, min(settings["gfk_dim"], n_source - 1, n_target - 1))


def classify(settings: dict, x_source: np.ndarray, y_source: np.ndarray, x_target: np.ndarray,
             x_test: np.ndarray, x_source_test: np.ndarray, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """One row of :data:`CLASSICAL_ROWS` on descriptors: fit on the labelled visual training descriptors
    (and, with GFK, the unlabelled tactile stream's), predict the tactile and visual test descriptors.

    Args:
        settings: a :data:`CLASSICAL_ROWS` entry (``gfk``, ``gfk_dim``, ``classifier``).
        x_source, y_source: labelled visual training descriptors.
        x_target: unlabelled tactile descriptors of the target stream (only GFK reads them).
        x_test, x_source_test: tactile and visual test descriptors.
        seed: the SVM's random state.

    Shapes:
        x_source (n_s, D), y_source (n_s,), x_target (n_t, D), x_test (m, D), x_source_test (m_v, D)
        -> (tactile predictions (m,), visual predictions (m_v,))
    """
    named = {"x_source": x_source, "x_target": x_target, "x_test": x_test, "x_source_test": x_source_test}
    arrays = {k: np.asarray(v, dtype=np.float64) for k, v in named.items()}
    dim = arrays["x_source"].shape[-1] if arrays["x_source"].ndim == 2 else None
    for name, x in arrays.items():
        if x.ndim != 2 or len(x) == 0 or x.shape[1] != dim:
            raise ValueError(f"{name}: need a non-empty (n, D) array of descriptors with x_source's D, got "
                             f"shape {x.shape}")
        if not np.isfinite(x).all():
            raise ValueError(f"{name}: contains NaN or inf")
    y_source = np.asarray(y_source)
    if y_source.shape != (len(arrays["x_source"]),):
        raise ValueError(f"y_source: need one label per row of x_source ({len(arrays['x_source'])}), got "
                         f"shape {y_source.shape}")
    return _classify(settings, y_source, seed, **arrays)[:2]


def _classify(settings: dict, y_source, seed: int, x_source, x_target, x_test, x_source_test):
    """:func:`classify` on checked arrays; also returns the GFK's subspace dimension (None without GFK)."""
    dim = None
    if settings["gfk"]:
        from vtlearn.classical.gfk import GeodesicFlowKernel

        gfk = GeodesicFlowKernel(dim=gfk_dim(settings, len(x_source), len(x_target)), zscore=True)
        gfk.fit(x_source, x_target)
        zs, zt = gfk.transform(x_source, domain="source"), gfk.transform(x_test, domain="target")
        zv = gfk.transform(x_source_test, domain="source")
        dim = gfk.dim_
    else:
        from sklearn.preprocessing import StandardScaler

        # the visual clouds' statistics for every descriptor (a bin no cloud fills keeps scale 1)
        scaler = StandardScaler().fit(x_source)
        zs, zt, zv = (scaler.transform(x) for x in (x_source, x_test, x_source_test))
    clf = _classifier(settings["classifier"], seed).fit(zs, y_source)
    return clf.predict(zt), clf.predict(zv), dim


def crossmodal_descriptors(dm, seed: int, tactile_train: bool = False,
                           on_cloud: Callable[[int, int], object] | None = None
                           ) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray | None]]:
    """ESF descriptors (:data:`ESF_SAMPLES` triplets) of the clouds a seed's rows read from ``dm`` (a
    :class:`~vtlearn.datamodules.CrossModalDataModule`): ``"source"``, its labelled visual training clouds;
    ``"target"``, its unlabelled target stream; ``"test"`` and ``"source_test"``, its tactile and visual test
    clouds; with ``tactile_train``, also ``"tactile_train"``, the labelled tactile training clouds of the
    ``_oracle`` rows (:meth:`~vtlearn.datamodules.CrossModalDataModule.labelled_target_train_dataloader`).
    The training sets' yaw augmentation draws from torch's generator, seeded here with ``seed`` (as
    ``seed_everything`` seeds a network row) and restored afterwards, so the descriptors repeat for a seed.
    Returns (descriptors, labels) by set; the target stream has no labels (None). ``on_cloud(done, total)``
    is called after each cloud's descriptor, with the clouds done so far and those of all the sets.

    Shapes:
        -> ({set: (n_set, 640)}, {set: (n_set,) int64 or None})
    """
    import torch

    from vtlearn.geometry.esf import esf_descriptors

    sets = {"source": dm.source_train_dataset(), "target": dm.target_dataset(),
            "test": dm.test_dataloader().dataset, "source_test": dm.source_test_dataloader().dataset}
    # each set its own stream of triplets (ESF seeds cloud i of a call with (seed, i)); the oracle's set
    # draws from a base no other set of any seed uses
    streams = {name: 4 * seed + k for k, name in enumerate(sets)}
    if tactile_train:
        sets["tactile_train"] = dm.labelled_target_train_dataloader().dataset
        streams["tactile_train"] = 1_000_003 + seed
    desc, labels = {}, {}
    total, done = sum(len(ds) for ds in sets.values()), 0

    def count() -> None:
        nonlocal done
        done += 1
        on_cloud(done, total)

    with torch.random.fork_rng():
        torch.manual_seed(seed)
        for name, ds in sets.items():
            clouds, labels[name] = _dataset_clouds(ds)
            desc[name] = esf_descriptors(clouds, n_samples=ESF_SAMPLES, seed=streams[name],
                                         on_cloud=count if on_cloud is not None else None)
    return desc, labels


def classical_runs(variants: list[str], seed: int, data_kwargs: dict, threads: int = 1,
                   on_cloud: Callable[[int, int], object] | None = None):
    """The rows ``variants`` (names of :data:`CLASSICAL_ROWS`) for one seed, on the data of
    ``CrossModalDataModule(**data_kwargs, seed=seed)``.

    The descriptors of its visual training clouds, its unlabelled target stream, its tactile test clouds
    and its visual test clouds (and, for ``_oracle`` rows, its labelled tactile training clouds) are
    computed once and shared by the rows. Returns (one bench row per variant, the class names); a row holds
    ``tactile_acc`` and ``visual_acc`` (%), ``fit_s`` (its transfer and classifier), ``descriptor_s`` (the
    shared descriptors) and the tactile ``confusion`` (rows: true class). ``on_cloud``: as for
    :func:`crossmodal_descriptors`, a progress count of the descriptors."""
    from sklearn.metrics import confusion_matrix
    from threadpoolctl import threadpool_limits

    from vtlearn.datamodules import CrossModalDataModule

    unknown = [v for v in variants if v not in CLASSICAL_ROWS]
    if unknown or not variants:
        raise ValueError(f"variants: {f'unknown {unknown}' if unknown else 'none given'}; choose from "
                         f"{list(CLASSICAL_ROWS)}")
    dm = CrossModalDataModule(**{**data_kwargs, "seed": seed})
    with threadpool_limits(threads):
        t0 = time.perf_counter()
        oracle = any(CLASSICAL_ROWS[v].get("train_on") == "tactile" for v in variants)
        desc, labels = crossmodal_descriptors(dm, seed, tactile_train=oracle, on_cloud=on_cloud)
        descriptor_s = time.perf_counter() - t0
        rows = []
        for variant in variants:
            t1 = time.perf_counter()
            train = "tactile_train" if CLASSICAL_ROWS[variant].get("train_on") == "tactile" else "source"
            pred_t, pred_v, dim = _classify(CLASSICAL_ROWS[variant], labels[train], seed, desc[train],
                                            desc["target"], desc["test"], desc["source_test"])
            conf = confusion_matrix(labels["test"], pred_t, labels=np.arange(dm.num_classes))
            rows.append({"variant": variant, "seed": seed,
                         "tactile_acc": 100.0 * float((pred_t == labels["test"]).mean()),
                         "visual_acc": 100.0 * float((pred_v == labels["source_test"]).mean()),
                         "fit_s": time.perf_counter() - t1, "descriptor_s": descriptor_s,
                         "confusion": conf.astype(int).tolist()})
            if dim is not None:  # the dimension used: the SDM's, or less than the row's on a small dataset
                rows[-1]["gfk_dim"] = dim
    return rows, dm.class_names
