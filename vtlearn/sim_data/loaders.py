"""Real mesh datasets as item lists for `vtlearn gen-data --meshes ...` (thesis ch.5, 7, 8 train on ShapeNet).

Supported layouts (detected automatically by :func:`scan_mesh_folder`):

* ShapeNetCore v2: ``ROOT/<synset>/<model>/models/model_normalized.obj``, and v1:
  ``ROOT/<synset>/<model>/model.obj``. Categories get readable names (``02691156`` -> ``airplane``) from a
  built-in table of the 55 ShapeNetCore synsets, then from ``ROOT/taxonomy.json`` (its first name), else
  they keep the synset id. ShapeNet is y-up, so its meshes are turned z-up.
* ModelNet40 / ModelNet10: ``ROOT/<category>/{train,test}/*.off`` (z-up). Each item records the folder
  it came from as ``"source_split"`` (``"train"`` or ``"test"``). gen-data splits the instances by
  ``--splits`` and ignores those folders, unless ``--keep-split`` is given: then every kept mesh of a
  ``test`` folder is a test instance, and the kept ``train`` meshes are split into train and val in the
  ratio of the train and val fractions of ``--splits``, so that results compare with published ModelNet
  numbers. ``--per-category N`` then takes up to N usable meshes from each of a category's two folders
  (``vtlearn gen-data crossmodal --meshes ModelNet40 --keep-split --per-category 1000`` keeps every mesh:
  no ModelNet40 folder holds more than 889).
* Category per folder: ``ROOT/<category>/*.{obj,off,ply,stl}`` (z-up).
* ``"pybullet_data"``: the meshes shipped with pybullet (bunny, duck, teddy, mug, 50 random_urdfs objects).

Hidden files (``.DS_Store``, macOS ``._*`` copies) are ignored. Each item is ``{"category", "file",
"scale_m"}`` plus ``"up": "y"`` for y-up meshes and ``"source_split"`` for ModelNet meshes. ``scale_m`` is
a nominal real size in metres for the category, because these meshes carry no metric scale: every mesh is
centred and scaled to a largest extent of 1 whatever its units (mm, m, or none). Meshes that cannot be
read, are empty, have non-finite vertices, zero area, are flat (one plane), or have non-manifold edges
(shared by more than two faces, once duplicate faces are dropped) are skipped, with one warning per mesh
and a count. They never crash a run. Open meshes are kept.
"""

from __future__ import annotations

import contextlib
import json
import logging
from collections import Counter
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)

