"""Smoke tests of `vtlearn bench crossmodal` / `bench active-learning` on the tiny simulated dataset,
and consistency of the ablation configs with the bench's variant table."""

import json
import math
import os
from pathlib import Path

import numpy as np
import pytest
import yaml
from _tiny_models import tiny_xavtnet_config

from vtlearn.models.xavtnet import XAVTNet
from vtlearn.models.xavtnet_cli import VARIANTS, _data_kwargs, load_config

os.environ.setdefault("WANDB_MODE", "disabled")
ROOT = Path(__file__).resolve().parents[1]


def test_ablation_configs_match_bench_variants():
    for name, overrides in VARIANTS.items():
        cfg = yaml.safe_load((ROOT / "configs" / "xavtnet_ablation" / f"{name}.yaml").read_text())
        assert cfg["model"]["class_path"] == "vtlearn.models.xavtnet.XAVTNet"
        args = cfg["model"]["init_args"]
        for key, value in overrides.items():
            assert args[key] == value, (name, key)
        XAVTNet(**args)  # the config's other keys are valid arguments too


@pytest.mark.parametrize("path", ["xavtnet.yaml", "quick/xavtnet.yaml", "cpu/xavtnet.yaml",
                                  "gpu/xavtnet.yaml", "cpu/xavtnet_lam500.yaml",
                                  "active_learning.yaml", "quick/active_learning.yaml",
                                  "cpu/active_learning.yaml", "cpu/active_learning_equal.yaml",
                                  "cpu/active_learning_converged.yaml",
                                  "cpu/xavtnet_episodes.yaml", "cpu/xavtnet_tactile.yaml",
                                  "cpu/xavtnet_touchsim.yaml", "cpu/xavtnet_ramp.yaml",
                                  "cpu/xavtnet_balance.yaml", "cpu/xavtnet_objects.yaml",
                                  "cpu/xavtnet_memory.yaml", "cpu/xavtnet_object_frame.yaml",
                                  "cpu/xavtnet_object_frame_k1.yaml", "cpu/xavtnet_object_frame_k9.yaml",
                                  "cpu/xavtnet_objects_k9.yaml", "cpu/xavtnet_objects_ddc.yaml",
                                  "cpu/xavtnet_object_frame_ddc.yaml"])
def test_configs_build_the_model(path):
    import inspect

    from vtlearn.datamodules import CrossModalDataModule

    cfg = load_config(str(ROOT / "configs" / path))
    model = XAVTNet(**cfg["model"])
    if "active" not in path:  # the crossmodal configs name only arguments the datamodule takes
        assert set(cfg["data"]) <= set(inspect.signature(CrossModalDataModule).parameters), path
    assert model.hparams.num_classes == 12
    assert cfg["trainer"]["max_epochs"] >= 1
    if cfg.get("active"):
        from vtlearn.active.mc_dropout import QUERY_STRATEGIES

        assert set(cfg["active"]["strategies"].split(",")) <= set(QUERY_STRATEGIES)


@pytest.fixture(scope="module")
def tiny_crossmodal(tmp_path_factory):
    from vtlearn.sim_data.fixtures import make_tiny_dataset

    return make_tiny_dataset("crossmodal", tmp_path_factory.mktemp("cross"))


def test_data_kwargs_override_and_missing_dataset():
    cfg = {"data": {"data_dir": "cfg_dir", "batch_size": 8}}
    assert _data_kwargs(cfg, None) == {"data_dir": "cfg_dir", "batch_size": 8}
    assert _data_kwargs(cfg, "cli_dir")["data_dir"] == "cli_dir"
    assert cfg["data"]["data_dir"] == "cfg_dir"  # the config itself is not modified
    with pytest.raises(ValueError, match="--data: no dataset directory"):
        _data_kwargs({"data": {"batch_size": 8}}, None)


def test_load_config_names_the_flag_for_a_missing_or_broken_file(tmp_path):
    with pytest.raises(ValueError, match="--config: no such file"):
        load_config(str(tmp_path / "nope.yaml"))
    (tmp_path / "bad.yaml").write_text("model: [unclosed\n")
    with pytest.raises(ValueError, match="--config: .* is not valid YAML"):
        load_config(str(tmp_path / "bad.yaml"))
    (tmp_path / "list.yaml").write_text("- 1\n- 2\n")
    with pytest.raises(ValueError, match="--config: .* is not a YAML mapping"):
        load_config(str(tmp_path / "list.yaml"))


