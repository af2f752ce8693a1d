"""Seed-paired comparisons of ``vtlearn bench crossmodal`` rows, within one run or pooled over several.

A row's margin over another (VTLoss over no-DA, thesis Table 7.2/7.4) is read best seed by seed: every seed
draws the same data order and initial weights for every row, so the paired differences are far less spread
than the rows themselves. ``bench crossmodal`` prints them against ``--baseline`` after its table, and
``bench crossmodal --merge A.json B.json ...`` pools the runs of earlier results of the same protocol (more
seeds, or rows run apart) before it does, instead of a script of one's own.

The thesis's own protocol (7.3.2: twelve objects, one per class) hangs on which twelve objects are drawn:
here one draw gives anything from +4 to +25 points for VTLoss over no-DA (docs/xavtnet_results.md, stop 59),
far more than the seeds of one draw. ``bench crossmodal --merge-sets`` reads the results of one protocol on
several datasets (object sets), pools each set's files as ``--merge`` does, and pairs the rows by object set:
each set's mean over its seeds is one pair (:func:`load_object_sets`, :func:`set_paired_rows`).

Pooling is refused when the files differ in data (``data_fingerprint`` or the datamodule settings), in
training length or in the model, or repeat a (row, seed) with other numbers. A pair whose two runs ran on
different machines is counted (``cross_machine``): a training repeats bit for bit on one machine, not on
another CPU (docs/xavtnet_results.md), so such a pair keeps its seed but loses the shared noise that pairing
removes.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from vtlearn.bench_utils import check_same_protocol, holm_adjust, paired_difference, read_results

__all__ = ["load_crossmodal_results", "score_field", "parse_pairs", "default_pairs", "paired_rows",
           "paired_table_columns", "paired_figure", "load_object_sets", "set_paired_rows",
           "set_summaries", "set_table_rows", "check_versus_protocol", "generation_differences",
           "versus_set_rows", "with_holm"]

# The keys two results must share for their runs to be pooled.
_MERGE_KEYS = ("data", "max_epochs", "model_base")


def score_field(spec: str) -> tuple[str, str]:
    """A comparison side ``variant[.score]`` as ``(variant, run field)``: ``vtloss`` reads the network's
    ``tactile_acc``, ``vtloss_g12_mt_vote.teacher`` its teacher's ``tactile_acc_teacher``, ``noda.adabn``
    ``tactile_acc_adabn`` (any ``tactile_acc_<score>`` that the runs hold)."""
    variant, _, score = spec.strip().partition(".")
    if not variant or (score == "" and spec.strip().endswith(".")):
        raise ValueError(f"--pairs: {spec!r} is not a row name, optionally with .<score> "
                         "(e.g. vtloss.teacher)")
    return variant, "tactile_acc" + (f"_{score}" if score else "")


def parse_pairs(text: str | None) -> list[tuple[str, str]]:
    """``--pairs "a-b,c.teacher-d"`` as ``[("a", "b"), ("c.teacher", "d")]``: each item is the row that
    should be ahead, a minus sign, and the row it is compared with (row names hold no minus sign)."""
    out = []
    for item in (x.strip() for x in (text or "").split(",")):
        if not item:
            continue
        a, sep, b = item.partition("-")
        if not sep or not a.strip() or not b.strip() or "-" in b:
            raise ValueError(f"--pairs: {item!r} is not of the form A-B (e.g. vtloss-mmd, "
                             "vtloss_g12_mt_vote.teacher-noda)")
        score_field(a)
        score_field(b)
        out.append((a.strip(), b.strip()))
    return out


def default_pairs(variants: list[str], runs: list[dict], baseline: str) -> list[tuple[str, str]]:
    """Every row against ``baseline`` (nothing when no run is of it), and a teacher row's teacher too."""
    if not any(r["variant"] == baseline for r in runs):
        return []
    out = []
    for v in variants:
        if v != baseline:
            out.append((v, baseline))
        if any(r["variant"] == v and "tactile_acc_teacher" in r for r in runs):
            out.append((f"{v}.teacher", baseline))
    return out


