"""Seed-paired comparisons of ``bench crossmodal`` rows and the pooling of results (``--merge``)."""

import json
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from vtlearn.bench_utils import holm_adjust, paired_difference
from vtlearn.models.crossmodal_compare import (
    check_versus_protocol,
    default_pairs,
    generation_differences,
    load_crossmodal_results,
    load_object_sets,
    paired_rows,
    paired_table_columns,
    parse_pairs,
    per_class_scores,
    per_class_table_rows,
    score_field,
    set_paired_rows,
    set_summaries,
    set_table_rows,
    versus_set_rows,
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


def test_holm_adjustment_matches_the_step_down_rule():
    # Holm 1979 by hand: sorted 0.01, 0.02, 0.03, 0.04 of m = 4 -> 4·0.01, 3·0.02, then 2·0.03 = 0.06 is
    # below the running 0.06, and 1·0.04 is lifted to it (the adjusted values never fall with the rank)
    assert holm_adjust([0.03, 0.01, 0.04, 0.02]) == pytest.approx([0.06, 0.04, 0.06, 0.06])
    # capped at 1; undefined p-values stay undefined and are not counted in m
    assert holm_adjust([0.5, None, 0.2]) == [pytest.approx(0.5), None, pytest.approx(0.4)]
    assert holm_adjust([0.9, 0.8]) == pytest.approx([1.0, 1.0]) and holm_adjust([0.3]) == [0.3]
    assert holm_adjust([]) == []
    # every adjusted p is at least the raw one and at most m times it
    raw = np.random.default_rng(1).uniform(0, 0.3, 7)
    adj = np.array(holm_adjust(raw.tolist()))
    assert np.all(adj >= raw) and np.all(adj <= np.minimum(1.0, 7 * raw) + 1e-12)
    for bad in ([1.5], [-0.1], [float("nan")], ["0.1"]):
        with pytest.raises(ValueError, match=r"pvalues\[0\]: need a probability"):
            holm_adjust(bad)


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
    # the t-test p of each comparison, adjusted over the table's family of four
    raw = [rows[c]["t_p"] for c in rows]
    assert [rows[c]["t_p_holm"] for c in rows] == pytest.approx(holm_adjust(raw))
    assert all(rows[c]["t_p_holm"] >= rows[c]["t_p"] for c in rows) and rows["vtloss − noda"]["p (Holm)"]
    assert "p (Holm)" in paired_table_columns(list(rows.values()), 20.0)
    one = paired_rows(runs, [("vtloss", "noda")])  # one comparison: nothing to adjust
    assert one[0]["t_p_holm"] is None and "p (Holm)" not in paired_table_columns(one, None)
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
    # one kernel build and CPU name, but AVX2 kernels instead of AVX-512 ones: another host's rounding
    avx2 = {**HOST_A, "cpu_capability": "AVX2"}
    f4 = _result(tmp_path, "d.json", _runs("coral", [0], [42.0]), machine=avx2)
    _, runs = load_crossmodal_results([f1, f4])
    assert paired_rows(runs, [("vtloss", "coral")])[0]["cross_machine"] == 1


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


def _set(tmp_path, name, fp, runs, data_dir=None, **over):
    """A result of one object set: ``fp`` its data fingerprint, ``data_dir`` its folder."""
    data = {"data_dir": data_dir or f"runs/xavtnet/{fp}", "batch_size": 32}
    return _result(tmp_path, name, runs, **{"data": data, "data_fingerprint": {"data_dir": fp}, **over})


def test_object_sets_are_paired_by_their_means(tmp_path):
    # set s1 in two files (rows run apart), s2 and s3 in one each; s3 has no mmd
    a1 = _set(tmp_path, "s1a.json", "s1", _runs("noda", [0, 1, 2], [30.0, 33.0, 36.0])
              + _runs("vtloss", [0, 1, 2], [50.0, 52.0, 51.0]))
    a2 = _set(tmp_path, "s1b.json", "s1", _runs("mmd", [0, 1, 2], [55.0, 50.0, 51.0]), machine=HOST_B)
    b = _set(tmp_path, "s2.json", "s2", _runs("noda", [0, 1], [40.0, 42.0])
             + _runs("vtloss", [0, 1], [45.0, 49.0]) + _runs("mmd", [0, 1], [44.0, 47.0]))
    c = _set(tmp_path, "s3.json", "s3", _runs("noda", [0, 1, 2], [28.0, 26.0, 30.0])
             + _runs("vtloss", [0, 1], [54.0, 50.0]))
    meta, sets = load_object_sets([a1, b, a2, c])
    assert [s["label"] for s in sets] == ["s1", "s2", "s3"] and sets[0]["files"] == [a1, a2]
    assert meta["data"] == {"batch_size": 32} and meta["max_epochs"] == 30 and meta["merged_from"][0] == a1
    rows = {r["comparison"]: r for r in set_paired_rows(sets, [("vtloss", "noda"), ("vtloss", "mmd")], 20.0)}
    vt = rows["vtloss − noda"]
    # each set's pair is the means over the seeds both rows have there (s3: seeds 0-1 only)
    assert vt["sets"] == ["s1", "s2", "s3"]
    assert vt["diffs"] == pytest.approx([51.0 - 33.0, 47.0 - 41.0, 52.0 - 27.0])
    ref = paired_difference([51.0, 47.0, 52.0], [33.0, 41.0, 27.0], margin=20.0)
    assert vt["mean_diff"] == pytest.approx(ref["mean_diff"]) and vt["t_p"] == pytest.approx(ref["t_p"])
    assert vt["p_at_most_margin"] == pytest.approx(ref["p_at_most_margin"])
    assert vt["sets ahead"] == "3/3" and vt["runs_ahead"] == 7 and vt["runs"] == 7
    vm = rows["vtloss − mmd"]
    assert vm["sets"] == ["s1", "s2"] and vm["diffs"] == pytest.approx([51.0 - 52.0, 47.0 - 45.5])
    assert vm["runs ahead"] == "3/5" and vm["cross_machine"] == 3  # s1's mmd ran on another host
    table = set_table_rows(set_summaries(sets), ["noda", "vtloss", "mmd"])
    assert [t["set"] for t in table[:3]] == ["s1", "s2", "s3"] and table[2]["mmd"] == "-"
    assert table[2]["vtloss"] == "52.0" and table[2]["seeds"] == "0,1,2"
    assert table[3]["noda"] == f"{np.mean([33.0, 41.0, 28.0]):.1f}"
    assert table[3]["mmd"] == f"{np.mean([52.0, 45.5]):.1f} (2 sets)"
    with pytest.raises(ValueError, match="no object set has runs of both mmd and oracle"):
        set_paired_rows(sets, [("mmd", "oracle")])


def test_object_sets_refuse_other_protocols_and_unknown_sets(tmp_path):
    a = _set(tmp_path, "a.json", "s1", _runs("noda", [0], [40.0]))
    b = _set(tmp_path, "b.json", "s2", _runs("noda", [0], [41.0]))
    assert len(load_object_sets([a, b])[1]) == 2
    with pytest.raises(ValueError, match="--merge-sets: the files hold one dataset"):
        load_object_sets([a, _set(tmp_path, "a2.json", "s1", _runs("vtloss", [0], [50.0]))])
    old = _set(tmp_path, "old.json", "s3", _runs("noda", [0], [41.0]), data_fingerprint=None)
    with pytest.raises(ValueError, match="--merge-sets: .*old.json has no data_fingerprint"):
        load_object_sets([a, old])
    with pytest.raises(ValueError, match="--merge-sets: .*ep.json has max_epochs=60"):
        load_object_sets([a, _set(tmp_path, "ep.json", "s2", _runs("noda", [0], [41.0]), max_epochs=60)])
    batch = _result(tmp_path, "bs.json", _runs("noda", [0], [41.0]), data_fingerprint={"data_dir": "s2"},
                    data={"data_dir": "runs/xavtnet/s2", "batch_size": 64})
    with pytest.raises(ValueError, match="--merge-sets: .*bs.json has data="):
        load_object_sets([a, batch])
    s1 = _set(tmp_path, "v1.json", "s1", _runs("noda", [0], [40.0]), variant_settings={"noda": {"da": 0}})
    s2 = _set(tmp_path, "v2.json", "s2", _runs("noda", [0], [40.0]), variant_settings={"noda": {"da": 1}})
    with pytest.raises(ValueError, match="--merge-sets: .*trains noda with"):
        load_object_sets([s1, s2])
    clash = _set(tmp_path, "cl.json", "s1", _runs("noda", [0], [43.0]))
    with pytest.raises(ValueError, match="--merge-sets: .*both hold noda seed 0"):
        load_object_sets([a, b, clash])
    # one folder regenerated with another draw: the fingerprints tell the two sets apart
    r1 = _set(tmp_path, "r1.json", "aaaa1111bbbb", _runs("noda", [0], [40.0]), data_dir="runs/obj")
    r2 = _set(tmp_path, "r2.json", "cccc2222dddd", _runs("noda", [0], [42.0]), data_dir="runs/obj")
    assert [s["label"] for s in load_object_sets([r1, r2])[1]] == ["obj (aaaa1111)", "obj (cccc2222)"]


def test_bench_merge_sets_writes_the_set_table_pairs_and_figure(tmp_path, capsys):
    from vtlearn.cli import main

    files = [_set(tmp_path, f"s{i}.json", f"s{i}", _runs("noda", [0, 1], [30.0 + i, 32.0])
                  + _runs("vtloss", [0, 1], [45.0 + 2 * i, 50.0]) + _runs("mmd", [0, 1], [47.0, 49.0 + i]))
             for i in range(4)]
    out = tmp_path / "sets.json"
    assert main(["bench", "crossmodal", "--merge-sets", *files, "--pairs", "vtloss-mmd", "--margin", "20",
                 "--json", str(out)]) == 0
    res = json.loads(out.read_text())
    assert res["by"] == "object set" and [s["label"] for s in res["sets"]] == ["s0", "s1", "s2", "s3"]
    assert res["sets"][2]["means"] == {"noda": 32.0, "vtloss": 49.5, "mmd": 49.0}
    assert res["sets"][2]["seeds"]["vtloss"] == [0, 1] and res["sets"][2]["files"] == [files[2]]
    pairs = {r["comparison"]: r for r in res["paired"]}
    assert set(pairs) == {"vtloss − noda", "mmd − noda", "vtloss − mmd"}
    assert pairs["vtloss − noda"]["diffs"] == pytest.approx([16.5, 17.0, 17.5, 18.0])
    assert "p(≤ 20)" in pairs["vtloss − noda"] and Path(res["figures"]["paired"]).exists()
    holm = holm_adjust([pairs[c]["t_p"] for c in pairs])
    assert [pairs[c]["t_p_holm"] for c in pairs] == pytest.approx(holm)
    text = capsys.readouterr().out
    assert "per object set" in text and "sets ahead" in text and "| s3 " in text and "p (Holm)" in text
    # refused by name: an input as the output, --merge beside --merge-sets, a baseline no set has
    assert main(["bench", "crossmodal", "--merge-sets", *files, "--json", files[0]]) == 2
    assert "--json:" in capsys.readouterr().err
    assert main(["bench", "crossmodal", "--merge-sets", *files, "--merge", files[0], "--json", str(out)]) == 2
    assert "give either --merge" in capsys.readouterr().err
    assert main(["bench", "crossmodal", "--merge-sets", *files, "--baseline", "coral",
                 "--json", str(out)]) == 2
    assert "--baseline: 'coral' is not one of the rows" in capsys.readouterr().err


def test_versus_sets_pair_the_same_sets_read_twice(tmp_path):
    """--versus-sets: the i-th set of one reading against the i-th of the other; a row's reading per set is
    its mean there, a margin's the mean difference over the seeds both rows have there; the statistics are
    paired_difference of those readings; a row or margin one set lacks is read over the others."""
    opaque = [_set(tmp_path, "o1.json", "o1", _runs("noda", [0, 1], [30.0, 34.0])
                   + _runs("vtloss", [0, 1], [55.0, 53.0])),
              _set(tmp_path, "o2.json", "o2", _runs("noda", [0, 1], [40.0, 40.0])
                   + _runs("vtloss", [0], [60.0])),
              _set(tmp_path, "o3.json", "o3", _runs("noda", [0, 1], [20.0, 22.0]), machine=HOST_B)]
    glass = [_set(tmp_path, "g1.json", "g1", _runs("noda", [0, 1], [33.0, 35.0])
                  + _runs("vtloss", [0, 1], [50.0, 52.0])),
             _set(tmp_path, "g2.json", "g2", _runs("noda", [0, 1, 2], [41.0, 43.0, 60.0])
                  + _runs("vtloss", [0, 1, 2], [55.0, 57.0, 70.0])),
             _set(tmp_path, "g3.json", "g3", _runs("noda", [0], [25.0]))]
    _, sets = load_object_sets(opaque)
    _, versus = load_object_sets(glass)
    rows = {r["comparison"]: r for r in versus_set_rows(sets, versus, [("noda", None), ("vtloss", None),
                                                                       ("vtloss", "noda")])}
    noda = rows["noda"]
    assert noda["sets"] == ["o1 : g1", "o2 : g2", "o3 : g3"]
    assert noda["diffs"] == pytest.approx([32.0 - 34.0, 40.0 - 48.0, 21.0 - 25.0])
    assert noda["cross_machine"] == 1 and noda["sets ahead"] == "0/3"  # o3 ran on another host than g3
    # o2 has vtloss on seed 0 only: its margin is read there; o3 has no vtloss and is left out
    margin = rows["vtloss − noda"]
    assert margin["sets"] == ["o1 : g1", "o2 : g2"]
    glass_margins = [17.0, np.mean([55.0 - 41.0, 57.0 - 43.0, 70.0 - 60.0])]
    assert margin["diffs"] == pytest.approx([22.0 - glass_margins[0], 20.0 - glass_margins[1]])
    ref = paired_difference([22.0, 20.0], glass_margins)
    assert margin["mean_diff"] == pytest.approx(ref["mean_diff"])
    assert margin["t_p"] == pytest.approx(ref["t_p"])
    assert rows["vtloss"]["diffs"] == pytest.approx([54.0 - 51.0, 60.0 - np.mean([55.0, 57.0, 70.0])])
    holm = holm_adjust([rows[c]["t_p"] for c in rows])
    assert [rows[c]["t_p_holm"] for c in rows] == pytest.approx(holm)
    with pytest.raises(ValueError, match="--versus-sets: 2 object sets against the 3 of --merge-sets"):
        versus_set_rows(sets, versus[:2], [("noda", None)])
    with pytest.raises(ValueError, match="--versus-sets: no pair of object sets has mmd − noda"):
        versus_set_rows(sets, versus, [("mmd", "noda")])


def test_versus_sets_check_the_draws_they_pair_by_their_gen_data_settings(tmp_path):
    """Where the bench results recorded their datasets' gen-data settings, a pair of sets drawn with other
    seeds is refused (the files were named in another order), and the settings the two readings differ in
    are listed, without the seed; results without the record are paired as named."""
    def gen(seed, transparency):
        return {"data_dir": {"seed": seed, "transparency": transparency, "views": 60}}

    opaque = [_set(tmp_path, f"o{k}.json", f"o{k}", _runs("noda", [0], [30.0]),
                   data_generation=gen(k, False)) for k in (11, 12)]
    glass = [_set(tmp_path, f"g{k}.json", f"g{k}", _runs("noda", [0], [31.0]),
                  data_generation=gen(k, True)) for k in (11, 12)]
    (meta, sets), (vmeta, versus) = load_object_sets(opaque), load_object_sets(glass)
    assert sets[0]["generation"] == {"seed": 11, "transparency": False, "views": 60}
    # --merge keeps the record (from the first file that has one), so a merged result can be paired too
    unrecorded_run = _set(tmp_path, "o11b.json", "o11", _runs("vtloss", [0], [50.0]))
    assert load_crossmodal_results([unrecorded_run, opaque[0]])[0]["data_generation"] == gen(11, False)
    assert load_crossmodal_results([unrecorded_run])[0]["data_generation"] is None
    check_versus_protocol(meta, vmeta, [opaque[0], glass[0]], sets, versus)
    assert generation_differences(sets, versus) == {"transparency": ([False], [True])}
    (vmeta2, swapped) = load_object_sets(glass[::-1])
    with pytest.raises(ValueError, match=r"--versus-sets: pairs o11 \(gen-data --seed 11\) with g12 "
                                         r"\(--seed 12\)"):
        check_versus_protocol(meta, vmeta2, [opaque[0], glass[1]], sets, swapped)
    old = [_set(tmp_path, f"n{k}.json", f"n{k}", _runs("noda", [0], [31.0])) for k in (12, 11)]
    (ometa, unrecorded) = load_object_sets(old)
    check_versus_protocol(meta, ometa, [opaque[0], old[0]], sets, unrecorded)
    assert generation_differences(sets, unrecorded) == {} and unrecorded[0]["generation"] is None


def test_bench_versus_sets_writes_how_the_rows_moved(tmp_path, capsys):
    """`--merge-sets A --versus-sets B`: A's table as without it, then B's per-set table and the rows and
    margins paired set by set, in the JSON's ``versus`` with a figure; refused by name before any table: B
    without --merge-sets, B of another protocol or with another number of sets, B holding none of A's rows,
    one of B's files as --json."""
    from vtlearn.cli import main

    a = [_set(tmp_path, f"a{i}.json", f"a{i}", _runs("noda", [0, 1], [30.0 + i, 32.0])
              + _runs("vtloss", [0, 1], [50.0 + i, 52.0]),
              data_generation={"data_dir": {"seed": i, "transparency": False}}) for i in range(3)]
    b = [_set(tmp_path, f"b{i}.json", f"b{i}", _runs("noda", [0, 1], [31.0, 33.0 + i])
              + _runs("vtloss", [0, 1], [48.0, 50.0]) + _runs("mmd", [0, 1], [47.0, 49.0]),
              data_generation={"data_dir": {"seed": i, "transparency": True}}) for i in range(3)]
    out = tmp_path / "vs.json"
    assert main(["bench", "crossmodal", "--merge-sets", *a, "--versus-sets", *b, "--json", str(out)]) == 0
    res = json.loads(out.read_text())
    assert [p["comparison"] for p in res["paired"]] == ["vtloss − noda"]  # A's own table is unchanged
    vs = res["versus"]
    assert vs["merged_from"] == b and vs["pairing"] == [["a0", "b0"], ["a1", "b1"], ["a2", "b2"]]
    assert [s["label"] for s in vs["sets"]] == ["b0", "b1", "b2"] and "mmd" in vs["sets"][0]["means"]
    rows = {r["comparison"]: r for r in vs["paired"]}
    assert list(rows) == ["noda", "vtloss", "vtloss − noda"]  # mmd is B's only
    assert rows["vtloss − noda"]["diffs"] == pytest.approx([20.0 - 17.0, 20.0 - 16.5, 20.0 - 16.0])
    assert rows["noda"]["diffs"] == pytest.approx([31.0 - 32.0, 31.5 - 32.5, 32.0 - 33.0])
    assert Path(res["figures"]["versus"]).exists() and Path(res["figures"]["paired"]).exists()
    assert vs["generation_differences"] == {"transparency": {"sets": [False], "versus": [True]}}
    text = capsys.readouterr().out
    assert "--versus-sets: V→T accuracy" in text and "a2 : b2" in text and "| vtloss − noda |" in text
    assert "generated with other transparency (False here, against True)" in text
    ep = [_set(tmp_path, f"e{i}.json", f"e{i}", _runs("noda", [0], [30.0]), max_epochs=60) for i in range(3)]
    other = [_set(tmp_path, f"m{i}.json", f"m{i}", _runs("mmd", [0], [30.0])) for i in range(3)]
    for argv, msg in [(["--versus-sets", *b], "--versus-sets: only with --merge-sets"),
                      (["--merge-sets", *a, "--versus-sets", *b[:2]], "2 object sets against the 3"),
                      (["--merge-sets", *a, "--versus-sets", *ep], "max_epochs=60"),
                      (["--merge-sets", *a, "--versus-sets", *other], "hold none of the rows of"),
                      (["--merge-sets", *a, "--versus-sets", *b, "--json", b[0]], "--json:")]:
        given = argv if "--json" in argv else [*argv, "--json", str(out)]
        assert main(["bench", "crossmodal", *given, "--no-figures"]) == 2
        text = capsys.readouterr()
        assert msg in text.err and "V→T accuracy" not in text.out  # refused before any table


def test_bench_merges_keep_only_the_rows_asked(tmp_path, capsys):
    """--rows keeps the rows named in the tables, the comparisons and the JSON (their settings too); a set
    left without them is dropped and said to be; a row no file holds, fewer than two sets left, or --rows on
    a training run are refused by name."""
    from vtlearn.cli import main

    settings = {"noda": {"da": 0}, "vtloss": {"da": 1}, "mmd": {"da": 2}}
    one = _result(tmp_path, "one.json", _runs("noda", [0, 1], [40.0, 42.0])
                  + _runs("vtloss", [0, 1], [50.0, 49.0]) + _runs("mmd", [0, 1], [51.0, 52.0]),
                  variant_settings=settings)
    out = tmp_path / "m.json"
    assert main(["bench", "crossmodal", "--merge", one, "--rows", "noda,vtloss", "--no-figures",
                 "--json", str(out)]) == 0
    res = json.loads(out.read_text())
    assert [r["variant"] for r in res["rows"]] == ["noda", "vtloss"]
    assert {r["variant"] for r in res["runs"]} == {"noda", "vtloss"}
    assert [p["comparison"] for p in res["paired"]] == ["vtloss − noda"]
    assert set(res["variant_settings"]) == {"noda", "vtloss"}
    files = [_set(tmp_path, f"s{i}.json", f"s{i}", _runs("noda", [0], [30.0 + i])
                  + _runs("vtloss", [0], [45.0])) for i in range(2)]
    files.append(_set(tmp_path, "s2.json", "s2", _runs("mmd", [0], [47.0])))
    capsys.readouterr()
    assert main(["bench", "crossmodal", "--merge-sets", *files, "--rows", "vtloss,noda", "--no-figures",
                 "--json", str(out)]) == 0
    res = json.loads(out.read_text())
    assert [s["label"] for s in res["sets"]] == ["s0", "s1"]
    assert [p["comparison"] for p in res["paired"]] == ["vtloss − noda"]
    assert "s2 hold none of the rows kept" in capsys.readouterr().out
    for argv, msg in [(["--merge", one, "--rows", "noda,oracle"], "--rows: ['oracle'] are in none"),
                      (["--merge-sets", *files, "--rows", "mmd"], "--rows: only 1 object set"),
                      (["--merge", one, "--rows", " , "], "--rows: need a comma list"),
                      (["--variants", "noda", "--rows", "noda"], "--rows: only with --merge")]:
        assert main(["bench", "crossmodal", *argv, "--no-figures", "--json", str(out)]) == 2
        assert msg in capsys.readouterr().err


def test_per_class_recall_and_prediction_share_pool_the_seeds_confusions():
    """Each row's recall per class and its share of the predictions, from its confusion matrices summed over
    seeds (true x predicted), worked by hand; a class without test clouds has no recall; rows without a
    matrix are left out; matrices of two sizes are refused."""
    runs = [{"variant": "noda", "seed": 0, "tactile_acc": 0, "confusion": [[2, 0, 0], [3, 1, 0], [0, 0, 0]]},
            {"variant": "noda", "seed": 1, "tactile_acc": 0, "confusion": [[1, 1, 0], [2, 2, 0], [0, 0, 0]]},
            {"variant": "vtloss", "seed": 0, "tactile_acc": 0,
             "confusion": [[3, 0, 0], [0, 4, 0], [0, 0, 0]]},
            {"variant": "gfk_1nn", "seed": 0, "tactile_acc": 0}]
    scores = per_class_scores(runs, ["noda", "vtloss", "gfk_1nn"])
    assert list(scores) == ["noda", "vtloss"]
    # noda summed: [[3, 1, 0], [5, 3, 0], [0, 0, 0]]: recall 3/4, 3/8; predictions 8 and 4 of 12
    assert scores["noda"]["recall"][:2] == pytest.approx([75.0, 37.5]) and scores["noda"]["recall"][2] is None
    assert scores["noda"]["predicted_share"] == pytest.approx([200 / 3, 100 / 3, 0.0])
    assert (scores["noda"]["clouds"], scores["noda"]["seeds"]) == (12, 2)
    rows = per_class_table_rows(scores, ["can", "mug", "box"])
    assert rows[0] == {"class": "can", "noda": "75 (67)", "vtloss": "100 (43)"}
    assert rows[2]["noda"] == "- (0)"
    assert [r["class"] for r in per_class_table_rows(scores, None)] == ["0", "1", "2"]
    with pytest.raises(ValueError, match="runs: the confusion matrices of noda"):
        per_class_scores([runs[0], {**runs[1], "confusion": [[1, 0], [0, 1]]}], ["noda"])


def test_merge_carries_the_class_names_and_prints_the_per_class_table(tmp_path, capsys):
    from vtlearn.cli import main

    conf = [[4, 0], [3, 1]]
    f1 = _result(tmp_path, "a.json", _runs("noda", [0], [62.5], confusion=conf), class_names=["can", "mug"])
    f2 = _result(tmp_path, "b.json", _runs("noda", [1], [62.5], confusion=conf))  # merged before the names
    meta, _ = load_crossmodal_results([f1, f2])
    assert meta["class_names"] == ["can", "mug"]
    out = tmp_path / "m.json"
    assert main(["bench", "crossmodal", "--merge", f1, f2, "--no-figures", "--json", str(out)]) == 0
    res = json.loads(out.read_text())
    assert res["class_names"] == ["can", "mug"]
    assert res["per_class"]["noda"]["recall"] == pytest.approx([100.0, 25.0])
    assert "| can   | 100 (88) |" in capsys.readouterr().out

