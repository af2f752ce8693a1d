"""Helpers shared by the ``vtlearn`` commands, the benches above all: a plain-text table, JSON output,
comma-separated argument lists, the significance tests the benches report (Welch's t-test for independent
runs; Wilcoxon's signed-rank test and, with its interval, the paired t-test for paired ones), and the unit
checks of input clouds (vtlearn works in metres; a file in millimetres is the commonest wrong input)."""

from __future__ import annotations

import json
import math
import os
import platform
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "print_table", "format_table", "write_json", "save_figure", "machine_info", "host_info", "numpy_simd",
    "to_jsonable", "csv_list", "welch_p", "wilcoxon_p", "holm_adjust", "paired_difference", "read_results",
    "check_same_protocol", "ratio", "cloud_extent", "check_metres", "check_same_units",
]


def csv_list(text: str) -> list[str]:
    """The items of a comma-separated command-line value, stripped, empty items dropped."""
    return [x.strip() for x in text.split(",") if x.strip()]


def sample_std(values) -> float:
    """The sample standard deviation (ddof 1) of a bench's per-seed or per-trial values, 0.0 for a single
    value, as the tables print it beside the mean.

    Shapes:
        values (n,), n >= 1 -> float
    """
    v = np.asarray(values, dtype=np.float64)
    if v.ndim != 1 or len(v) == 0:
        raise ValueError(f"values: need a non-empty 1-D sample, got shape {v.shape}")
    return float(v.std(ddof=1)) if len(v) > 1 else 0.0


def welch_p(a, b) -> float | None:
    """Two-sided p-value of Welch's t-test (unequal variances) between two independent samples, or None
    when it is undefined: fewer than two values on a side, or both sides constant.

    Shapes:
        a (N,), b (M,) -> float
    """
    from scipy.stats import ttest_ind

    a, b = np.asarray(a, dtype=float).ravel(), np.asarray(b, dtype=float).ravel()
    if len(a) < 2 or len(b) < 2 or (a.std() == 0 and b.std() == 0):
        return None
    return float(ttest_ind(a, b, equal_var=False).pvalue)


def wilcoxon_p(diff) -> float | None:
    """Two-sided p-value of Wilcoxon's signed-rank test of paired differences, or None when it is undefined:
    fewer than two differences, or all of them zero.

    Shapes:
        diff (N,) -> float
    """
    d = np.asarray(diff, dtype=float).ravel()
    if d.size < 2 or not np.any(d != 0):
        return None
    from scipy.stats import wilcoxon

    return float(wilcoxon(d).pvalue)


def holm_adjust(pvalues) -> list[float | None]:
    """Holm's step-down adjustment of a family of p-values (Holm 1979): sorted ascending, the i-th smallest
    of the m defined ones becomes ``max_{j ≤ i} min(1, (m − j + 1)·p_(j))``, so rejecting every hypothesis
    whose adjusted p is at most α holds the family-wise error rate at α, with no assumption on how the tests
    depend on each other. Undefined p-values (None) stay None and do not count towards m.

    Shapes:
        pvalues (m,) of float in [0, 1] or None -> list (m,), in the input order
    """
    ps = list(pvalues)
    for i, p in enumerate(ps):
        if p is not None and not (isinstance(p, (int, float)) and 0.0 <= p <= 1.0):
            raise ValueError(f"pvalues[{i}]: need a probability in [0, 1] or None, got {p!r}")
    defined = sorted((p, i) for i, p in enumerate(ps) if p is not None)
    m = len(defined)
    out: list[float | None] = [None] * len(ps)
    running = 0.0
    for rank, (p, i) in enumerate(defined):
        running = max(running, min(1.0, (m - rank) * float(p)))
        out[i] = running
    return out