def test_bench_crossmodal_smoke(tmp_path, tiny_crossmodal, capsys):
    from vtlearn.cli import main

    cfg = tiny_xavtnet_config(tmp_path, tiny_crossmodal)
    out = tmp_path / "cm.json"
    rc = main(["bench", "crossmodal", "--config", str(cfg), "--variants", "noda,vtloss", "--seeds", "2",
               "--json", str(out)])  # the figures go beside the JSON, in cm/
    assert rc == 0
    res = json.loads(out.read_text())
    assert [r["variant"] for r in res["rows"]] == ["noda", "vtloss"]
    assert len(res["runs"]) == 4 and all(0 <= r["tactile_acc"] <= 100 for r in res["runs"])
    assert "vtloss_minus_noda" in res["checks"]
    # which data made the numbers: the dataset's fingerprint, as a regenerated folder would show it
    from vtlearn.datamodules.shards import dataset_fingerprint

    assert res["data_fingerprint"] == {"data_dir": dataset_fingerprint(tiny_crossmodal)}
    # and how they were drawn: the gen-data settings of the dataset's manifest
    manifest = json.loads((Path(tiny_crossmodal) / "manifest.json").read_text())
    assert res["data_generation"] == {"data_dir": manifest["config"]} and "seed" in manifest["config"]
    # what each row sets over model_base is recorded with its numbers
    assert res["variant_settings"]["noda"] == {"da_method": "none"}
    assert res["variant_settings"]["vtloss"]["da_layers"] == ["fc1", "fc2"]
    assert (res["accelerator"], res["workers"]) == ("cpu", 1)
    assert Path(res["figures"]["tsne"]).exists() and Path(res["figures"]["confusion"]).exists()
    assert Path(res["figures"]["tsne"]).parent == tmp_path / "cm"
    captured = capsys.readouterr()
    printed = captured.out
    assert "Table 7.2/7.4 analogue" in printed and "Seed-paired differences" in printed
    # per class, from the runs' confusion matrices summed over the seeds: recall and share of the predictions
    assert "Per class: tactile recall" in printed and list(res["per_class"]) == ["noda", "vtloss"]
    conf = np.sum([r["confusion"] for r in res["runs"] if r["variant"] == "vtloss"], axis=0)
    assert res["per_class"]["vtloss"]["predicted_share"] == pytest.approx(100 * conf.sum(0) / conf.sum())
    # the bar counts the trainings' epochs as they run: 2 rows x 2 seeds x max_epochs
    assert f"{4 * res['max_epochs']}/{4 * res['max_epochs']} " in captured.err.split("bench crossmodal")[-1]
    # with two seeds every row is paired against no-DA, seed by seed, in the table, the JSON and a figure
    (pair,) = res["paired"]
    acc = {(r["variant"], r["seed"]): r["tactile_acc"] for r in res["runs"]}
    assert (pair["a"], pair["b"], pair["seeds"]) == ("vtloss", "noda", [0, 1])
    assert pair["diffs"] == pytest.approx([acc["vtloss", s] - acc["noda", s] for s in (0, 1)])
    assert pair["cross_machine"] == 0 and Path(res["figures"]["paired"]).exists()
    # the same jobs in two spawned worker processes give the same runs, in the same order
    out2 = tmp_path / "cm2.json"
    assert main(["bench", "crossmodal", "--config", str(cfg), "--variants", "noda,vtloss", "--seeds", "2",
                 "--workers", "2", "--no-figures", "--json", str(out2)]) == 0
    res2 = json.loads(out2.read_text())
    assert res2["workers"] == 2
    # the workers' epochs reached the bar through the manager queue
    bar = capsys.readouterr().err.split("bench crossmodal")[-1]
    assert f"{4 * res2['max_epochs']}/{4 * res2['max_epochs']} " in bar, bar
    key = [(r["variant"], r["seed"], r["tactile_acc"], r["visual_acc"], r["confusion"]) for r in res["runs"]]
    assert key == [(r["variant"], r["seed"], r["tactile_acc"], r["visual_acc"], r["confusion"])
                   for r in res2["runs"]]
    with pytest.raises(SystemExit) as exc:  # refused by argparse, before any training
        main(["bench", "crossmodal", "--config", str(cfg), "--workers", "0", "--json", str(out2)])
    assert exc.value.code == 2 and "argument --workers: must be >= 1" in capsys.readouterr().err
    # the train-on-target upper bound is a variant of its own, scored like the others
    assert main(["bench", "crossmodal", "--config", str(cfg), "--variants", "tactile_oracle", "--seeds", "1",
                 "--no-figures", "--json", str(out2)]) == 0
    res_oracle = json.loads(out2.read_text())
    assert [r["variant"] for r in res_oracle["runs"]] == ["tactile_oracle"]
    assert res_oracle["variant_settings"] == {"tactile_oracle": {"da_method": "none"}}
    assert "discrepancy" not in res_oracle and "discrepancy" not in res_oracle["runs"][0]
    # a pair that the trained runs cannot give (no teacher) is left out with a note, the results kept
    capsys.readouterr()
    assert main(["bench", "crossmodal", "--config", str(cfg), "--variants", "tactile_oracle", "--seeds", "1",
                 "--pairs", "tactile_oracle.teacher-tactile_oracle", "--no-figures",
                 "--json", str(out2)]) == 0
    assert "paired" not in json.loads(out2.read_text())
    assert "left out of the paired table: --pairs: no run of tactile_oracle with tactile_acc_teacher" in (
        capsys.readouterr().out)
    # --discrepancy measures what each run leaves between the domains, and summarises it per row
    assert main(["bench", "crossmodal", "--config", str(cfg), "--variants", "noda,mmd", "--seeds", "2",
                 "--max-epochs", "1", "--discrepancy", "--no-figures", "--json", str(out2)]) == 0
    res_d = json.loads(out2.read_text())
    assert [r["variant"] for r in res_d["discrepancy"]] == ["noda", "mmd"]
    for row in res_d["discrepancy"]:
        runs = [r["discrepancy"] for r in res_d["runs"] if r["variant"] == row["variant"]]
        assert row["seeds"] == 2 and len(runs) == 2
        assert row["coral_fc1_mean"] == pytest.approx(np.mean([d["coral_fc1"] for d in runs]))
        assert all(d["mmd_fc2"] >= -1e-6 and d["coral_fc2"] >= 0 for d in runs)
    assert "Domain discrepancy left by each row" in capsys.readouterr().out
    # --merge pools the two results (no-DA of seeds 0-1 ran in both, alike, and is kept once) and pairs
    # every row with no-DA and the rows asked for, training nothing
    merged = tmp_path / "merged.json"
    assert main(["bench", "crossmodal", "--merge", str(out), str(out2), "--pairs", "vtloss-mmd",
                 "--margin", "5", "--json", str(merged)]) == 0
    res_m = json.loads(merged.read_text())
    assert [r["variant"] for r in res_m["rows"]] == ["noda", "vtloss", "mmd"]
    assert len(res_m["runs"]) == 6 and res_m["merged_from"] == [str(out), str(out2)]
    by = {(r["variant"], r["seed"]): r["tactile_acc"] for r in res_m["runs"]}
    pairs = {r["comparison"]: r for r in res_m["paired"]}
    assert set(pairs) == {"vtloss − noda", "mmd − noda", "vtloss − mmd"}
    assert pairs["vtloss − mmd"]["diffs"] == pytest.approx([by["vtloss", s] - by["mmd", s] for s in (0, 1)])
    assert "p(≤ 5)" in pairs["vtloss − mmd"] and Path(res_m["figures"]["paired"]).exists()
    assert res_m["data_fingerprint"] == res["data_fingerprint"] and len(res_m["machines"]) == 1
    assert main(["bench", "crossmodal", "--merge", str(out), "--json", str(out)]) == 2  # would overwrite it
    assert "--json:" in capsys.readouterr().err
    assert main(["bench", "crossmodal", "--config", str(cfg), "--variants", "noda", "--pairs", "noda-mmd",
                 "--json", str(merged)]) == 2  # mmd is not trained: refused before any training
    assert "--pairs: mmd names a row that --variants does not train" in capsys.readouterr().err
    assert main(["bench", "crossmodal", "--merge", str(out), "--baseline", "mmd", "--json", str(merged)]) == 2
    assert "--baseline: 'mmd' is not one of the rows" in capsys.readouterr().err
    assert main(["bench", "crossmodal", "--merge", str(out), str(out2), "--baseline", "mmd", "--no-figures",
                 "--json", str(merged)]) == 0
    compared = {r["comparison"] for r in json.loads(merged.read_text())["paired"]}
    assert compared == {"noda − mmd", "vtloss − mmd"}
    # each information-maximisation row (beyond the thesis) is compared with no-DA
    assert main(["bench", "crossmodal", "--config", str(cfg), "--variants", "noda,vtloss_im", "--seeds", "1",
                 "--no-figures", "--json", str(out2)]) == 0
    res3 = json.loads(out2.read_text())
    assert [r["variant"] for r in res3["rows"]] == ["noda", "vtloss_im"]
    assert res3["checks"]["vtloss_im_minus_noda"] == pytest.approx(
        res3["rows"][1]["tactile_mean"] - res3["rows"][0]["tactile_mean"])
    # AaD with the teacher's bank starts after a third of the epochs: two epochs reach it on the datamodule's
    # indexed target stream
    assert main(["bench", "crossmodal", "--config", str(cfg), "--variants", "noda,vtloss_g12_mt_aadt",
                 "--seeds", "1", "--max-epochs", "2", "--no-figures", "--json", str(out2)]) == 0
    res3 = json.loads(out2.read_text())
    noda, aad = res3["runs"]
    assert 0 <= aad["tactile_acc_teacher"] <= 100
    assert res3["checks"]["vtloss_g12_mt_aadt_minus_noda"] == pytest.approx(aad["tactile_acc"]
                                                                            - noda["tactile_acc"])
    assert main(["bench", "crossmodal", "--config", str(cfg), "--variants", "bogus",
                 "--json", str(out2)]) == 2
    # --source-points reaches the datamodule and is recorded; a bad range is refused by name
    assert main(["bench", "crossmodal", "--config", str(cfg), "--variants", "noda", "--seeds", "1",
                 "--source-points", "10", "20", "--source-views", "2", "--source-splits", "train,test",
                 "--no-figures", "--json", str(out2)]) == 0
    data = json.loads(out2.read_text())["data"]
    assert (data["source_points"], data["source_views"]) == ([10, 20], 2)
    assert data["source_splits"] == ["train", "test"]
    assert "labelled visual source: train+test" in capsys.readouterr().out
    assert main(["bench", "crossmodal", "--config", str(cfg), "--variants", "noda", "--seeds", "1",
                 "--target-split", "test", "--target-holdout", "0.5", "--no-figures",
                 "--json", str(out2)]) == 0
    assert json.loads(out2.read_text())["data"]["target_holdout"] == 0.5
    assert "less the 0.5 of their tactile clouds held out" in capsys.readouterr().out
    assert main(["bench", "crossmodal", "--config", str(cfg), "--variants", "noda", "--seeds", "1",
                 "--target-split", "train", "--target-holdout", "0.5", "--no-figures",
                 "--json", str(out2)]) == 2
    assert "--target-holdout:" in capsys.readouterr().err
    assert main(["bench", "crossmodal", "--config", str(cfg), "--variants", "noda", "--seeds", "1",
                 "--source-splits", "train,nope", "--no-figures", "--json", str(out2)]) == 2
    assert "--source-splits:" in capsys.readouterr().err
    assert main(["bench", "crossmodal", "--config", str(cfg), "--variants", "noda", "--seeds", "1",
                 "--source-points", "20", "10", "--no-figures", "--json", str(out2)]) == 2
    assert "--source-points:" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main(["bench", "crossmodal", "--config", str(cfg), "--variants", "noda", "--seeds", "1",
              "--source-views", "0", "--no-figures", "--json", str(out2)])
    assert exc.value.code == 2 and "argument --source-views: must be >= 1" in capsys.readouterr().err
    # --adabn scores every row a second time with target statistics; the *_dbn rows train with them; a
    # teacher row is scored as its teacher too (on a copy, so AdaBN's conversion does not stop it)
    assert main(["bench", "crossmodal", "--config", str(cfg), "--variants",
                 "noda,vtloss_dbn,vtloss_g12_mt,vtloss_g12_mt_dbn", "--seeds", "1", "--adabn", "--no-figures",
                 "--json", str(out2)]) == 0
    res3 = json.loads(out2.read_text())
    assert all(0 <= r["tactile_acc_adabn"] <= 100 for r in res3["runs"])
    noda, dbn, mt, mt_dbn = res3["runs"]
    for row in (mt, mt_dbn):  # the teacher row with statistics per domain is scored as its teacher too
        assert 0 <= row["tactile_acc_teacher"] <= 100 and 0 <= row["tactile_acc_teacher_adabn"] <= 100
    assert "tactile_acc_teacher_adabn" not in noda
    checks = res3["checks"]
    assert checks["noda_adabn_minus_noda"] == pytest.approx(noda["tactile_acc_adabn"] - noda["tactile_acc"])
    # every other row against plain no-DA and, like for like, against no-DA after AdaBN
    assert checks["vtloss_dbn_adabn_minus_noda"] == pytest.approx(
        dbn["tactile_acc_adabn"] - noda["tactile_acc"])
    assert checks["vtloss_g12_mt_adabn_minus_noda_adabn"] == pytest.approx(
        mt["tactile_acc_adabn"] - noda["tactile_acc_adabn"])
    assert checks["vtloss_g12_mt_teacher_adabn_minus_noda_adabn"] == pytest.approx(
        mt["tactile_acc_teacher_adabn"] - noda["tactile_acc_adabn"])
    assert "tactile_acc_adabn" in capsys.readouterr().out
    # a mean-teacher row (here with distribution alignment) is scored again with re-estimated statistics
    # and as its teacher; no-DA is not. --balanced adds every row's class-balanced assignment, compared
    # like for like with no-DA's
    assert main(["bench", "crossmodal", "--config", str(cfg), "--variants", "noda,vtloss_g12_mt_align",
                 "--seeds", "1", "--balanced", "--no-figures", "--json", str(out2)]) == 0
    res4 = json.loads(out2.read_text())
    noda, mt = res4["runs"]
    assert "tactile_acc_teacher" not in noda and "tactile_acc_bn" not in noda
    assert "tactile_acc_teacher_balanced" not in noda
    assert all(0 <= mt[k] <= 100 for k in ("tactile_acc_bn", "tactile_acc_teacher", "visual_acc_teacher",
                                           "tactile_acc_balanced", "tactile_acc_teacher_balanced"))
    checks = res4["checks"]
    assert checks["vtloss_g12_mt_align_teacher_minus_noda"] == pytest.approx(
        mt["tactile_acc_teacher"] - noda["tactile_acc"])
    assert checks["noda_balanced_minus_noda"] == pytest.approx(noda["tactile_acc_balanced"]
                                                               - noda["tactile_acc"])
    assert checks["vtloss_g12_mt_align_balanced_minus_noda_balanced"] == pytest.approx(
        mt["tactile_acc_balanced"] - noda["tactile_acc_balanced"])
    assert checks["vtloss_g12_mt_align_teacher_balanced_minus_noda_balanced"] == pytest.approx(
        mt["tactile_acc_teacher_balanced"] - noda["tactile_acc_balanced"])
    printed = capsys.readouterr().out
    assert "tactile_acc_teacher" in printed and "tactile_acc_balanced" in printed
    # --centroid and --probe add the network's and the teacher's feature scores, compared with no-DA's
    # like for like, and leave every other score of the run as it was without them
    assert main(["bench", "crossmodal", "--config", str(cfg), "--variants", "noda,vtloss_g12_mt_align",
                 "--seeds", "1", "--balanced", "--centroid", "--probe", "--no-figures", "--json",
                 str(out2)]) == 0
    res5 = json.loads(out2.read_text())
    for before, after in zip(res4["runs"], res5["runs"], strict=True):
        assert {k: v for k, v in after.items() if not k.endswith(("_centroid", "_probe"))} == {
            k: v for k, v in before.items() if k != "fit_s"} | {"fit_s": after["fit_s"]}
    noda, mt = res5["runs"]
    assert "tactile_acc_teacher_probe" not in noda
    assert all(0 <= r[k] <= 100 for r in (noda, mt) for k in ("tactile_acc_centroid", "tactile_acc_probe"))
    checks = res5["checks"]
    assert checks["noda_probe_minus_acc"] == pytest.approx(noda["tactile_acc_probe"] - noda["tactile_acc"])
    assert checks["vtloss_g12_mt_align_teacher_probe_minus_noda_probe"] == pytest.approx(
        mt["tactile_acc_teacher_probe"] - noda["tactile_acc_probe"])
    assert checks["vtloss_g12_mt_align_centroid_minus_noda_centroid"] == pytest.approx(
        mt["tactile_acc_centroid"] - noda["tactile_acc_centroid"])
    assert "noda_probe_minus_noda_probe" not in checks
    assert "tactile_acc_teacher_probe" in capsys.readouterr().out


