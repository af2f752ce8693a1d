"""The classical Table 7.4 baseline (ESF descriptors, GFK, 1-NN / linear SVM) on hand-built descriptors."""

import numpy as np
import pytest

from vtlearn.classical.crossmodal_baseline import (
    CLASSICAL_ROWS,
    classical_runs,
    classify,
    crossmodal_descriptors,
)


def _blobs(rng, n_per_class, centres, noise):
    k, dim = centres.shape
    y = np.repeat(np.arange(k), n_per_class)
    return centres[y] + noise * rng.standard_normal((len(y), dim)), y


def _problem(seed=0, dim=60, k=3, n=30, noise=0.05):
    rng = np.random.default_rng(seed)
    centres = rng.standard_normal((k, dim))
    xs, ys = _blobs(rng, n, centres, noise)
    xt, _ = _blobs(rng, n, centres, noise)
    xtest, ytest = _blobs(rng, n, centres, noise)
    xv, yv = _blobs(rng, n, centres, noise)
    return rng, (xs, ys, xt, xtest, ytest, xv, yv)


@pytest.mark.parametrize("row", list(CLASSICAL_ROWS))
def test_every_row_solves_well_separated_classes_without_a_domain_shift(row):
    _, (xs, ys, xt, xtest, ytest, xv, yv) = _problem()
    pred_t, pred_v = classify(CLASSICAL_ROWS[row], xs, ys, xt, xtest, xv)
    assert (pred_t == ytest).all() and (pred_v == yv).all()


def test_gfk_rows_undo_a_per_feature_shift_of_the_target_that_the_plain_rows_cannot():
    """Tactile descriptors as the visual ones with every bin scaled and offset: per-domain standardisation
    (the GFK rows') undoes it up to sampling noise, the visual statistics (the no-transfer rows') do not."""
    rng, (xs, ys, xt, xtest, ytest, xv, yv) = _problem(seed=1)
    scale = rng.uniform(0.5, 2.0, xs.shape[1])
    offset = 10.0 * rng.standard_normal(xs.shape[1])  # ten times the spread of the class centres
    xt, xtest = xt * scale + offset, xtest * scale + offset
    acc = {row: float((classify(CLASSICAL_ROWS[row], xs, ys, xt, xtest, xv)[0] == ytest).mean())
           for row in CLASSICAL_ROWS}
    gfk_rows = ("esf_gfk_1nn", "esf_gfk_svm", "esf_gfk_sdm_1nn", "esf_gfk_sdm_svm")
    assert all(acc[row] >= 0.95 for row in gfk_rows)
    # the shifted test clouds all fall nearest to one class: chance level (1/3) or close to it
    assert acc["esf_1nn"] <= 0.5 and acc["esf_svm"] <= 0.5


def test_classify_refuses_bad_descriptors_by_name():
    _, (xs, ys, xt, xtest, _, xv, _) = _problem()
    settings = CLASSICAL_ROWS["esf_gfk_1nn"]
    with pytest.raises(ValueError, match="x_test: need a non-empty"):
        classify(settings, xs, ys, xt, xtest[:, :5], xv)
    with pytest.raises(ValueError, match="x_target: need a non-empty"):
        classify(settings, xs, ys, xt[:0], xtest, xv)
    bad = xv.copy()
    bad[0, 0] = np.nan
    with pytest.raises(ValueError, match="x_source_test: contains NaN"):
        classify(settings, xs, ys, xt, xtest, bad)
    with pytest.raises(ValueError, match="y_source: need one label per row"):
        classify(settings, xs, ys[:-1], xt, xtest, xv)


def test_classical_runs_refuses_unknown_rows_by_name():
    with pytest.raises(ValueError, match=r"variants: unknown \['esf_knn'\]"):
        classical_runs(["esf_knn"], 0, {"data_dir": "unused"})
    with pytest.raises(ValueError, match="variants: none given"):
        classical_runs([], 0, {"data_dir": "unused"})