def _same_machine(m1: dict | None, m2: dict | None) -> bool:
    """Whether two runs' ``machine`` records name the same host (platform string, with the kernel build, and
    the CPU model and torch's vector capability where both have them: two hosts of one kernel build and CPU
    name can still run AVX-512 kernels on one and AVX2 ones on the other); an unrecorded machine is taken as
    the same."""
    if not m1 or not m2:
        return True
    if m1.get("platform") != m2.get("platform"):
        return False
    return not any(m1.get(k) and m2.get(k) and m1[k] != m2[k] for k in ("cpu_model", "cpu_capability"))


def _machine_of(doc: dict) -> dict | None:
    m = doc.get("machine")
    if not isinstance(m, dict):
        return None
    return {k: m.get(k) for k in ("platform", "cpu_model", "cpu_capability") if m.get(k) is not None}


def load_crossmodal_results(paths: list[str], flag: str = "--merge") -> tuple[dict, list[dict]]:
    """The runs of several ``bench crossmodal`` JSONs of one protocol, pooled.

    Every run keeps its numbers and gains ``machine`` (its file's platform and CPU, unless it has one
    already) and ``file``. A (row, seed) found in two files is kept once if both give the same tactile and
    visual accuracy, else refused. Raises ``ValueError`` naming the file when one is missing, is not a
    ``bench crossmodal`` result, was run on other data (``data_fingerprint``, or other datamodule settings),
    for another number of epochs or with another model, gives a row other settings (``variant_settings``),
    or repeats a (row, seed) with other numbers. Results written before the fingerprint or the settings
    were recorded are compared on the rest. ``flag`` is the command-line flag the messages name.

    Returns:
        meta (the shared ``data``, ``max_epochs``, ``model_base``, ``data_fingerprint``, the first
        ``data_generation`` recorded (None if none is), the ``variant_settings`` known, ``config`` and
        ``merged_from`` lists), runs (one dict per (row, seed))
    """
    return _pool_results(paths, read_results(paths, "crossmodal", "runs", flag), flag)


def _merge_settings(named: list[tuple[str, dict | None]], flag: str) -> dict[str, dict]:
    """The ``variant_settings`` of several results as one dict; a ``ValueError`` naming ``flag`` and both
    files when two give a row different settings. ``named``: (file, its variant_settings) pairs."""
    settings: dict[str, tuple[str, dict]] = {}
    for path, given in named:
        for variant, s in (given or {}).items():
            if variant in settings and settings[variant][1] != s:
                raise ValueError(f"{flag}: {path} trains {variant} with {s}, {settings[variant][0]} with "
                                 f"{settings[variant][1]}")
            settings.setdefault(variant, (path, s))
    return {v: s for v, (_, s) in settings.items()}


def _pool_results(paths: list[str], docs: list[dict], flag: str) -> tuple[dict, list[dict]]:
    """:func:`load_crossmodal_results` on results already read (``docs``, one per path)."""
    fingerprint = check_same_protocol(paths, docs, _MERGE_KEYS, flag)
    named = [(path, doc.get("variant_settings")) for path, doc in zip(paths, docs, strict=True)]
    settings = _merge_settings(named, flag)
    runs: list[dict] = []
    where: dict[tuple[str, int], int] = {}
    for path, doc in zip(paths, docs, strict=True):
        machine = _machine_of(doc)
        for r in doc["runs"]:
            if not isinstance(r, dict) or not {"variant", "seed", "tactile_acc"} <= r.keys():
                raise ValueError(f"{flag}: {path} holds a run without variant, seed and tactile_acc")
            key = (r["variant"], r["seed"])
            if key in where:
                old = runs[where[key]]
                if (old["tactile_acc"], old.get("visual_acc")) != (r["tactile_acc"], r.get("visual_acc")):
                    raise ValueError(f"{flag}: {path} and {old['file']} both hold {key[0]} seed {key[1]}, "
                                     f"with tactile accuracy {r['tactile_acc']:.2f} against "
                                     f"{old['tactile_acc']:.2f}; leave one of them out")
                continue
            where[key] = len(runs)
            runs.append({**r, "machine": r.get("machine") or machine, "file": str(path)})
    meta = {key: docs[0].get(key) for key in _MERGE_KEYS}
    names = {json.dumps(doc.get("class_names")) for doc in docs if doc.get("class_names")}
    meta["class_names"] = json.loads(names.pop()) if len(names) == 1 else None  # None where files disagree
    # how the data were drawn, from the first file that recorded it (the fingerprint check makes them one)
    meta["data_generation"] = next((d["data_generation"] for d in docs if d.get("data_generation")), None)
    meta.update({"data_fingerprint": fingerprint, "variant_settings": settings,
                 "config": [doc.get("config") for doc in docs], "merged_from": [str(p) for p in paths]})
    return meta, runs