def paired_difference(a, b, margin: float | None = None) -> dict:
    """How far ``a`` is ahead of ``b`` over paired runs (the same seeds): the mean difference, its sample
    standard deviation, the 95 % confidence interval of the mean (Student's t), the two-sided p-values of
    the paired t-test and of Wilcoxon's signed-rank test, how many pairs ``a`` leads and trails, and with
    ``margin`` the one-sided p-value of the paired t-test that the true mean difference is no more than
    ``margin`` (small: the data show ``a`` ahead by more than ``margin``). Values that need two pairs (or
    a nonzero spread) are None with fewer.

    Shapes:
        a (N,), b (N,) -> {"pairs", "mean_diff", "sd", "ci95", "t_p", "wilcoxon_p", "ahead", "behind",
        "p_at_most_margin", "margin"}
    """
    from scipy import stats

    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    if a.ndim != 1 or a.shape != b.shape or len(a) == 0:
        raise ValueError(f"a, b: need two non-empty 1-D samples of the same length, got shapes {a.shape} and "
                         f"{b.shape}")
    if not (np.isfinite(a).all() and np.isfinite(b).all()):
        raise ValueError("a, b: the paired values must be finite (NaN or inf found)")
    if margin is not None and not math.isfinite(margin):
        raise ValueError(f"margin: need a finite number, got {margin}")
    d = a - b
    n = len(d)
    out = {"pairs": n, "mean_diff": float(d.mean()), "sd": sample_std(d), "ci95": None, "t_p": None,
           "wilcoxon_p": wilcoxon_p(d), "ahead": int((d > 0).sum()), "behind": int((d < 0).sum()),
           "margin": margin, "p_at_most_margin": None}
    if n >= 2 and out["sd"] > 0:
        se = out["sd"] / math.sqrt(n)
        half = float(stats.t.ppf(0.975, n - 1)) * se
        out["ci95"] = [out["mean_diff"] - half, out["mean_diff"] + half]
        out["t_p"] = float(2 * stats.t.sf(abs(out["mean_diff"]) / se, n - 1))
        if margin is not None:
            out["p_at_most_margin"] = float(stats.t.sf((out["mean_diff"] - margin) / se, n - 1))
    return out


def read_results(paths: list[str], bench: str, key: str, flag: str = "--merge") -> list[dict]:
    """The JSONs of earlier ``vtlearn bench <bench>`` runs, read to be pooled; a ``ValueError`` naming
    ``flag`` and the file for one that is missing, not JSON, or not a ``bench`` result holding ``key``."""
    if not paths:
        raise ValueError(f"{flag}: give at least one bench {bench} JSON")
    docs = []
    for path in paths:
        f = Path(path)
        if not f.is_file():
            raise ValueError(f"{flag}: no such file {path}")
        try:
            doc = json.loads(f.read_text())
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise ValueError(f"{flag}: {path} is not a JSON file ({exc})") from None
        if not (isinstance(doc, dict) and doc.get("bench") == bench and key in doc):
            raise ValueError(f"{flag}: {path} is not a `bench {bench}` result")
        docs.append(doc)
    return docs


def check_same_protocol(paths: list[str], docs: list[dict], keys: tuple[str, ...],
                        flag: str = "--merge") -> Any:
    """A ``ValueError`` naming ``flag`` and the file when results to be pooled were run on other data (their
    ``data_fingerprint``: the same folder name may hold data regenerated with another seed or sampler) or
    differ from the first in any of ``keys``. Results from before the fingerprint was recorded cannot be
    checked on it, so each file that has one is checked against the first that has one. Returns that
    fingerprint as the files hold it (``{"data_dir": ...}`` for the xAVTNet benches; None when no file has
    one)."""
    known = [(path, doc["data_fingerprint"]) for path, doc in zip(paths, docs, strict=True)
             if doc.get("data_fingerprint")]
    for path, fp in known[1:]:
        if fp != known[0][1]:
            raise ValueError(f"{flag}: {path} was run on other data than {known[0][0]} (data_fingerprint "
                             f"{fp} against {known[0][1]}), though both may name the same folder")
    for path, doc in zip(paths[1:], docs[1:], strict=True):
        for key in keys:
            if doc.get(key) != docs[0].get(key):
                raise ValueError(f"{flag}: {path} has {key}={doc.get(key)!r}, {paths[0]} has "
                                 f"{docs[0].get(key)!r}: not the same protocol")
    return known[0][1] if known else None


def ratio(a, b) -> float | None:
    """``a / b`` for the ratio columns of the bench tables (a method against the reference method, or against
    the thesis), or None when either is missing or ``b`` is not a positive finite number."""
    if a is None or b is None:
        return None
    a, b = float(a), float(b)
    if not (math.isfinite(a) and math.isfinite(b)) or b <= 0:
        return None
    return a / b


