"""Seed-paired comparisons of ``bench crossmodal`` rows and the pooling of results (``--merge``)."""

import json

import numpy as np
import pytest
from scipy import stats

from vtlearn.bench_utils import paired_difference
from vtlearn.models.crossmodal_compare import (
    default_pairs,
    load_crossmodal_results,
    paired_rows,
    parse_pairs,
    score_field,
)

HOST_A = {"platform": "Linux-6.18.44-fc-v1252-x86_64", "cpu_model": "AMD EPYC", "cpu_capability": "AVX512"}
HOST_B = {"platform": "Linux-6.18.44-fc-v1147-x86_64"}


def test_paired_difference_matches_scipy_and_the_t_interval():
    a = np.array([50.0, 47.5, 53.1, 49.0, 55.2, 51.0])
    b = np.array([41.0, 42.5, 40.0, 44.1, 43.0, 45.2])
    out = paired_difference(a, b, margin=5.0)
    d = a - b
    assert out["pairs"] == 6 and out["mean_diff"] == pytest.approx(d.mean())
    assert out["sd"] == pytest.approx(d.std(ddof=1))
    assert out["t_p"] == pytest.approx(stats.ttest_rel(a, b).pvalue)
    assert out["wilcoxon_p"] == pytest.approx(stats.wilcoxon(d).pvalue)
    lo, hi = stats.t.interval(0.95, 5, loc=d.mean(), scale=d.std(ddof=1) / np.sqrt(6))
    assert out["ci95"] == pytest.approx([lo, hi])
    # one-sided: H0 "the margin is no more than 5"; scipy's alternative='greater' on d - 5
    one_sided = stats.ttest_1samp(d - 5.0, 0.0, alternative="greater").pvalue
    assert out["p_at_most_margin"] == pytest.approx(one_sided)
    assert (out["ahead"], out["behind"]) == (6, 0)
    # a margin far above the differences is not shown to be exceeded
    assert paired_difference(a, b, margin=30.0)["p_at_most_margin"] > 0.99


def test_paired_difference_with_one_pair_or_constant_differences():
    one = paired_difference([3.0], [1.0])
    assert one["mean_diff"] == 2.0 and one["sd"] == 0.0
    assert one["ci95"] is None and one["t_p"] is None and one["wilcoxon_p"] is None
    same = paired_difference([2.0, 3.0, 4.0], [1.0, 2.0, 3.0], margin=0.5)
    assert same["mean_diff"] == pytest.approx(1.0)
    assert same["ci95"] is None and same["p_at_most_margin"] is None


@pytest.mark.parametrize("a, b, match", [
    ([], [], "non-empty"),
    ([1.0, 2.0], [1.0], "same length"),
    ([[1.0, 2.0]], [[1.0, 2.0]], "1-D"),
    ([1.0, np.nan], [1.0, 2.0], "finite"),
])
def test_paired_difference_refuses_bad_samples(a, b, match):
    with pytest.raises(ValueError, match=match):
        paired_difference(a, b)


def test_pairs_and_score_fields_parse_or_are_refused_by_flag():
    assert parse_pairs("vtloss-mmd, vtloss_g12_mt_vote.teacher-noda_vote") == [
        ("vtloss", "mmd"), ("vtloss_g12_mt_vote.teacher", "noda_vote")]
    assert parse_pairs(None) == [] and parse_pairs(" , ") == []
    assert score_field("vtloss") == ("vtloss", "tactile_acc")
    assert score_field("x.teacher_adabn") == ("x", "tactile_acc_teacher_adabn")
    for bad in ("vtloss", "vtloss-", "-noda", "a-b-c", "vtloss.-noda"):
        with pytest.raises(ValueError, match="--pairs"):
            parse_pairs(bad)


def _runs(variant, seeds, accs, **extra):
    return [{"variant": variant, "seed": s, "tactile_acc": a, "visual_acc": 90.0, **extra}
            for s, a in zip(seeds, accs, strict=True)]


def _result(tmp_path, name, runs, machine=HOST_A, **over):
    doc = {"bench": "crossmodal", "data": {"data_dir": "runs/x", "batch_size": 32}, "max_epochs": 30,
           "model_base": {"lr": 0.001}, "data_fingerprint": {"data_dir": "abc"}, "runs": runs,
           "machine": machine, "config": "c.yaml", **over}
    path = tmp_path / name
    path.write_text(json.dumps(doc))
    return str(path)