def _by_seed(runs: list[dict], spec: str) -> tuple[str, dict[int, dict]]:
    """The run field that the comparison side ``spec`` reads (:func:`score_field`) and the runs of its row
    that hold that field, keyed by seed."""
    variant, field = score_field(spec)
    return field, {r["seed"]: r for r in runs if r["variant"] == variant and r.get(field) is not None}


def paired_rows(runs: list[dict], pairs: list[tuple[str, str]], margin: float | None = None) -> list[dict]:
    """One row per ``(a, b)`` of ``pairs`` (sides as :func:`score_field` reads them): the seeds both have,
    :func:`~vtlearn.bench_utils.paired_difference` of ``a`` over ``b`` on them, the pairs whose runs ran on
    different machines (``cross_machine``), the t-test p adjusted over the pairs (:func:`with_holm`), and
    table text. A side with no run, or two sides without a seed
    in common, is refused naming it.

    Shapes:
        runs: one dict per (variant, seed) -> one dict per pair
    """
    out = []
    for a, b in pairs:
        sides = []
        for spec in (a, b):
            field, got = _by_seed(runs, spec)
            if not got:
                have = sorted({r["variant"] for r in runs})
                raise ValueError(f"--pairs: no run of {score_field(spec)[0]} with {field} (rows: {have})")
            sides.append((field, got))
        (fa, ra), (fb, rb) = sides
        seeds = sorted(set(ra) & set(rb))
        if not seeds:
            raise ValueError(f"--pairs: {a} (seeds {sorted(ra)}) and {b} (seeds {sorted(rb)}) share no seed")
        x = np.array([ra[s][fa] for s in seeds], dtype=np.float64)
        y = np.array([rb[s][fb] for s in seeds], dtype=np.float64)
        cross = sum(not _same_machine(ra[s].get("machine"), rb[s].get("machine")) for s in seeds)
        row = {"comparison": f"{a} − {b}", "a": a, "b": b, "seeds": seeds, **_pair_row(x, y, margin),
               "cross_machine": cross}
        row["seeds ahead"] = f"{row['ahead']}/{len(seeds)}"
        out.append(row)
    return with_holm(out)


def check_versus_protocol(meta: dict, versus_meta: dict, paths: list[str], sets: list[dict],
                          versus: list[dict], flag: str = "--versus-sets") -> None:
    """A ``ValueError`` naming ``flag`` unless two readings of :func:`load_object_sets` (``meta``, ``sets``
    and ``versus_meta``, ``versus``; ``paths``: the first file of each) can be paired set by set: the same
    protocol bar the data (the datamodule settings but the folders, the training length, the model, and the
    settings of every row both train), as many sets, and a row in common."""
    docs = [{key: m.get(key) for key in _MERGE_KEYS} for m in (meta, versus_meta)]
    check_same_protocol(paths, docs, _MERGE_KEYS, flag)
    _merge_settings(list(zip(paths, (meta.get("variant_settings"), versus_meta.get("variant_settings")),
                             strict=True)), flag)
    _check_set_count(sets, versus, flag)
    for s, v in zip(sets, versus, strict=True):
        seeds = [g.get("seed") if isinstance(g, dict) else None
                 for g in (s.get("generation"), v.get("generation"))]
        if None not in seeds and seeds[0] != seeds[1]:
            raise ValueError(f"{flag}: pairs {s['label']} (gen-data --seed {seeds[0]}) with {v['label']} "
                             f"(--seed {seeds[1]}), which are other object draws; the sets are paired in "
                             "the order first named, so name the files of each in the same order")
    rows, held = ({r["variant"] for s in group for r in s["runs"]} for group in (sets, versus))
    if not rows & held:
        raise ValueError(f"{flag}: its sets hold none of the rows of --merge-sets ({sorted(rows)}); they "
                         f"hold {sorted(held)}")