def cloud_extent(points) -> float:
    """The length of the diagonal of the axis-aligned bounding box of ``points`` (0 for no points), in the
    cloud's units.

    Shapes:
        points (N, 3) -> float
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    return float(np.linalg.norm(p.max(0) - p.min(0))) if len(p) else 0.0


def check_metres(points, name: str, max_extent_m: float = 10.0, what: str = "an object cloud") -> float:
    """A ``ValueError`` naming ``name`` (a command-line flag) when ``points`` span more than ``max_extent_m``
    metres, longer than ``what`` can be: in practice a file in millimetres. Returns the extent.

    Shapes:
        points (N, 3)
    """
    ext = cloud_extent(points)
    if ext > max_extent_m:
        raise ValueError(f"{name}: spans {ext:.4g} m, more than the {max_extent_m:g} m {what} can; vtlearn "
                         "reads metres (in millimetres? divide by 1000)")
    return ext


def check_same_units(a, name_a: str, b, name_b: str, factor: float = 200.0) -> None:
    """A ``ValueError`` naming both flags when the extents of two clouds of the same object differ by more
    than ``factor`` (in either direction): one of them is in other units (millimetres against metres differ by
    1000). A cloud of one point or of coincident points has no extent and is left to the caller's checks.

    Shapes:
        a (N, 3), b (M, 3)
    """
    ea, eb = cloud_extent(a), cloud_extent(b)
    if ea <= 0 or eb <= 0:
        return
    big, small = max(ea, eb), min(ea, eb)
    if big > factor * small:
        raise ValueError(f"{name_a} spans {ea:.4g} m but {name_b} {eb:.4g} m ({big / small:.0f} times as "
                         f"much): they should be the same object in the same units; vtlearn reads metres "
                         "(is one in millimetres?)")


def to_jsonable(obj: Any, nan_as_null: bool = True) -> Any:
    """Convert numpy scalars/arrays (and NaN) recursively into JSON-safe Python objects. ``nan_as_null=False``
    keeps non-finite floats, which Python's ``json`` writes and reads back as ``NaN`` / ``Infinity`` (not
    standard JSON)."""
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v, nan_as_null) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v, nan_as_null) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist(), nan_as_null)
    if isinstance(obj, np.generic):
        return to_jsonable(obj.item(), nan_as_null)
    if nan_as_null and isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, Path):
        return str(obj)
    return obj


def _fmt(v: Any) -> str:
    if v is None:
        return "-"  # not available (e.g. a p-value of fewer than two runs), as the tables' blank cells
    if isinstance(v, (float, np.floating)):
        if not math.isfinite(v):
            return "-"  # no value (a mean over no runs, a ratio to 0): null in the JSON, as None is
        a = abs(v)
        return f"{v:.3g}" if (a != 0 and (a < 1e-2 or a >= 1e5)) else f"{v:.3f}"
    return str(v)


def format_table(rows: list[dict], columns: list[str], title: str | None = None) -> str:
    """A markdown-style table of ``rows`` (dicts) restricted to ``columns``; None and missing cells
    print as "-" and "", and so do non-finite floats (the JSON holds null for both)."""
    cells = [[_fmt(r.get(c, "")) for c in columns] for r in rows]
    widths = [max([len(c)] + [len(row[i]) for row in cells]) for i, c in enumerate(columns)]
    lines = []
    if title:
        lines.append(f"### {title}")
    lines.append("| " + " | ".join(c.ljust(w) for c, w in zip(columns, widths, strict=True)) + " |")
    lines.append("|" + "|".join("-" * (w + 2) for w in widths) + "|")
    for row in cells:
        lines.append("| " + " | ".join(v.ljust(w) for v, w in zip(row, widths, strict=True)) + " |")
    return "\n".join(lines)


def print_table(rows: list[dict], columns: list[str], title: str | None = None) -> str:
    """Print :func:`format_table` and return the text (so it can also go into a markdown file)."""
    text = format_table(rows, columns, title)
    print(text, flush=True)
    return text


# The packages whose versions a benchmark records beside torch's: seeded runs repeat to the digit in one
# environment, but a different numpy, trimesh or scikit-learn can draw or compute differently, so a figure
# that does not repeat across sessions can be traced to the versions that changed.
RECORDED_PACKAGES = ("numpy", "scipy", "lightning", "torch_geometric", "trimesh", "open3d", "pybullet",
                     "scikit-learn")


def cpu_model() -> str:
    """The CPU's model name (Linux ``/proc/cpuinfo``, else :func:`platform.processor`; ``"unknown"`` when
    neither says)."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as fh:
            for line in fh:
                if line.lower().startswith("model name"):
                    return line.split(":", 1)[1].strip() or "unknown"
    except OSError:
        pass
    return platform.processor() or "unknown"


def numpy_simd() -> list[str] | None:
    """The SIMD targets numpy dispatches to on this CPU beyond its build baseline (e.g. ``["X86_V3"]`` on
    an AVX2 CPU, ``["X86_V3", "X86_V4", ...]`` on an AVX-512 one), from numpy's own feature detection;
    None where this numpy does not expose it. Functions with a kernel per target (numpy's AVX-512 float64
    ``exp`` and ``log`` among them) may round differently from one target to another."""
    try:
        from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__
    except ImportError:
        return None
    return [t for t in __cpu_dispatch__ if __cpu_features__.get(t)]