MESH_EXTS = (".obj", ".off", ".ply", ".stl")
# The 55 ShapeNetCore synsets, named after the first word of their taxonomy.json names (some shortened).
SHAPENET_SYNSETS = {
    "02691156": "airplane", "02747177": "trash_bin", "02773838": "bag", "02801938": "basket",
    "02808440": "bathtub", "02818832": "bed", "02828884": "bench", "02843684": "birdhouse",
    "02871439": "bookshelf", "02876657": "bottle", "02880940": "bowl", "02924116": "bus",
    "02933112": "cabinet", "02942699": "camera", "02946921": "can", "02954340": "cap", "02958343": "car",
    "02992529": "cellphone", "03001627": "chair", "03046257": "clock", "03085013": "keyboard",
    "03207941": "dishwasher", "03211117": "display", "03261776": "earphone", "03325088": "faucet",
    "03337140": "file_cabinet", "03467517": "guitar", "03513137": "helmet", "03593526": "jar",
    "03624134": "knife", "03636649": "lamp", "03642806": "laptop", "03691459": "loudspeaker",
    "03710193": "mailbox", "03759954": "microphone", "03761084": "microwave", "03790512": "motorcycle",
    "03797390": "mug", "03928116": "piano", "03938244": "pillow", "03948459": "pistol", "03991062": "pot",
    "04004475": "printer", "04074963": "remote", "04090263": "rifle", "04099429": "rocket",
    "04225987": "skateboard", "04256520": "sofa", "04330267": "stove", "04379243": "table",
    "04401088": "telephone", "04460130": "tower", "04468005": "train", "04530566": "watercraft",
    "04554684": "washer",
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
# ShapeNet's y-up frame -> vtlearn's z-up frame: +90 deg about x, (x, y, z) -> (x, -z, y)
_R_ZUP_YUP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def _flatness(vertices: np.ndarray) -> float:
    """Smallest over largest principal spread of ``vertices`` (V, 3): 0 for points in one plane or line."""
    c = vertices - vertices.mean(axis=0)
    ev = np.clip(np.linalg.eigvalsh(c.T @ c), 0.0, None)  # ascending
    return float(np.sqrt(ev[0] / ev[-1])) if ev[-1] > 0 else 0.0


def check_mesh(path: str | Path, up: str = "z"):
    """(mesh, None) for a usable mesh, (None, reason) otherwise; the mesh is canonical (see below).

    Unusable: unreadable or unsupported files, no faces, NaN/inf vertices (checked on the file's raw
    vertices, before trimesh's processing silently drops them with their faces), zero surface area, all
    vertices at one point, a flat mesh (all vertices in one plane or on one line: a planar polygon is not a
    touchable object), or non-manifold edges. Open (non-watertight) meshes are accepted: real ShapeNet meshes
    often are. Duplicate faces (ShapeNet often stores a face once per winding) and zero-area faces are
    dropped first.

    The returned mesh is in the canonical frame: turned z-up when ``up == "y"`` (ShapeNet), the bounding
    box centred at the origin and the largest extent 1, whatever the file's units. The vertices are
    rescaled before trimesh merges them, so meshes in mm or at 1e-9 or 1e20 scale are read alike.

    Raises:
        FileNotFoundError: ``path`` does not exist.
        ValueError: ``up`` is not ``"z"`` or ``"y"``.
    """
    import trimesh

    from vtlearn.io import MESH_SUFFIXES
    from vtlearn.sim_data.shapes import normalize_mesh

    if up not in ("z", "y"):
        raise ValueError(f"up: expected 'z' or 'y', got {up!r}")
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
    v = np.asarray(raw.vertices, dtype=np.float64)
    faces = np.asarray(raw.faces)
    if not np.all(np.isfinite(v)):
        return None, "non-finite vertices"
    if faces.min() < 0 or faces.max() >= len(v):
        return None, f"unreadable (face index {int(faces.max())} out of range for {len(v)} vertices)"
    lo, hi = v.min(axis=0), v.max(axis=0)
    extent = float(np.max(hi - lo))
    if not (np.isfinite(extent) and extent > 0):
        return None, "zero surface area (all vertices at one point)"
    v = (v - (lo + hi) / 2) / extent  # scale-free from here on: trimesh's merge tolerance is absolute
    if up == "y":
        v = v @ _R_ZUP_YUP.T
    mesh = trimesh.Trimesh(v, faces, process=True)
    mesh.update_faces(mesh.unique_faces())
    mesh.update_faces(mesh.nondegenerate_faces())
    mesh.remove_unreferenced_vertices()
    if len(mesh.faces) == 0 or not mesh.area > 0:
        return None, "zero surface area"
    if _flatness(np.asarray(mesh.vertices, dtype=np.float64)) < 1e-6:
        return None, "flat (all vertices in one plane or on one line)"
    edges = np.sort(mesh.edges, axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    if (counts > 2).any():
        return None, f"non-manifold ({int((counts > 2).sum())} edges shared by > 2 faces)"
    return normalize_mesh(mesh)[0], None


def load_mesh_item(item: dict):
    """The canonical mesh of a scanned item (:func:`check_mesh` of ``item["file"]``, ``item.get("up")``).

    Raises:
        ValueError: naming the file, when the mesh is unusable (e.g. changed since it was scanned).
    """
    mesh, reason = check_mesh(item["file"], item.get("up", "z"))
    if reason is not None:
        raise ValueError(f"{item['file']}: unusable mesh ({reason})")
    return mesh


def _item(category: str, path: Path, up: str = "z", source_split: str | None = None) -> dict:
    item = {"category": category, "file": str(path), "scale_m": NOMINAL_SIZE_M.get(category, DEFAULT_SIZE_M)}
    if up != "z":
        item["up"] = up
    if source_split is not None:
        item["source_split"] = source_split
    return item


def _visible(paths):
    """``paths`` without hidden files or folders (``.DS_Store``, macOS ``._*`` copies in archives)."""
    return [p for p in paths if not any(part.startswith(".") for part in p.parts[-3:])]


def shapenet_names(root: str | Path) -> dict[str, str]:
    """Synset id -> category name: ``ROOT/taxonomy.json`` (first of its names, snake_case) for the synsets
    the built-in :data:`SHAPENET_SYNSETS` table lacks. A missing or malformed taxonomy.json is ignored
    (with a warning when malformed)."""
    names = {}
    path = Path(root) / "taxonomy.json"
    if path.is_file():
        try:
            for entry in json.loads(path.read_text()):
                first = str(entry["name"]).split(",")[0].strip().lower().replace(" ", "_")
                if first:
                    names[str(entry["synsetId"])] = first
        except (OSError, UnicodeDecodeError, ValueError, TypeError, KeyError) as exc:
            log.warning("ignoring %s: not a ShapeNet taxonomy (%s: %s)", path, type(exc).__name__, exc)
    return names | SHAPENET_SYNSETS


def scan_shapenet(root: str | Path) -> list[dict]:
    """ShapeNetCore v2 (``*/*/models/model_normalized.obj``) or, failing that, v1 (``*/*/model.obj``)."""
    root = Path(root)
    files = _visible(sorted(root.glob("*/*/models/model_normalized.obj")))
    synset_part = -4
    if not files:
        files, synset_part = _visible(sorted(root.glob("*/*/model.obj"))), -3
    names = shapenet_names(root) if files else {}
    unnamed = sorted({p.parts[synset_part] for p in files} - set(names))
    if unnamed:
        log.warning("ShapeNet synsets without a name (no taxonomy.json entry): %s; they keep their ids",
                    ", ".join(unnamed))
    return [_item(names.get(p.parts[synset_part], p.parts[synset_part]), p, up="y") for p in files]


def scan_modelnet(root: str | Path) -> list[dict]:
    root = Path(root)
    return [_item(p.parts[-3], p, source_split=p.parts[-2]) for p in _visible(sorted(root.glob("*/*/*.off")))
            if p.parts[-2] in ("train", "test")]


def scan_category_folders(root: str | Path) -> list[dict]:
    root = Path(root)
    return [_item(p.parent.name, p) for p in _visible(sorted(root.glob("*/*")))
            if p.suffix.lower() in MESH_EXTS]


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


def mesh_root(spec: str | Path) -> Path:
    """The folder a mesh source's files are under (pybullet's data folder for ``"pybullet_data"``)."""
    if str(spec) == "pybullet_data":
        import pybullet_data

        return Path(pybullet_data.getDataPath())
    return Path(spec)


def _relative(file: str | Path, root: Path) -> str:
    try:
        return str(Path(file).relative_to(root))
    except ValueError:
        return str(file)


def scan_mesh_folder(spec: str | Path, check: bool = True, categories=None, per_category: int | None = None,
                     progress: bool = False, by_source_split: bool = False) -> list[dict]:
    """Items of a real mesh dataset; layout detected from ``spec`` (see module docstring).

    Only ``categories`` (all when None) are kept. With ``check``, each category's meshes are read in sorted
    order until ``per_category`` usable ones are found (all when None), under a progress bar when
    ``progress``; unusable ones are skipped with a warning each, then one warning counting them by reason.
    The items are the same as checking every mesh and keeping the first ``per_category`` of each category.
    With ``by_source_split`` (datasets with a split of their own, ``gen-data --keep-split``),
    ``per_category`` applies to each source split of a category instead: up to ``per_category`` usable
    train meshes and up to ``per_category`` usable test meshes.

    Raises:
        ValueError: ``by_source_split`` is set for a layout whose items have no ``"source_split"``.
    """
    from tqdm.auto import tqdm
    from tqdm.contrib.logging import logging_redirect_tqdm

    root = mesh_root(spec)
    if str(spec) == "pybullet_data":
        items = scan_pybullet_data()
    else:
        if not root.is_dir():
            raise FileNotFoundError(f"spec: no such mesh directory {root}")
        items = scan_shapenet(root) or scan_modelnet(root) or scan_category_folders(root)
        if not items:
            raise ValueError(
                f"spec: no meshes found in {root} (expected ShapeNetCore v1/v2, ModelNet40/10 or "
                "<category>/<mesh> folders)"
            )
    if categories is not None:
        items = [it for it in items if it["category"] in set(categories)]
    if by_source_split and any("source_split" not in it for it in items):
        raise ValueError(f"by_source_split: the meshes of {spec} have no train/test split of their own (only "
                         "ModelNet40/10 trees, <category>/{train,test}/*.off, have one)")
    if not check:
        return items
    # the groups per_category caps: categories, or each category's source splits
    groups: dict[tuple, list[dict]] = {}
    for it in items:
        key = (it["category"], it.get("source_split") if by_source_split else None)
        groups.setdefault(key, []).append(it)
    todo = sum(len(v) if per_category is None else min(len(v), per_category) for v in groups.values())
    good, skipped = [], []
    redirect = logging_redirect_tqdm() if progress else contextlib.nullcontext()
    with redirect, tqdm(total=todo, desc="checking meshes", unit="mesh", disable=not progress) as bar:
        for cat_items in groups.values():
            kept = 0
            for it in cat_items:
                if per_category is not None and kept >= per_category:
                    break
                try:
                    _, reason = check_mesh(it["file"], it.get("up", "z"))
                except FileNotFoundError:  # e.g. a pybullet_data file this pybullet version does not ship
                    reason = "missing file"
                if reason is None:
                    good.append(it)
                    kept += 1
                    bar.update()
                else:
                    skipped.append(reason.split(" (")[0])
                    log.warning("skipping mesh %s: %s", _relative(it["file"], root), reason)
    if skipped:
        reasons = ", ".join(f"{n} {r}" for r, n in Counter(skipped).most_common())
        log.warning("skipped %d of %d meshes read in %s (%s); each is named above", len(skipped),
                    len(good) + len(skipped), root, reasons)
    return good