def generation_differences(sets: list[dict], versus: list[dict]) -> dict[str, tuple[list, list]]:
    """The ``gen-data`` settings in which the datasets of two readings differ (``--opaque`` is
    ``transparency``), over the pairs of sets whose bench results recorded them (``data_generation``):
    ``{setting: (its values in sets, its values in versus)}``, each list without repeats; the seed, which
    the pairing keeps, is left out.

    Shapes:
        sets (S,), versus (S,): one dict per object set -> {setting: ([values], [values])}
    """
    out: dict[str, tuple[list, list]] = {}
    for s, v in zip(sets, versus, strict=True):
        a, b = s.get("generation"), v.get("generation")
        if not (isinstance(a, dict) and isinstance(b, dict)):
            continue
        for key in sorted((set(a) | set(b)) - {"seed"}):
            if a.get(key) != b.get(key):
                here, there = out.setdefault(key, ([], []))
                for values, value in ((here, a.get(key)), (there, b.get(key))):
                    if value not in values:
                        values.append(value)
    return out


def _check_set_count(sets: list[dict], versus: list[dict], flag: str) -> None:
    if len(sets) != len(versus):
        raise ValueError(f"{flag}: {len(versus)} object sets against the {len(sets)} of --merge-sets; the "
                         "sets are paired in the order first named, so both need as many")


def _set_value(runs: list[dict], a: str, b: str | None) -> tuple[float, list] | None:
    """One object set's reading of a row (``b`` None: ``a``'s mean over its seeds there) or of a margin
    (``a − b``: the mean difference over the seeds both have there), with the machines of the runs read;
    None when the set lacks it."""
    fa, ra = _by_seed(runs, a)
    fb, rb = _by_seed(runs, b) if b is not None else (fa, {})
    seeds = sorted(ra) if b is None else sorted(set(ra) & set(rb))
    if not seeds:
        return None
    value = float(np.mean([ra[k][fa] - (rb[k][fb] if k in rb else 0.0) for k in seeds]))
    return value, [r.get("machine") for k in seeds for r in (ra[k], rb.get(k)) if r is not None]


def versus_set_rows(sets: list[dict], versus: list[dict], comparisons: list[tuple[str, str | None]],
                    flag: str = "--versus-sets") -> list[dict]:
    """How rows and margins move between two readings of the same object sets (the same draws rendered
    otherwise, or generated with other touches), paired set by set: the i-th set of ``sets`` with
    the i-th of ``versus``, both as :func:`load_object_sets` gives them (in the order first named).

    For each ``(a, None)`` of ``comparisons`` the reading per set is ``a``'s mean over its seeds there, for
    each ``(a, b)`` the margin of ``a`` over ``b`` (their mean difference over the seeds both have there).
    Each row is :func:`~vtlearn.bench_utils.paired_difference` of the ``sets`` readings over the ``versus``
    ones over the pairs of sets that both have it, the sets paired (``"label : label"``), the pairs of sets
    whose runs ran on more than one machine (``cross_machine``), the t-test p adjusted over the rows
    (:func:`with_holm`) and table text. A ``ValueError`` names ``flag`` when the two hold different numbers
    of sets, and a comparison that no pair of sets has on both sides.

    Shapes:
        sets (S,), versus (S,): one dict per object set, each with its runs -> one dict per comparison
    """
    _check_set_count(sets, versus, flag)
    out = []
    for a, b in comparisons:
        name = a if b is None else f"{a} − {b}"
        labels, x, y, cross = [], [], [], 0
        for s, v in zip(sets, versus, strict=True):
            got, ref = _set_value(s["runs"], a, b), _set_value(v["runs"], a, b)
            if got is None or ref is None:
                continue
            labels.append(f"{s['label']} : {v['label']}")
            x.append(got[0])
            y.append(ref[0])
            machines = got[1] + ref[1]
            cross += not all(_same_machine(machines[0], m) for m in machines[1:])
        if not labels:
            raise ValueError(f"{flag}: no pair of object sets has {name} on both sides")
        row = {"comparison": name, "a": a, "b": b, "sets": labels,
               **_pair_row(np.array(x), np.array(y), None), "cross_machine": cross}
        row["sets ahead"] = f"{row['ahead']}/{len(labels)}"
        out.append(row)
    return with_holm(out)


