"""Real mesh datasets as item lists for `vtlearn gen-data --meshes ...` (thesis ch.5, 7, 8 train on ShapeNet).

Supported layouts (detected automatically by :func:`scan_mesh_folder`):

* ShapeNetCore v2: ``ROOT/<synset>/<model>/models/model_normalized.obj``; known synsets get names.
* ModelNet40: ``ROOT/<category>/{train,test}/*.off``.
* Category per folder: ``ROOT/<category>/*.{obj,off,ply,stl}``.
* ``"pybullet_data"``: the meshes shipped with pybullet (bunny, duck, teddy, mug, 50 random_urdfs objects).

Each item is ``{"category", "file", "scale_m"}``. ``scale_m`` is a nominal real size in metres for the
category, because these meshes carry no metric scale. Meshes that cannot be read, are empty, have
non-finite vertices, zero area, are flat (one plane), or have non-manifold edges (shared by more than two
faces) are skipped, and the reason is logged. They never crash a run. Open meshes are kept.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)

MESH_EXTS = (".obj", ".off", ".ply", ".stl")
SHAPENET_SYNSETS = {
    "02876657": "bottle",
    "02946921": "can",
    "03797390": "mug",
    "02880940": "bowl",
    "03593526": "jar",
    "02808440": "bathtub",
    "02747177": "trash_bin",
    "03642806": "laptop",
    "03991062": "pot",
    "04401088": "telephone",
    "02942699": "camera",
    "03624134": "knife",
    "04074963": "remote",
}
NOMINAL_SIZE_M = {
    "bottle": 0.25,
    "can": 0.12,
    "mug": 0.12,
    "bowl": 0.16,
    "jar": 0.12,
    "cup": 0.1,
    "bunny": 0.15,
    "duck": 0.1,
    "teddy": 0.2,
}
DEFAULT_SIZE_M = 0.15


def _flatness(vertices: np.ndarray) -> float:
    """Smallest over largest principal spread of ``vertices`` (V, 3): 0 for points in one plane or line."""
    c = vertices - vertices.mean(axis=0)
    ev = np.clip(np.linalg.eigvalsh(c.T @ c), 0.0, None)  # ascending
    return float(np.sqrt(ev[0] / ev[-1])) if ev[-1] > 0 else 0.0


def check_mesh(path: str | Path):
    """(mesh, None) for a usable mesh, (None, reason) otherwise.

    Unusable: unreadable or unsupported files, no faces, NaN/inf vertices (checked on the file's raw
    vertices, before trimesh's processing silently drops them with their faces), zero surface area, a
    flat mesh (all vertices in one plane or on one line: a planar polygon is not a touchable object), or
    non-manifold edges. Open (non-watertight) meshes are accepted: real ShapeNet meshes often are.

    Raises:
        FileNotFoundError: ``path`` does not exist.
    """
    import trimesh

    from vtlearn.io import MESH_SUFFIXES

    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"path: no such mesh file {p}")
    if p.suffix.lower() not in MESH_SUFFIXES:
        return None, f"unreadable (unsupported mesh format {p.suffix!r}; expected one of {MESH_SUFFIXES})"
    try:
        # process=False: processing would drop NaN vertices and their faces without telling us
        raw = trimesh.load(str(p), force="mesh", process=False)
    except Exception as exc:  # noqa: BLE001 - any reader failure means "skip this file"
        return None, f"unreadable ({type(exc).__name__}: {exc})"
    if not isinstance(raw, trimesh.Trimesh) or len(raw.faces) == 0:
        return None, "no faces"
    if not np.all(np.isfinite(raw.vertices)):
        return None, "non-finite vertices"
    try:
        mesh = trimesh.Trimesh(raw.vertices, raw.faces, process=True)
    except Exception as exc:  # noqa: BLE001 - e.g. face indices out of range
        return None, f"unreadable ({type(exc).__name__}: {exc})"
    if len(mesh.faces) == 0:
        return None, "no faces"
    if not mesh.area > 0:
        return None, "zero surface area"
    if _flatness(np.asarray(mesh.vertices, dtype=np.float64)) < 1e-6:
        return None, "flat (all vertices in one plane or on one line)"
    edges = np.sort(mesh.edges, axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    if (counts > 2).any():
        return None, f"non-manifold ({int((counts > 2).sum())} edges shared by > 2 faces)"
    return mesh, None


def _item(category: str, path: Path) -> dict:
    return {"category": category, "file": str(path), "scale_m": NOMINAL_SIZE_M.get(category, DEFAULT_SIZE_M)}


def scan_shapenet(root: str | Path) -> list[dict]:
    root = Path(root)
    return [
        _item(SHAPENET_SYNSETS.get(p.parts[-4], p.parts[-4]), p)
        for p in sorted(root.glob("*/*/models/model_normalized.obj"))
    ]


def scan_modelnet(root: str | Path) -> list[dict]:
    root = Path(root)
    return [_item(p.parts[-3], p) for p in sorted(root.glob("*/*/*.off")) if p.parts[-2] in ("train", "test")]


def scan_category_folders(root: str | Path) -> list[dict]:
    root = Path(root)
    return [_item(p.parent.name, p) for p in sorted(root.glob("*/*")) if p.suffix.lower() in MESH_EXTS]


def scan_pybullet_data(random_objects: int = 50) -> list[dict]:
    import pybullet_data

    d = Path(pybullet_data.getDataPath())
    items = [
        _item("bunny", d / "bunny.obj"),
        _item("duck", d / "duck.obj"),
        _item("teddy", d / "teddy2_VHACD_CHs.obj"),
        _item("mug", d / "objects" / "mug.obj"),
    ]
    items += [
        _item("random_object", p) for p in sorted((d / "random_urdfs").glob("*/*.obj"))[:random_objects]
    ]
    return items


def scan_mesh_folder(spec: str | Path, check: bool = True) -> list[dict]:
    """Items of a real mesh dataset; layout detected from ``spec`` (see module docstring)."""
    if str(spec) == "pybullet_data":
        items = scan_pybullet_data()
    else:
        root = Path(spec)
        if not root.is_dir():
            raise FileNotFoundError(f"spec: no such mesh directory {root}")
        items = scan_shapenet(root) or scan_modelnet(root) or scan_category_folders(root)
        if not items:
            raise ValueError(
                f"spec: no meshes found in {root} (expected ShapeNetCore v2, ModelNet40 or "
                "<category>/<mesh> folders)"
            )
    if not check:
        return items
    good = []
    for it in items:
        try:
            _, reason = check_mesh(it["file"])
        except FileNotFoundError:  # e.g. a pybullet_data file this pybullet version does not ship
            reason = "missing file"
        if reason is None:
            good.append(it)
        else:
            log.warning("skipping mesh %s: %s", os.path.relpath(it["file"]), reason)
    return good