def test_merge_pools_seeds_and_rows_and_pairs_them(tmp_path):
    f1 = _result(tmp_path, "a.json", _runs("noda", [0, 1, 2], [40.0, 41.0, 39.0])
                 + _runs("vtloss", [0, 1, 2], [50.0, 48.0, 47.0]))
    f2 = _result(tmp_path, "b.json", _runs("noda", [2, 3], [39.0, 44.0])  # seed 2 repeated alike: kept once
                 + _runs("vtloss", [3], [53.0])
                 + _runs("vote", [0, 1, 2, 3], [60.0, 58.0, 62.0, 61.0], tactile_acc_teacher=61.0))
    meta, runs = load_crossmodal_results([f1, f2])
    assert len(runs) == 3 + 3 + 1 + 1 + 4 and meta["merged_from"] == [f1, f2]
    assert meta["data_fingerprint"] == {"data_dir": "abc"} and meta["max_epochs"] == 30
    variants = list(dict.fromkeys(r["variant"] for r in runs))
    pairs = default_pairs(variants, runs, "noda")
    assert pairs == [("vtloss", "noda"), ("vote", "noda"), ("vote.teacher", "noda")]
    rows = {r["comparison"]: r for r in paired_rows(runs, pairs + [("vote", "vtloss")], margin=20.0)}
    vt = rows["vtloss − noda"]
    assert vt["seeds"] == [0, 1, 2, 3] and vt["diffs"] == pytest.approx([10.0, 7.0, 8.0, 9.0])
    assert vt["mean_diff"] == pytest.approx(8.5) and vt["ahead"] == 4 and vt["cross_machine"] == 0
    assert rows["vote.teacher − noda"]["diffs"] == pytest.approx([21.0, 20.0, 22.0, 17.0])
    assert rows["vote − vtloss"]["mean_diff"] == pytest.approx(np.mean([10.0, 10.0, 15.0, 8.0]))
    assert rows["vtloss − noda"]["p_at_most_margin"] > 0.99
    assert default_pairs(variants, runs, "nope") == []


def test_pairs_across_machines_are_counted(tmp_path):
    f1 = _result(tmp_path, "a.json",
                 _runs("noda", [0, 1], [40.0, 41.0]) + _runs("vtloss", [0, 1], [50.0, 48.0]))
    f2 = _result(tmp_path, "b.json", _runs("mmd", [0, 1, 2], [49.0, 47.0, 50.0]), machine=HOST_B)
    _, runs = load_crossmodal_results([f1, f2])
    rows = {r["comparison"]: r for r in paired_rows(runs, [("vtloss", "mmd"), ("vtloss", "noda")])}
    assert rows["vtloss − mmd"]["cross_machine"] == 2 and rows["vtloss − noda"]["cross_machine"] == 0
    # the same host with the CPU recorded on one side only is still the same host
    f3 = _result(tmp_path, "c.json", _runs("coral", [0], [42.0]), machine={"platform": HOST_A["platform"]})
    _, runs = load_crossmodal_results([f1, f3])
    assert paired_rows(runs, [("vtloss", "coral")])[0]["cross_machine"] == 0


def test_pairs_without_runs_or_common_seeds_are_refused(tmp_path):
    f1 = _result(tmp_path, "a.json", _runs("noda", [0, 1], [40.0, 41.0]) + _runs("mmd", [5], [50.0]))
    _, runs = load_crossmodal_results([f1])
    with pytest.raises(ValueError, match="no run of vtloss with tactile_acc"):
        paired_rows(runs, [("vtloss", "noda")])
    with pytest.raises(ValueError, match="no run of noda with tactile_acc_teacher"):
        paired_rows(runs, [("mmd", "noda.teacher")])
    with pytest.raises(ValueError, match="share no seed"):
        paired_rows(runs, [("mmd", "noda")])


def test_merge_refuses_other_protocols_and_conflicting_runs(tmp_path):
    base = _runs("noda", [0], [40.0])
    f1 = _result(tmp_path, "a.json", base)
    with pytest.raises(ValueError, match="--merge: no such file"):
        load_crossmodal_results([f1, str(tmp_path / "nope.json")])
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(ValueError, match="is not a JSON file"):
        load_crossmodal_results([str(tmp_path / "bad.json")])
    (tmp_path / "al.json").write_text(json.dumps({"bench": "active-learning", "curves": {}}))
    with pytest.raises(ValueError, match="is not a `bench crossmodal` result"):
        load_crossmodal_results([f1, str(tmp_path / "al.json")])
    with pytest.raises(ValueError, match="give at least one"):
        load_crossmodal_results([])
    other = _result(tmp_path, "fp.json", _runs("noda", [1], [41.0]), data_fingerprint={"data_dir": "zzz"})
    with pytest.raises(ValueError, match="other data"):
        load_crossmodal_results([f1, other])
    epochs = _result(tmp_path, "ep.json", _runs("noda", [1], [41.0]), max_epochs=60)
    with pytest.raises(ValueError, match="max_epochs=60"):
        load_crossmodal_results([f1, epochs])
    model = _result(tmp_path, "mo.json", _runs("noda", [1], [41.0]), model_base={"lr": 0.01})
    with pytest.raises(ValueError, match="model_base"):
        load_crossmodal_results([f1, model])
    clash = _result(tmp_path, "cl.json", _runs("noda", [0], [43.0]))
    with pytest.raises(ValueError, match="both hold noda seed 0"):
        load_crossmodal_results([f1, clash])
    s1 = _result(tmp_path, "s1.json", base, variant_settings={"noda": {"da_method": "none"}})
    s2 = _result(tmp_path, "s2.json", _runs("noda", [1], [41.0]),
                 variant_settings={"noda": {"da_method": "none", "domain_bn": True}})
    with pytest.raises(ValueError, match="trains noda with"):
        load_crossmodal_results([s1, s2])
    # results from before the fingerprint was recorded are compared on the rest
    old = _result(tmp_path, "old.json", _runs("noda", [1], [41.0]), data_fingerprint=None)
    assert len(load_crossmodal_results([f1, old])[1]) == 2