def _pair_row(x: np.ndarray, y: np.ndarray, margin: float | None) -> dict:
    """:func:`~vtlearn.bench_utils.paired_difference` of ``x`` over ``y``, the two means, the differences,
    and the table text of a comparison (``p(≤ margin)`` with a ``margin``).

    Shapes:
        x (N,), y (N,) -> dict
    """
    stats = paired_difference(x, y, margin)
    ci = stats["ci95"]
    row = {**stats, "a_mean": float(x.mean()), "b_mean": float(y.mean()), "diffs": (x - y).tolist(),
           "means": f"{x.mean():.2f} vs {y.mean():.2f}",
           "difference": f"{stats['mean_diff']:+.2f} ± {stats['sd']:.2f}",
           "95% CI": f"{ci[0]:+.1f} to {ci[1]:+.1f}" if ci else None,
           "p (t)": _p_text(stats["t_p"]), "p (Wilcoxon)": _p_text(stats["wilcoxon_p"])}
    if margin is not None:
        row[f"p(≤ {margin:g})"] = _p_text(stats["p_at_most_margin"])
    return row


def load_object_sets(paths: list[str], flag: str = "--merge-sets") -> tuple[dict, list[dict]]:
    """The results of one protocol run on several datasets (object sets), grouped by dataset.

    The files are grouped by their ``data_fingerprint``; each group is pooled by
    :func:`load_crossmodal_results` (the same checks, naming ``flag``). Across the groups everything but the
    data folders must agree: the datamodule settings other than ``data_dir`` (and ``target_data_dir``), the
    training length, the model, and the settings of every row that two sets both train. Raises
    ``ValueError`` naming ``flag`` and the file for a file without a fingerprint (its set cannot be told
    from another's), for fewer than two datasets (pooling one is ``--merge``'s work) and for a file of
    another protocol.

    Returns:
        meta (``data`` without the folders, ``max_epochs``, ``model_base``, ``variant_settings``,
        ``merged_from``), sets (one dict per dataset in the order first named: ``label``, the folder's name,
        with the fingerprint's first characters where two sets share a name; ``data_dir``,
        ``data_fingerprint``, ``files``, ``generation``, the gen-data settings its results recorded
        (``data_generation``) or None; ``runs``)
    """
    docs = read_results(paths, "crossmodal", "runs", flag)
    groups: dict[str, list[int]] = {}
    for i, (path, doc) in enumerate(zip(paths, docs, strict=True)):
        fp = doc.get("data_fingerprint")
        if not fp:
            raise ValueError(f"{flag}: {path} has no data_fingerprint, so its object set cannot be told from "
                             "another's; rerun it with this version's bench")
        groups.setdefault(json.dumps(fp, sort_keys=True), []).append(i)
    if len(groups) < 2:
        raise ValueError(f"{flag}: the files hold one dataset; pairing by object set needs two or more "
                         "(--merge pools the seeds of one dataset)")
    # across the sets: the protocol bar the data folders (no fingerprint: the sets' differ by design)
    protocols = [{"data": {k: v for k, v in (doc.get("data") or {}).items()
                           if k not in ("data_dir", "target_data_dir")},
                  **{key: doc.get(key) for key in _MERGE_KEYS if key != "data"}} for doc in docs]
    check_same_protocol(paths, protocols, _MERGE_KEYS, flag)
    sets, named = [], []
    for group in groups.values():
        meta, runs = _pool_results([paths[i] for i in group], [docs[i] for i in group], flag)
        named.append((paths[group[0]], meta["variant_settings"]))
        data_dir = str((meta["data"] or {}).get("data_dir", ""))
        recorded = meta["data_generation"]
        generation = recorded.get("data_dir") if isinstance(recorded, dict) else None
        generation = generation if isinstance(generation, dict) else None  # a record of another shape: none
        sets.append({"label": Path(data_dir).name or data_dir, "data_dir": data_dir, "runs": runs,
                     "data_fingerprint": meta["data_fingerprint"], "files": meta["merged_from"],
                     "generation": generation})
    settings = _merge_settings(named, flag)  # a row trained alike in every set
    names = [s["label"] for s in sets]
    for s in sets:
        if names.count(s["label"]) > 1:  # one folder regenerated: the fingerprint tells the draws apart
            s["label"] += " (" + "/".join(str(v)[:8] for v in s["data_fingerprint"].values()) + ")"
    meta = {**protocols[0], "variant_settings": settings, "merged_from": [str(p) for p in paths]}
    return meta, sets