def test_bench_active_learning_rejects_unknown_strategies(tmp_path, tiny_crossmodal, capsys):
    from vtlearn.cli import main

    cfg = tiny_xavtnet_config(tmp_path, tiny_crossmodal, active=True)
    assert main(["bench", "active-learning", "--config", str(cfg), "--strategies", "entropy,margin"]) == 2
    assert "strategies" in capsys.readouterr().err


@pytest.mark.slow
def test_bench_active_learning_smoke(tmp_path, tiny_crossmodal, capsys):
    from vtlearn.cli import main

    cfg = tiny_xavtnet_config(tmp_path, tiny_crossmodal, active=True)
    out = tmp_path / "al.json"
    rc = main(["bench", "active-learning", "--config", str(cfg), "--seeds", "1", "--json", str(out),
               "--plot", str(tmp_path / "al.png")])
    assert rc == 0
    res = json.loads(out.read_text())
    assert set(res["ratios_2pct"]) == {"entropy"}
    for strategy in ("entropy", "random"):
        assert res["curves"][strategy]["n_labels"] == [3, 5]
        assert set(res["curves"][strategy]["labels_to_reach"]) == {"10%", "5%", "3%", "2%"}
    assert (tmp_path / "al.png").exists() and res["figure"] == str(tmp_path / "al.png")
    # two worker processes: the same curves and full-pool reference as the serial run
    out2 = tmp_path / "al2.json"
    assert main(["bench", "active-learning", "--config", str(cfg), "--seeds", "1", "--workers", "2",
                 "--json", str(out2), "--plot", str(tmp_path / "al2.png")]) == 0
    res2 = json.loads(out2.read_text())
    assert res2["full_acc"] == res["full_acc"]
    # the bar counts trainings, the workers' as they end: the reference, and two rounds of two strategies
    assert "5/5 " in capsys.readouterr().err.split("bench active-learning")[-1]
    for strategy in ("entropy", "random"):
        assert res2["curves"][strategy]["runs"] == res["curves"][strategy]["runs"]
        assert set(res["curves"][strategy]["labels_to_stay"]) == {"10%", "5%", "3%", "2%"}
    assert res["train_steps"] is None and set(res["ratios_2pct_sustained"]) == {"entropy"}
    assert res["paired_vs_random"]["entropy"]["pairs"] == 1  # one seed, one query round
    # equal-budget protocol: every training runs max_epochs over the whole pool, whatever its labels
    out3 = tmp_path / "al3.json"
    assert main(["bench", "active-learning", "--config", str(cfg), "--seeds", "1", "--equal-steps",
                 "--json", str(out3)]) == 0
    assert (tmp_path / "al3.png").is_file()  # the plot goes beside the JSON unless --plot names it
    res3 = json.loads(out3.read_text())
    assert res3["train_steps"] == res3["max_epochs"] * math.ceil(res3["pool_size"] / 4)
    # --merge pools the seeds of runs with the same protocol, and refuses anything else
    out4 = tmp_path / "al4.json"
    assert main(["bench", "active-learning", "--config", str(cfg), "--seed", "1", "--seeds", "1",
                 "--json", str(out4), "--plot", str(tmp_path / "al4.png")]) == 0
    res4 = json.loads(out4.read_text())
    merged = tmp_path / "merged.json"
    assert main(["bench", "active-learning", "--merge", str(out), str(out4), "--json", str(merged),
                 "--plot", str(tmp_path / "merged.png")]) == 0
    m = json.loads(merged.read_text())
    assert m["seeds"] == [0, 1] and m["full_acc"] == res["full_acc"] + res4["full_acc"]
    for strategy in ("entropy", "random"):
        runs = res["curves"][strategy]["runs"] + res4["curves"][strategy]["runs"]
        assert m["curves"][strategy]["runs"] == runs
        assert m["curves"][strategy]["acc_mean"] == pytest.approx(
            [(a["accuracy"] + b["accuracy"]) / 2 for a, b in zip(*runs, strict=True)])
    assert m["paired_vs_random"]["entropy"]["pairs"] == 2
    # the seed bootstrap of the merged run: one value per reading, and its point is the table's ratio
    b = m["bootstrap_2pct"]["entropy"]
    assert set(b) == {"reached", "sustained"} and b["reached"]["n_boot"] == 2000
    assert b["reached"]["ratio"] == m["ratios_2pct"]["entropy"]
    assert b["sustained"]["ratio"] == m["ratios_2pct_sustained"]["entropy"]
    texts = m["ratios_2pct_text"]["entropy"]
    assert set(texts) == {"labels_to_reach", "labels_to_stay"}
    if m["ratios_2pct"]["entropy"] is not None:
        assert texts["labels_to_reach"] == f"{m['ratios_2pct']['entropy']:.2f}"
    for bad, what in (([str(out), str(out2)], "repeat seeds"), ([str(out4), str(out3)], "train_steps"),
                      ([str(out), str(tmp_path / "none.json")], "no such file")):
        assert main(["bench", "active-learning", "--merge", *bad, "--json", str(tmp_path / "x.json"),
                     "--plot", str(tmp_path / "x.png")]) == 2
        assert what in capsys.readouterr().err