def host_info() -> dict:
    """The host's identity as far as floating point is concerned: the platform string (with the kernel
    build), the CPU model, the vector kernels torch dispatches to (``cpu_capability``, e.g. AVX512 or AVX2:
    float sums round differently on each, so a training reproduces bit for bit only on the same capability)
    and numpy's SIMD targets (:func:`numpy_simd`). `gen-data` records it beside each shard's checksum."""
    import torch

    return {"platform": platform.platform(), "cpu_model": cpu_model(),
            "cpu_capability": torch.backends.cpu.get_cpu_capability(), "numpy_simd": numpy_simd()}


def machine_info(extra_packages: tuple[str, ...] = ()) -> dict:
    """What a benchmark ran on: CPU count, model and vector capability (:func:`host_info`), Python, torch,
    threads, and the versions of :data:`RECORDED_PACKAGES` and ``extra_packages`` (distribution names;
    ``None`` for one that is not installed)."""
    from importlib import metadata

    import torch

    def version(name: str):
        try:
            return metadata.version(name)
        except metadata.PackageNotFoundError:
            return None

    host = host_info()
    return {
        "python": platform.python_version(),
        "platform": host["platform"],
        "cpu_count": os.cpu_count(),
        "cpu_model": host["cpu_model"],
        "cpu_capability": host["cpu_capability"],
        "numpy_simd": host["numpy_simd"],
        "torch": torch.__version__,
        "torch_threads": torch.get_num_threads(),
        "packages": {name: version(name) for name in (*RECORDED_PACKAGES, *extra_packages)},
    }


def check_output_path(path, name: str, what: str, folder: bool = False) -> Path:
    """``path`` as a place a command can write a ``what`` file (or, with ``folder``, a folder) into later; a
    ``ValueError`` naming ``name`` when it is a folder where a file goes (``--json runs/`` instead of
    ``--json runs/x.json``), a file where a folder goes, or below a file. Nothing is created, so a command
    checks its output paths before a long run instead of failing at its end."""
    p = Path(path)
    if not folder and p.is_dir():
        raise ValueError(f"{name}: {p} is a folder; give a file name for the {what} inside it")
    if folder and p.exists() and not p.is_dir():
        raise ValueError(f"{name}: {p} is a file; need a folder for the {what}")
    bad = next((q for q in p.parents if q.exists() and not q.is_dir()), None)
    if bad is not None:
        raise ValueError(f"{name}: cannot write the {what} to {p}, {bad} is a file, not a folder")
    return p


def _output_file(path, what: str) -> Path:
    """``path`` checked by :func:`check_output_path`, its parent folders created."""
    p = check_output_path(path, "path", what)
    p.parent.mkdir(parents=True, exist_ok=True)
    return p


def figure_suffixes() -> tuple[str, ...]:
    """The file suffixes matplotlib can save a figure as (.png, .pdf, .svg, ...)."""
    from matplotlib.backend_bases import FigureCanvasBase

    return tuple(sorted("." + k for k in FigureCanvasBase.get_supported_filetypes()))


def check_figure_path(path, name: str) -> Path:
    """:func:`check_output_path` for a figure, and a ``ValueError`` naming ``name`` when matplotlib cannot
    write its format (``--figure x.txt``), so a command refuses it before its run, not after."""
    p = check_output_path(path, name, "figure")
    suffixes = figure_suffixes()
    if p.suffix.lower() not in suffixes:
        got = f"format {p.suffix!r}" if p.suffix else "file without a suffix"
        raise ValueError(f"{name}: unsupported figure {got} ({path}); expected one of {', '.join(suffixes)}")
    return p


def write_json_and_figure(path, result: dict, figure, draw) -> None:
    """Write ``result`` as JSON at ``path``, then draw it with ``draw(result, figure)`` and record the
    figure's path in the JSON (``"figure"``): a figure that fails leaves the results on disk."""
    write_json(path, result)
    draw(result, figure)
    result["figure"] = str(figure)
    write_json(path, result)


def write_json(path, obj: Any) -> Path:
    """Write ``obj`` as indented JSON (numpy converted), creating parent folders. The text goes to a
    temporary file beside ``path`` first and is renamed over it, so a killed run never leaves half a file."""
    from vtlearn.io import atomic_path

    p = _output_file(path, "JSON")
    with atomic_path(p) as tmp:
        tmp.write_text(json.dumps(to_jsonable(obj), indent=2))
    return p


def save_figure(fig, path, dpi: int = 120) -> Path:
    """Save a matplotlib figure as ``path`` (parent folders created) and close it; returns the path."""
    import matplotlib.pyplot as plt

    p = _output_file(path, "figure")
    fig.savefig(p, dpi=dpi)
    plt.close(fig)
    return p