def set_paired_rows(sets: list[dict], pairs: list[tuple[str, str]], margin: float | None = None
                    ) -> list[dict]:
    """One row per ``(a, b)`` of ``pairs`` over the object sets of :func:`load_object_sets`: in each set that
    has both sides, the mean of ``a`` and of ``b`` over the seeds both have there is one pair;
    :func:`~vtlearn.bench_utils.paired_difference` of those set means, the sets and single runs ``a``
    leads, the runs whose two sides ran on different machines (``cross_machine``), the t-test p adjusted
    over the pairs (:func:`with_holm`), and table text. A pair
    that no set has both sides of is refused naming it.

    Shapes:
        sets: one dict per object set, each with its runs -> one dict per pair
    """
    out = []
    for a, b in pairs:
        labels, xa, xb, run_a, run_b, cross = [], [], [], [], [], 0
        for s in sets:
            (fa, ra), (fb, rb) = _by_seed(s["runs"], a), _by_seed(s["runs"], b)
            seeds = sorted(set(ra) & set(rb))
            if not seeds:
                continue
            labels.append(s["label"])
            run_a += [float(ra[k][fa]) for k in seeds]
            run_b += [float(rb[k][fb]) for k in seeds]
            xa.append(float(np.mean([ra[k][fa] for k in seeds])))
            xb.append(float(np.mean([rb[k][fb] for k in seeds])))
            cross += sum(not _same_machine(ra[k].get("machine"), rb[k].get("machine")) for k in seeds)
        if not labels:
            raise ValueError(f"--pairs: no object set has runs of both {a} and {b} on a common seed")
        runs_ahead = int(sum(p > q for p, q in zip(run_a, run_b, strict=True)))
        row = {"comparison": f"{a} − {b}", "a": a, "b": b, "sets": labels,
               **_pair_row(np.array(xa), np.array(xb), margin), "cross_machine": cross,
               "runs": len(run_a), "runs_ahead": runs_ahead, "runs ahead": f"{runs_ahead}/{len(run_a)}"}
        row["sets ahead"] = f"{row['ahead']}/{len(labels)}"
        out.append(row)
    return with_holm(out)


def _confusions(runs: list[dict], variant: str) -> list[np.ndarray]:
    """The tactile confusion matrices (true x predicted) of ``variant``'s runs that hold one, one per seed; a
    ValueError names ``runs`` when they are not square matrices of one size."""
    confs = [np.asarray(r["confusion"], dtype=float) for r in runs
             if r["variant"] == variant and r.get("confusion") is not None]
    if confs and (len({c.shape for c in confs}) != 1 or confs[0].ndim != 2
                  or confs[0].shape[0] != confs[0].shape[1]):
        raise ValueError(f"runs: the confusion matrices of {variant} are not square matrices of one size "
                         f"({sorted({c.shape for c in confs})})")
    return confs