def test_label_ratio_text_bounds_a_curve_that_misses_the_line_by_the_last_round():
    """A curve that does not reach the line by its last round has a count beyond it, so the ratio is
    bounded, not unknown: above by the strategy's last round when only random reaches it, below when only
    the strategy does."""
    from vtlearn.models.xavtnet_cli import _ratio_text

    assert _ratio_text(512, 832, 896) == "0.62"
    assert _ratio_text(None, 832, 896) == "> 1.08 (not reached by 896 labels)"
    assert _ratio_text(512, None, 896) == "< 0.57 (random does not reach it by 896 labels)"
    assert (_ratio_text(512, None, 896, random_max_labels=1024)
            == "< 0.50 (random does not reach it by 1024 labels)")
    assert _ratio_text(None, None, 896).startswith("n/a")


@pytest.mark.slow  # a fresh interpreter importing lightning + train.py: tens of seconds on shared cores
def test_train_py_parses_config_with_ablation_override():
    import subprocess
    import sys

    if not (ROOT / "train.py").exists():
        pytest.skip("train.py not present")
    proc = subprocess.run(
        [sys.executable, str(ROOT / "train.py"), "fit", "--config", str(ROOT / "configs" / "xavtnet.yaml"),
         "--config", str(ROOT / "configs" / "xavtnet_ablation" / "vtloss_fc1.yaml"), "--print_config"],
        capture_output=True, text=True, timeout=120, cwd=ROOT,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    printed = yaml.safe_load(proc.stdout)
    args = printed["model"]["init_args"]
    assert args["da_layers"] == ["fc1"] and args["global_dim"] == 1024 and args["alpha"] == 10.0


def _al_result(path, seeds, *, model=None, min_steps=250, train_steps=410, kappa=32):
    """A hand-written `bench active-learning` result: one round history per seed and strategy."""
    doc = {"bench": "active-learning", "data": {"data_dir": "d"}, "pool_size": 1296, "max_epochs": 10,
           "train_steps": train_steps, "seeds": seeds, "full_acc": [0.9] * len(seeds),
           "active": {"n0": 32, "kappa": kappa, "rounds": 2, "mc_passes": 10, "warm_start": False,
                      "min_steps": min_steps, "power_beta": 1.0, "equal_steps": bool(train_steps)},
           "curves": {s: {"runs": [[{"n_labels": 32, "accuracy": 0.5 + 0.01 * seed}] for seed in seeds]}
                      for s in ("entropy", "random")}}
    if model is not None:
        doc["model"] = model
    path.write_text(json.dumps(doc))
    return str(path)


def test_merge_active_learning_runs_protocol_rules(tmp_path):
    from vtlearn.models.xavtnet_cli import merge_active_learning_runs

    m128, m256 = {"global_dim": 128}, {"global_dim": 256}
    # under equal steps min_steps is unused, so an older run's min_steps does not block the merge;
    # a file written before the model was recorded merges with one that records it
    a = _al_result(tmp_path / "a.json", [0, 1], min_steps=250)
    b = _al_result(tmp_path / "b.json", [3], model=m128, min_steps=0)
    meta, runs = merge_active_learning_runs([a, b])
    assert meta["seeds"] == [0, 1, 3] and meta["model"] == m128 and meta["full_acc"] == [0.9] * 3
    assert [r[0]["accuracy"] for r in runs["entropy"]] == pytest.approx([0.50, 0.51, 0.53])
    # different models, or min_steps when training length follows the label count, are other protocols
    c = _al_result(tmp_path / "c.json", [4], model=m256)
    with pytest.raises(ValueError, match="different models"):
        merge_active_learning_runs([b, c])
    d = _al_result(tmp_path / "d.json", [0], min_steps=250, train_steps=None)
    e = _al_result(tmp_path / "e.json", [1], min_steps=100, train_steps=None)
    with pytest.raises(ValueError, match="min_steps"):
        merge_active_learning_runs([d, e])
    f = _al_result(tmp_path / "f.json", [5], kappa=64)
    with pytest.raises(ValueError, match="kappa"):
        merge_active_learning_runs([a, f])
    # runs of other strategies on the same seeds are joined first, then pooled with other seeds
    g = _al_result(tmp_path / "g.json", [0, 1], min_steps=250)
    doc = json.loads(Path(g).read_text())
    doc["curves"] = {"bald": doc["curves"]["entropy"]}
    Path(g).write_text(json.dumps(doc))
    meta, runs = merge_active_learning_runs([a, g])
    assert list(runs) == ["entropy", "random", "bald"] and meta["seeds"] == [0, 1]
    assert meta["full_acc"] == [0.9, 0.9] and meta["active"]["strategies"] == "entropy,random,bald"
    meta, runs = merge_active_learning_runs([a, g, b])  # seed 3 has no bald: the common strategies
    assert list(runs) == ["entropy", "random"] and meta["seeds"] == [0, 1, 3]
    with pytest.raises(ValueError, match="repeat seeds"):  # the same (seed, strategy) twice
        merge_active_learning_runs([a, a])
    h = _al_result(tmp_path / "h.json", [1, 2])
    with pytest.raises(ValueError, match="without having the same seeds"):
        merge_active_learning_runs([a, h])
    doc["full_acc"] = [0.9, 0.8]
    Path(g).write_text(json.dumps(doc))
    with pytest.raises(ValueError, match="other full-pool references"):
        merge_active_learning_runs([a, g])
    # runs on other data under the same folder name are refused; a file without a fingerprint (written
    # before it was recorded) merges with one that has it, and the merged result keeps the one known
    fa, fb, fc = (_al_result(tmp_path / f"fp{i}.json", [i], min_steps=250) for i in range(3))
    for path, fp in ((fa, "aaaa"), (fb, "bbbb")):
        doc = json.loads(Path(path).read_text())
        doc["data_fingerprint"] = {"data_dir": fp}
        Path(path).write_text(json.dumps(doc))
    with pytest.raises(ValueError, match="other data"):
        merge_active_learning_runs([fa, fb])
    meta, _ = merge_active_learning_runs([fc, fa])
    assert meta["data_fingerprint"] == {"data_dir": "aaaa"}
    with pytest.raises(ValueError, match="other data"):  # also when the first file has no fingerprint
        merge_active_learning_runs([fc, fa, fb])


def test_adapt_bn_command_writes_a_loadable_adapted_checkpoint(tmp_path, tiny_crossmodal, capsys):
    import lightning as L
    import torch

    from vtlearn.cli import main
    from vtlearn.datamodules import CrossModalDataModule

    dm = CrossModalDataModule(str(tiny_crossmodal), batch_size=4)
    model = XAVTNet(num_classes=dm.num_classes, global_dim=32, fc_dims=[16, 8], max_points=64)
    trainer = L.Trainer(max_epochs=1, accelerator="cpu", logger=False, enable_progress_bar=False,
                        enable_model_summary=False, enable_checkpointing=False, limit_val_batches=0,
                        default_root_dir=tmp_path)
    trainer.fit(model, train_dataloaders=dm.train_dataloader())
    ckpt, out = tmp_path / "in.ckpt", tmp_path / "adapted" / "out.ckpt"
    trainer.save_checkpoint(ckpt)
    assert main(["adapt-bn", "--ckpt", str(ckpt), "--data", str(tiny_crossmodal), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "unlabelled tactile clouds" in text and "tactile test accuracy" in text
    adapted = XAVTNet.load_from_checkpoint(out, map_location="cpu", weights_only=True).eval()
    assert adapted.hparams.domain_bn
    original = XAVTNet.load_from_checkpoint(ckpt, map_location="cpu", weights_only=True).eval()
    x = torch.randn(2, 20, 3)
    with adapted.bn_domain("source"):  # the visual side is the trained network
        assert torch.allclose(adapted(x).logits, original(x).logits, atol=1e-6)
    assert not torch.allclose(adapted(x).logits, original(x).logits, atol=1e-4)
    assert "optimizer_states" not in torch.load(out, map_location="cpu", weights_only=True)
    # bad input is refused by name, and the input checkpoint is never overwritten
    assert main(["adapt-bn", "--ckpt", str(tmp_path / "none.ckpt"), "--data", str(tiny_crossmodal),
                 "--out", str(out)]) == 2
    assert "--ckpt" in capsys.readouterr().err
    assert main(["adapt-bn", "--ckpt", str(ckpt), "--data", str(tiny_crossmodal), "--out", str(ckpt)]) == 2
    assert "--out" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main(["adapt-bn", "--ckpt", str(ckpt), "--data", str(tiny_crossmodal), "--passes", "0",
              "--out", str(out)])
    assert exc.value.code == 2 and "argument --passes: must be >= 1" in capsys.readouterr().err
    other = tmp_path / "other.ckpt"  # a Lightning checkpoint of another model
    torch.save({"state_dict": {"decoder.w": torch.zeros(2)}, "hyper_parameters": {}}, other)
    assert main(["adapt-bn", "--ckpt", str(other), "--data", str(tiny_crossmodal), "--out", str(out)]) == 2
    assert "not an xAVTNet checkpoint" in capsys.readouterr().err


def _counting_loader(items, batch_size):
    """A loader factory whose loaders count, in ``factory.passes``, how often they are iterated."""
    import torch

    class Counting(torch.utils.data.DataLoader):
        def __iter__(self):
            factory.passes += 1
            return super().__iter__()

    def factory():
        return Counting(items, batch_size=batch_size)

    factory.passes = 0
    return factory


def test_balanced_accuracy_scores_the_balanced_assignment_and_keeps_the_random_state():
    """--balanced scores the Sinkhorn assignment of the whole test loader's eval-mode probabilities, and
    leaves torch's random state as it found it, so that it does not move the scores computed after it."""
    from types import SimpleNamespace

    import torch

    from vtlearn.models.components.class_balance import sinkhorn_balance
    from vtlearn.models.xavtnet_cli import _readout_scores

    torch.manual_seed(0)
    model = XAVTNet(num_classes=3, global_dim=32, fc_dims=[16, 8]).train()
    clouds = torch.randn(12, 20, 3)
    labels = torch.arange(12) % 3
    dm = SimpleNamespace(test_dataloader=_counting_loader(
        [{"points": p, "lengths": torch.tensor(20), "label": y} for p, y in zip(clouds, labels, strict=True)],
        batch_size=5))
    state = torch.random.get_rng_state()
    scores = _readout_scores(model, dm, prior=[1 / 3, 1 / 3, 1 / 3])
    assert torch.equal(torch.random.get_rng_state(), state)
    assert model.training  # the training flag is restored
    assert set(scores) == {"tactile_acc_balanced"}
    with torch.no_grad():
        probs = model.eval()(clouds, torch.full((12,), 20)).logits.softmax(-1)
    expected = (sinkhorn_balance(probs).argmax(-1) == labels).double().mean() * 100
    assert scores["tactile_acc_balanced"] == pytest.approx(float(expected))


def test_score_checks_write_each_kind_against_its_own_model_plain_noda_and_noda_like_for_like():
    """One rule for every extra score (--adabn, --balanced, --centroid, --probe): each row's and teacher's
    score less its own accuracy, less plain no-DA's, and less no-DA's score of the same kind; no-DA's own
    network has no like-for-like check, and nothing is written for a score a row lacks."""
    from vtlearn.models.xavtnet_cli import _score_checks

    rows = [
        {"variant": "noda", "tactile_mean": 40.0, "tactile_adabn_mean": 45.0},
        {"variant": "vtloss_g12_mt", "tactile_mean": 50.0, "tactile_teacher_mean": 52.0,
         "tactile_adabn_mean": 49.0, "tactile_teacher_adabn_mean": 56.0},
        {"variant": "vtloss", "tactile_mean": 47.0},
    ]
    checks = {}
    for what in ("adabn", "balanced", "centroid", "probe"):
        _score_checks(rows, what, checks)
    assert checks == {
        "noda_adabn_minus_acc": 5.0, "noda_adabn_minus_noda": 5.0,
        "vtloss_g12_mt_adabn_minus_acc": -1.0, "vtloss_g12_mt_adabn_minus_noda": 9.0,
        "vtloss_g12_mt_adabn_minus_noda_adabn": 4.0,
        "vtloss_g12_mt_teacher_adabn_minus_acc": 4.0, "vtloss_g12_mt_teacher_adabn_minus_noda": 16.0,
        "vtloss_g12_mt_teacher_adabn_minus_noda_adabn": 11.0,
    }
    # without a no-DA row only the score against the model's own accuracy is left
    checks = {}
    _score_checks(rows[1:], "adabn", checks)
    assert checks == {"vtloss_g12_mt_adabn_minus_acc": -1.0, "vtloss_g12_mt_teacher_adabn_minus_acc": 4.0}
    # a no-DA row without the score: no like-for-like check, the others stay
    checks = {}
    _score_checks([{"variant": "noda", "tactile_mean": 40.0}, rows[1]], "adabn", checks)
    assert "vtloss_g12_mt_adabn_minus_noda_adabn" not in checks
    assert checks["vtloss_g12_mt_adabn_minus_noda"] == 9.0


def test_feature_scores_read_the_features_not_the_classifier_and_keep_the_random_state():
    """--probe fits a linear probe on the labelled tactile training clouds' global features and scores the
    test clouds: on three classes of clouds that differ in scale, an untrained network's features separate
    them perfectly while its classifier does not. --centroid is SHOT's centroid labelling of the test
    features. Neither moves torch's random state, so the scores after them are unchanged, and all three
    readings together take one pass over the test clouds."""
    from types import SimpleNamespace

    import numpy as np
    import torch

    from vtlearn.losses.pseudo_labels import centroid_pseudo_labels
    from vtlearn.models.xavtnet_cli import _readout_scores

    torch.manual_seed(0)
    model = XAVTNet(num_classes=3, global_dim=32, fc_dims=[16, 8]).train()

    def loader(n, seed):
        g = torch.Generator().manual_seed(seed)
        labels = torch.arange(n) % 3
        clouds = torch.randn(n, 20, 3, generator=g) * (0.1 * 10.0 ** labels)[:, None, None]
        items = [{"points": p, "lengths": torch.tensor(20), "label": y}
                 for p, y in zip(clouds, labels, strict=True)]
        return _counting_loader(items, batch_size=7)

    dm = SimpleNamespace(test_dataloader=loader(30, 1), labelled_target_train_dataloader=loader(60, 2))
    state = torch.random.get_rng_state()
    scores = _readout_scores(model, dm, prior=[1 / 3] * 3, probe=True, centroid=True)
    assert torch.equal(torch.random.get_rng_state(), state)
    assert model.training  # extract_features restores the training flag
    assert set(scores) == {"tactile_acc_probe", "tactile_acc_centroid", "tactile_acc_balanced"}
    assert dm.test_dataloader.passes == 1 and dm.labelled_target_train_dataloader.passes == 1
    assert scores["tactile_acc_probe"] == 100.0
    with torch.no_grad():
        batch = next(iter(torch.utils.data.DataLoader(list(dm.test_dataloader().dataset), batch_size=30)))
        out = model.extract_features(batch["points"], batch["lengths"])
    classifier = 100 * float((out["logits"].argmax(-1) == batch["label"]).double().mean())
    assert classifier < 100.0  # the untrained classifier does not separate what its features do
    pseudo = centroid_pseudo_labels(out["global"].double(), out["logits"].double().softmax(-1))
    assert scores["tactile_acc_centroid"] == pytest.approx(100 * float(np.mean(pseudo.numpy()
                                                                            == batch["label"].numpy())))
    # each reading alone scores as it does beside the others
    assert _readout_scores(model, dm, probe=True) == {"tactile_acc_probe": scores["tactile_acc_probe"]}
    assert _readout_scores(model, dm) == {}


def test_adapt_bn_reads_the_clouds_as_the_checkpoint_was_trained(tmp_path, tiny_crossmodal, capsys):
    import copy

    import lightning as L
    import torch

    from vtlearn.cli import main
    from vtlearn.datamodules import CrossModalDataModule

    torch.manual_seed(0)
    model = XAVTNet(num_classes=3, global_dim=32, fc_dims=[16, 8], input_normalize="none")
    ckpt, out = tmp_path / "in.ckpt", tmp_path / "out.ckpt"
    torch.save({"state_dict": model.state_dict(), "hyper_parameters": dict(model.hparams)}, ckpt)
    assert main(["adapt-bn", "--ckpt", str(ckpt), "--data", str(tiny_crossmodal), "--out", str(out),
                 "--batch-size", "1024"]) == 0
    got = torch.load(out, map_location="cpu", weights_only=True)["state_dict"]
    stats = [k for k in got if k.endswith("running_mean_target")]
    assert stats
    for normalize in ("none", "center"):  # the same adaptation by hand, on the object frame and centred
        L.seed_everything(0, verbose=False)
        dm = CrossModalDataModule(str(tiny_crossmodal), batch_size=1024, target_split="train", seed=0,
                                  normalize=normalize)
        twin = copy.deepcopy(model)
        # the command scores the test clouds first, which draws from torch's stream as a test pass does
        L.Trainer(accelerator="cpu", devices=1, logger=False, enable_progress_bar=False,
                  enable_model_summary=False).test(twin, dataloaders=dm.test_dataloader(), verbose=False)
        twin.adapt_bn_statistics(dm.target_dataloader())
        same = all(torch.allclose(got[k], twin.state_dict()[k], atol=1e-6) for k in stats)
        assert same == (normalize == "none"), normalize


def test_adabn_score_converts_the_model_and_keeps_the_random_state(tiny_crossmodal):
    """--adabn's score re-estimates the target statistics on the shuffled target stream; it leaves torch's
    random state as it found it, so the teacher's scores drawn after it are those of a run without it."""
    import copy

    import torch

    from vtlearn.datamodules import CrossModalDataModule
    from vtlearn.models.xavtnet_cli import _adabn_acc, _test_acc, _trainer

    dm = CrossModalDataModule(data_dir=str(tiny_crossmodal), batch_size=4, seed=0)
    dm.setup("fit")
    torch.manual_seed(0)
    model = XAVTNet(num_classes=dm.num_classes, global_dim=32, fc_dims=[16, 8])
    twin = copy.deepcopy(model)
    trainer = _trainer(1)
    state = torch.random.get_rng_state()
    acc = _adabn_acc(trainer, model, dm)
    assert torch.equal(torch.random.get_rng_state(), state)
    assert model.hparams.domain_bn  # converted to statistics per domain, target ones re-estimated
    with torch.random.fork_rng():  # the same steps by hand, from the same random state
        twin.adapt_bn_statistics(dm.target_dataloader())
        assert acc == pytest.approx(100 * _test_acc(trainer, twin, dm.test_dataloader()))


def test_train_py_reports_a_bad_config_in_one_line(tmp_path, tiny_crossmodal, capsys, monkeypatch):
    """A dataset directory without a manifest, or a model whose class count differs from the dataset's, ends
    train.py with exit code 2 and one line naming the argument, not a traceback through jsonargparse."""
    monkeypatch.syspath_prepend(str(ROOT))
    monkeypatch.chdir(tmp_path)
    from train import _reason, main

    def config(data_dir, num_classes):
        path = tmp_path / "cfg.yaml"
        path.write_text(yaml.safe_dump({
            "model": {"class_path": "vtlearn.models.xavtnet.XAVTNet",
                      "init_args": {"num_classes": num_classes, "global_dim": 32, "fc_dims": [16, 8]}},
            "data": {"class_path": "vtlearn.datamodules.CrossModalDataModule",
                     "init_args": {"data_dir": str(data_dir), "batch_size": 4}},
            "trainer": {"max_epochs": 1, "logger": False, "enable_checkpointing": False}}))
        return f"--config={path}"

    assert main(["fit", config(tmp_path / "no_dataset_here", 3)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("train.py: error: data_dir: no manifest.json in")
    assert not any("Traceback" in line for line in err)
    assert main(["fit", config(tiny_crossmodal, 7)]) == 2
    err = capsys.readouterr().err
    assert "train.py: error: datamodule:" in err and "num_classes=7" in err and "Traceback" not in err
    # the jsonargparse union report keeps the vtlearn alternative's line only
    text = ("Does not validate against any of the Union subtypes\nSubtypes: [...]\nErrors:\n"
            "  - data_dir: missing\n  - Expected a <class 'NoneType'>\nGiven value: ...")
    assert _reason(ValueError(text)) == "data_dir: missing"
    assert _reason(ValueError("plain")) == "plain"


def test_benches_write_their_json_before_a_figure_that_fails(tmp_path, tiny_crossmodal, monkeypatch):
    """The trained results reach the JSON before any figure is drawn: a figure that raises (a full disk, a
    matplotlib backend error) loses the figure, not the trainings."""
    import vtlearn.models.xavtnet_cli as xcli
    from vtlearn.cli import main

    def boom(*a, **k):
        raise RuntimeError("figure failed")

    monkeypatch.setattr(xcli, "_confusion_figure", boom)
    cfg = tiny_xavtnet_config(tmp_path, tiny_crossmodal)
    out = tmp_path / "cm.json"
    with pytest.raises(RuntimeError, match="figure failed"):
        main(["bench", "crossmodal", "--config", str(cfg), "--variants", "noda", "--seeds", "1",
              "--json", str(out)])
    res = json.loads(out.read_text())
    assert [r["variant"] for r in res["runs"]] == ["noda"] and res["figures"] == {}

    monkeypatch.setattr(xcli, "save_figure", boom)
    cfg = tiny_xavtnet_config(tmp_path, tiny_crossmodal, active=True)
    out = tmp_path / "al.json"
    with pytest.raises(RuntimeError, match="figure failed"):
        main(["bench", "active-learning", "--config", str(cfg), "--seeds", "1", "--json", str(out)])
    res = json.loads(out.read_text())
    assert set(res["curves"]) == {"entropy", "random"} and "figure" not in res  # recorded once drawn


def test_bench_crossmodal_records_the_balance_rules_cap():
    """A row with the online balance rule records the cap on its λ_t beside its settings: the cap is a class
    constant that a JSON would otherwise not show (stop 51 ran the same row at two caps)."""
    from vtlearn.losses.vtloss import VTLoss
    from vtlearn.models.xavtnet_cli import VARIANTS, _variant_settings

    got = _variant_settings(["vtloss", "vtloss_bal", "coral_bal"])
    assert got["vtloss"] == VARIANTS["vtloss"] and "lam_balance_max" not in got["vtloss"]
    for name in ("vtloss_bal", "coral_bal"):
        assert got[name] == {**VARIANTS[name], "lam_balance_max": VTLoss.LAM_BALANCE_MAX}
    assert "lam_balance_max" not in VARIANTS["vtloss_bal"]  # the table itself is left as it was
    json.dumps(got)


def test_domain_discrepancy_is_zero_for_one_domain_and_grows_with_a_shift():
    """--discrepancy measures eq. 7.5-7.7 on the eval-mode features of the whole visual and tactile test sets:
    the same clouds in both give 0 for MMD and CORAL; target clouds stretched along z give both > 0, and
    the values are those of mk_mmd and coral on the features read by hand. Torch's random state and the
    training flag are left as they were."""
    from types import SimpleNamespace

    import torch

    from vtlearn.losses.coral import coral
    from vtlearn.losses.mmd import mk_mmd
    from vtlearn.models.xavtnet_cli import DISCREPANCY_LAYERS, _domain_discrepancy

    torch.manual_seed(0)
    model = XAVTNet(num_classes=3, global_dim=32, fc_dims=[16, 8]).train()
    g = torch.Generator().manual_seed(3)
    clouds = torch.randn(18, 20, 3, generator=g)

    def loader(pts):
        return _counting_loader([{"points": p, "lengths": torch.tensor(20), "label": torch.tensor(0)}
                                 for p in pts], batch_size=7)

    state = torch.random.get_rng_state()
    same = _domain_discrepancy(model, SimpleNamespace(source_test_dataloader=loader(clouds),
                                                      test_dataloader=loader(clouds)))
    assert torch.equal(torch.random.get_rng_state(), state) and model.training
    assert set(same) == {f"{k}_{layer}" for k in ("mmd", "coral", "norm") for layer in DISCREPANCY_LAYERS}
    assert all(v == pytest.approx(1.0 if k.startswith("norm") else 0.0, abs=1e-12) for k, v in same.items())
    stretched = clouds * torch.tensor([1.0, 1.0, 3.0])
    shifted = _domain_discrepancy(model, SimpleNamespace(source_test_dataloader=loader(clouds),
                                                         test_dataloader=loader(stretched)))
    # an untrained network's features are small, so CORAL's fourth-order scale is too: both are well above 0
    assert all(shifted[f"mmd_{layer}"] > 0.1 and shifted[f"coral_{layer}"] > 1e-9
               for layer in DISCREPANCY_LAYERS)
    with torch.no_grad():
        src = model.extract_features(clouds, torch.full((18,), 20))
        tgt = model.extract_features(stretched, torch.full((18,), 20))
    for layer in DISCREPANCY_LAYERS:
        s, t = src[layer].double(), tgt[layer].double()
        assert shifted[f"mmd_{layer}"] == pytest.approx(float(mk_mmd(s, t)), rel=1e-4)
        assert shifted[f"coral_{layer}"] == pytest.approx(float(coral(s, t)), rel=1e-4)
        assert shifted[f"norm_{layer}"] == pytest.approx(float(t.norm(dim=1).mean() / s.norm(dim=1).mean()),
                                                         rel=1e-4)


def test_domain_discrepancy_norm_ratio_is_nan_where_the_visual_features_are_all_zero(monkeypatch):
    """A layer whose visual features are all zero (dead ReLUs) has no norm ratio: NaN, which the table prints
    as "-" and the JSON writes as null, instead of inf or a division warning; the other layers keep theirs."""
    from types import SimpleNamespace

    import numpy as np
    import torch

    from vtlearn.bench_utils import to_jsonable
    from vtlearn.models import xavtnet_cli

    real = xavtnet_cli._collect_features
    calls = []

    def zero_source_fc2(model, loader, layers):
        feats, labels = real(model, loader, layers)
        if not calls:  # the first pass reads the visual test clouds
            feats["fc2"] = np.zeros_like(feats["fc2"])
        calls.append(loader)
        return feats, labels

    monkeypatch.setattr(xavtnet_cli, "_collect_features", zero_source_fc2)
    torch.manual_seed(0)
    model = XAVTNet(num_classes=3, global_dim=32, fc_dims=[16, 8])
    clouds = torch.randn(10, 20, 3, generator=torch.Generator().manual_seed(4))
    loader = _counting_loader([{"points": p, "lengths": torch.tensor(20), "label": torch.tensor(0)}
                               for p in clouds], batch_size=5)
    out = xavtnet_cli._domain_discrepancy(model, SimpleNamespace(source_test_dataloader=loader,
                                                                 test_dataloader=loader))
    assert len(calls) == 2 and np.isnan(out["norm_fc2"])
    assert out["norm_fc1"] == pytest.approx(1.0) and out["norm_global"] == pytest.approx(1.0)
    assert to_jsonable(out)["norm_fc2"] is None