def test_bench_crossmodal_runs_the_classical_rows_beside_the_network(tmp_path, cross_dir, monkeypatch,
                                                                    capsys):
    """The classical rows share one seed's descriptors, are scored on the network rows' test clouds, and
    are recorded, paired with no-DA and shown against the thesis's Table 7.4 like any other row."""
    import json

    from _tiny_models import tiny_xavtnet_config

    from vtlearn.classical import crossmodal_baseline
    from vtlearn.classical.gfk import GeodesicFlowKernel
    from vtlearn.cli import main
    from vtlearn.datamodules import CrossModalDataModule

    monkeypatch.setattr(crossmodal_baseline, "ESF_SAMPLES", 300)  # tiny clouds, smoke sizes
    cfg = tiny_xavtnet_config(tmp_path, cross_dir)
    out = tmp_path / "cm.json"
    rows = "noda,esf_1nn,esf_gfk_1nn,esf_gfk_svm,esf_gfk_sdm_1nn,esf_1nn_oracle"
    assert main(["bench", "crossmodal", "--config", str(cfg), "--variants", rows, "--seeds", "2",
                 "--no-figures", "--json", str(out)]) == 0
    res = json.loads(out.read_text())
    assert [r["variant"] for r in res["rows"]] == rows.split(",")
    assert len(res["runs"]) == 12
    assert res["variant_settings"]["esf_gfk_svm"] == {**CLASSICAL_ROWS["esf_gfk_svm"], "esf_samples": 300}
    thesis = {r["variant"]: r["thesis_V→T"] for r in res["rows"]}
    assert thesis["esf_gfk_1nn"] == 26.72 and thesis["esf_gfk_svm"] == 15.05 and thesis["esf_1nn"] == "-"
    assert {(p["a"], p["b"]) for p in res["paired"]} >= {("esf_gfk_1nn", "noda"), ("esf_1nn", "noda")}
    # a row is what classify() gives on the seed's descriptors, which repeat for the seed
    run = next(r for r in res["runs"] if (r["variant"], r["seed"]) == ("esf_gfk_1nn", 1))
    dm = CrossModalDataModule(data_dir=str(cross_dir), batch_size=4, seed=1)
    desc, labels = crossmodal_descriptors(dm, 1)
    counted = []  # a progress count: every cloud once, out of all the sets' clouds; the same descriptors
    again, _ = crossmodal_descriptors(dm, 1, on_cloud=lambda done, total: counted.append((done, total)))
    assert all(np.array_equal(desc[k], again[k]) for k in desc) and labels["target"] is None
    n_clouds = sum(len(d) for d in desc.values())
    assert counted == [(i + 1, n_clouds) for i in range(n_clouds)]
    assert desc["source"].shape == (len(dm.source_train_dataset()), 640)
    pred_t, pred_v = classify(CLASSICAL_ROWS["esf_gfk_1nn"], desc["source"], labels["source"], desc["target"],
                              desc["test"], desc["source_test"], 1)
    assert run["tactile_acc"] == pytest.approx(100 * (pred_t == labels["test"]).mean())
    assert run["visual_acc"] == pytest.approx(100 * (pred_v == labels["source_test"]).mean())
    assert run["gfk_dim"] == min(20, len(desc["source"]) - 1, len(desc["target"]) - 1)
    # the SDM row records the dimension that Gong et al.'s measure chose on the seed's descriptors
    sdm = next(r for r in res["runs"] if (r["variant"], r["seed"]) == ("esf_gfk_sdm_1nn", 1))
    chosen = GeodesicFlowKernel(dim="sdm", zscore=True).fit(desc["source"], desc["target"]).dim_
    assert sdm["gfk_dim"] == chosen
    pred_s, _ = classify(CLASSICAL_ROWS["esf_gfk_sdm_1nn"], desc["source"], labels["source"], desc["target"],
                         desc["test"], desc["source_test"], 1)
    assert sdm["tactile_acc"] == pytest.approx(100 * (pred_s == labels["test"]).mean())
    # the oracle row: the same descriptors of the test clouds, a classifier fitted on the labelled touches
    oracle = next(r for r in res["runs"] if (r["variant"], r["seed"]) == ("esf_1nn_oracle", 1))
    desc, labels = crossmodal_descriptors(dm, 1, tactile_train=True)
    assert len(desc["tactile_train"]) == len(dm.labelled_target_train_dataloader().dataset)
    assert (labels["tactile_train"] >= 0).all() and "gfk_dim" not in oracle
    pred_o, _ = classify(CLASSICAL_ROWS["esf_1nn_oracle"], desc["tactile_train"], labels["tactile_train"],
                         desc["target"], desc["test"], desc["source_test"], 1)
    assert oracle["tactile_acc"] == pytest.approx(100 * (pred_o == labels["test"]).mean())
    conf = np.array(run["confusion"])
    assert conf.sum() == len(labels["test"]) and np.trace(conf) == (pred_t == labels["test"]).sum()
    captured = capsys.readouterr()
    printed = captured.out
    assert "esf_gfk_svm seed 0" in printed and "2 seeds, 1 epoch," in printed
    # one bar for all: two no-DA trainings of one epoch, and each seed's classical rows as one epoch
    assert "4/4 " in captured.err.split("bench crossmodal")[-1]
    # classical rows alone train nothing, and the table says so instead of the config's epochs
    assert main(["bench", "crossmodal", "--config", str(cfg), "--variants", "esf_1nn", "--seeds", "1",
                 "--no-figures", "--json", str(tmp_path / "c.json")]) == 0
    assert "1 seeds, no training (classical rows)," in capsys.readouterr().out


def test_the_classical_job_spreads_its_share_of_the_bar_over_the_clouds(monkeypatch):
    import vtlearn.models.xavtnet_cli as xc
    from vtlearn.classical import crossmodal_baseline

    def fake_runs(variants, seed, data_kwargs, threads, on_cloud=None):
        for done in range(1, 6):
            on_cloud(done, 5)
        return [{"variant": variants[0]}], ["a"]

    class Sink:
        def __init__(self):
            self.ticks = []

        def put(self, n):
            self.ticks.append(n)

    monkeypatch.setattr(crossmodal_baseline, "classical_runs", fake_runs)
    sink = Sink()
    rows, feats, names = xc._classical_job(["esf_1nn"], 0, {}, 1, 7, progress=sink)
    assert rows == [{"variant": "esf_1nn"}] and feats is None and names == ["a"]
    # 7 units over 5 clouds: 1, 1, 2, 1, 2 (floor(7 * done / 5) - what was sent), all positive, 7 in all
    assert sink.ticks == [1, 1, 2, 1, 2]