def summed_confusion(runs: list[dict], variant: str) -> np.ndarray | None:
    """The tactile confusion matrices of ``variant``'s runs summed over its seeds (true x predicted), or None
    when none of its runs holds one (results written before the bench recorded them). A ValueError names
    ``runs`` when the matrices are not square matrices of one size.

    Shapes:
        runs: one dict per (row, seed), ``confusion`` (C, C) -> (C, C)
    """
    confs = _confusions(runs, variant)
    return np.sum(confs, axis=0) if confs else None


def per_class_scores(runs: list[dict], variants: list[str]) -> dict[str, dict]:
    """Each row's tactile recall per class and share of the predictions per class (%), from its confusion
    matrices summed over its seeds: the diagonal of thesis Table 7.3 (the tactile confusion matrix, rows
    normalised) for every row, and the column sums that show a class the row sends most clouds to. Rows
    whose runs hold no confusion matrix are left out; a class with no test cloud has recall None.

    Shapes:
        runs: one dict per (row, seed), ``confusion`` (C, C) true x predicted -> {row: {"recall": (C,),
        "predicted_share": (C,), "clouds": int, "seeds": int}}
    """
    out = {}
    for variant in variants:
        confs = _confusions(runs, variant)
        if not confs:
            continue
        conf = np.sum(confs, axis=0)
        truth, total = conf.sum(1), conf.sum()
        out[variant] = {
            "recall": [100 * float(conf[k, k] / truth[k]) if truth[k] else None for k in range(len(conf))],
            "predicted_share": (100 * conf.sum(0) / total).tolist() if total else [0.0] * len(conf),
            "clouds": int(total), "seeds": len(confs),
        }
    return out


def per_class_table_rows(scores: dict[str, dict], class_names: list[str] | None) -> list[dict]:
    """:func:`per_class_scores` as table rows, one per class: each row's recall with its share of the
    predictions in brackets (``"31 (14)"``); classes are named by ``class_names`` or by index.

    Shapes:
        scores: {row: {"recall": (C,), "predicted_share": (C,)}} -> C dicts
    """
    if not scores:
        return []
    n = len(next(iter(scores.values()))["recall"])
    names = list(class_names) if class_names and len(class_names) == n else [str(k) for k in range(n)]
    return [{"class": names[k], **{v: ("-" if s["recall"][k] is None else f"{s['recall'][k]:.0f}")
                                   + f" ({s['predicted_share'][k]:.0f})" for v, s in scores.items()}}
            for k in range(n)]


def set_summaries(sets: list[dict]) -> list[dict]:
    """Each object set of :func:`load_object_sets` without its runs, with each row's mean tactile accuracy
    over the seeds it has in the set (``means``) and those seeds (``seeds``).

    Shapes:
        sets: one dict per object set -> one dict per set
    """
    out = []
    for s in sets:
        acc: dict[str, list[float]] = {}
        seeds: dict[str, list[int]] = {}
        for r in s["runs"]:
            acc.setdefault(r["variant"], []).append(r["tactile_acc"])
            seeds.setdefault(r["variant"], []).append(r["seed"])
        out.append({**{k: v for k, v in s.items() if k != "runs"},
                    "means": {v: float(np.mean(a)) for v, a in acc.items()},
                    "seeds": {v: sorted(k) for v, k in seeds.items()}})
    return out


def set_table_rows(summaries: list[dict], variants: list[str]) -> list[dict]:
    """The per-set table of :func:`set_summaries`: each row's mean over the seeds it has in the set (``"-"``
    where it has none) and the set's seeds, then the mean over the sets that have the row.

    Shapes:
        summaries: one dict per object set -> one dict per set, and the mean
    """
    rows = []
    for s in summaries:
        seeds = sorted({k for v in variants for k in s["seeds"].get(v, [])})
        rows.append({"set": s["label"], **{v: f"{s['means'][v]:.1f}" if v in s["means"] else "-"
                                           for v in variants},
                     "seeds": ",".join(str(k) for k in seeds)})
    mean_row = {"set": f"mean of the sets ({len(summaries)})", "seeds": ""}
    for v in variants:
        m = [s["means"][v] for s in summaries if v in s["means"]]
        mean_row[v] = (f"{np.mean(m):.1f}" + ("" if len(m) == len(summaries) else f" ({len(m)} sets)")
                       if m else "-")
    return [*rows, mean_row]


def with_holm(rows: list[dict]) -> list[dict]:
    """``rows`` of :func:`paired_rows` or :func:`set_paired_rows` with the t-test p-values adjusted for
    the family of comparisons they form (:func:`~vtlearn.bench_utils.holm_adjust`): ``t_p_holm`` and its
    text ``"p (Holm)"`` in each row, when two or more of them have a p-value (None otherwise). One
    comparison read among many is significant at α only when its Holm p is at most α; the margin's
    one-sided p is not adjusted. The rows are changed in place and returned.

    Shapes:
        rows: one dict per comparison -> the same list
    """
    ps = [r.get("t_p") for r in rows]
    adjusted = holm_adjust(ps) if sum(p is not None for p in ps) >= 2 else [None] * len(rows)
    for r, p in zip(rows, adjusted, strict=True):
        r["t_p_holm"] = p
        r["p (Holm)"] = _p_text(p)
    return rows


def _p_text(p: float | None) -> str | None:
    if p is None:
        return None
    return f"{p:.2g}" if p < 0.001 else f"{p:.3f}"


def paired_table_columns(rows: list[dict], margin: float | None) -> list[str]:
    """The columns :func:`paired_rows`' table prints."""
    cols = ["comparison", "means", "difference", "95% CI", "p (t)", "p (Wilcoxon)", "seeds ahead"]
    if any(r.get("t_p_holm") is not None for r in rows):
        cols.insert(cols.index("p (Wilcoxon)") + 1, "p (Holm)")
    if margin is not None:
        cols.append(f"p(≤ {margin:g})")
    if any(r["cross_machine"] for r in rows):
        cols.append("cross_machine")
    return cols


def paired_figure(rows: list[dict], path, margin: float | None = None, title: str = "",
                  unit: str = "seeds") -> Path:
    """A forest plot of :func:`paired_rows` (or :func:`set_paired_rows`, with ``unit="object sets"``): each
    comparison's differences per seed or set (dots), their mean and 95 % interval (bar), a line at 0 and one
    at ``margin``. Returns the path written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from vtlearn.bench_utils import save_figure

    labels = [f"{r['comparison']} (n={r['pairs']})" for r in reversed(rows)]
    # the plot keeps about 5 inches however long the comparison names beside it are
    fig, ax = plt.subplots(figsize=(5.0 + 0.065 * max(len(t) for t in labels), 0.55 * len(rows) + 1.6))
    rng = np.random.default_rng(0)  # vertical jitter of the seed dots only
    for i, r in enumerate(rows):
        y = len(rows) - 1 - i
        d = np.asarray(r["diffs"])
        ax.scatter(d, y + rng.uniform(-0.15, 0.15, len(d)), s=12, color="0.55", zorder=2)
        if r["ci95"]:
            ax.plot(r["ci95"], [y, y], color="C0", lw=2.5, zorder=3)
        ax.plot([r["mean_diff"]], [y], "o", color="C0", ms=7, zorder=4)
    ax.axvline(0.0, color="k", lw=0.8)
    if margin is not None:
        ax.axvline(margin, color="C3", lw=1, ls="--", label=f"margin {margin:g}")
        ax.legend(loc="lower right", fontsize=8)
    ax.set_yticks(range(len(rows)))
    ax.set_yticklabels(labels, fontsize=8)
    ax.set_xlabel("difference in tactile accuracy (points)")
    ax.set_title(f"{title or 'Seed-paired differences'}\n{unit} (dots), mean and 95 % interval (bar)",
                 fontsize=9)
    fig.tight_layout()
    return save_figure(fig, path)
