"""Procedural category-level shapes, "ShapeNet-style" (thesis ch.5 5.3.3, ch.7 7.3.1, ch.8 8.3.1).

The thesis trains on ShapeNet meshes of household objects (bottles, mugs, cans, ...) and tests on the
real objects of its tables. ShapeNet cannot be downloaded here, so each category is a parametric
family: a revolved profile (a closed polyline in the (radius, height) half-plane, revolved about z)
plus parts (handles as capped tubes, trigger heads as boxes). Closed profiles give watertight
solids; a part is itself watertight and only touches the body, so the union is watertight edge-wise.

Every instance is built in metres, then put in the canonical frame used by ShapeNet: z-up, the
bounding box centred at the origin and the largest extent scaled to 1 (the unit cube). The metric
size is kept in the record so that ``mesh.vertices * record["scale_m"]`` is the real object.

Shapes:
    generate_shape -> trimesh.Trimesh with vertices (V, 3) inside [-0.5, 0.5]^3, faces (F, 3)
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from vtlearn.validation import as_int, as_surface_mesh

log = logging.getLogger(__name__)

CATEGORIES: tuple[str, ...] = (
    "bottle",
    "can",
    "cup",
    "mug",
    "wineglass",
    "spray_bottle",
    "detergent_bottle",
    "box",
    "jar",
    "bowl",
    "tape_roll",
    "shampoo_bottle",
)
# Categories whose real instances are (often) glass: the camera's transparent-object model applies.
TRANSPARENT_PROB: dict[str, float] = {"wineglass": 1.0, "bottle": 0.5, "jar": 0.5, "cup": 0.3}


@dataclass
class ShapeRecord:
    """Metadata of one generated instance (written as JSON beside the .obj)."""

    category: str
    seed: int
    params: dict
    size_m: list[float]  # bounding-box extents (x, y, z) of the real object in metres
    scale_m: float  # metres per canonical unit: vertices * scale_m is the real object
    transparent: bool
    watertight: bool
    num_faces: int

    def to_dict(self) -> dict:
        return dict(self.__dict__)


# --------------------------------------------------------------------------- building blocks
def _revolve(profile: Sequence[Sequence[float]], sections: int) -> trimesh.Trimesh:
    """Revolve a (radius, height) polyline about z. Endpoints at radius 0 close the solid."""
    return trimesh.creation.revolve(np.asarray(profile, dtype=np.float64), sections=sections)


def _arc(r0: float, z0: float, r1: float, z1: float, n: int, bulge: float = 1.0) -> np.ndarray:
    """Quarter-ellipse-like shoulder from (r0, z0) to (r1, z1), without the first point."""
    t = np.linspace(0.0, 1.0, n + 1)[1:]
    # cos/sin parametrisation gives a rounded shoulder; bulge < 1 flattens it towards a cone.
    r = r1 + (r0 - r1) * np.cos(t * np.pi / 2) ** bulge
    z = z0 + (z1 - z0) * np.sin(t * np.pi / 2)
    return np.stack([r, z], axis=1)


def _tube(path: np.ndarray, radius: float, segments: int = 12) -> trimesh.Trimesh:
    """A watertight capped tube of circular cross-section along a 3-D polyline ``path`` (K, 3)."""
    path = np.asarray(path, dtype=np.float64)
    k = len(path)
    tangents = np.gradient(path, axis=0)
    tangents /= np.linalg.norm(tangents, axis=1, keepdims=True)
    # Parallel transport keeps the ring frames from twisting along the path.
    ref = np.array([0.0, 0.0, 1.0]) if abs(tangents[0, 2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    normal = np.cross(tangents[0], ref)
    normal /= np.linalg.norm(normal)
    angles = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    rings = []
    for i in range(k):
        t = tangents[i]
        normal = normal - t * (normal @ t)
        normal /= np.linalg.norm(normal)
        binormal = np.cross(t, normal)
        ring = path[i] + radius * (np.cos(angles)[:, None] * normal + np.sin(angles)[:, None] * binormal)
        rings.append(ring)
    vertices = np.concatenate([np.concatenate(rings), path[[0, -1]]])
    faces = []
    for i in range(k - 1):
        for j in range(segments):
            a, b = i * segments + j, i * segments + (j + 1) % segments
            c, d = a + segments, b + segments
            faces += [[a, b, d], [a, d, c]]
    start, end = k * segments, k * segments + 1
    for j in range(segments):
        faces.append([start, (j + 1) % segments, j])
        faces.append([end, (k - 1) * segments + j, (k - 1) * segments + (j + 1) % segments])
    mesh = trimesh.Trimesh(vertices, np.asarray(faces), process=True)
    trimesh.repair.fix_normals(mesh)
    return mesh


def _box(extents: Sequence[float], centre: Sequence[float]) -> trimesh.Trimesh:
    return trimesh.creation.box(extents=extents, transform=trimesh.transformations.translation_matrix(centre))


def _cylinder(radius: float, z0: float, z1: float, sections: int, xy=(0.0, 0.0), axis: str = "z"):
    m = trimesh.creation.cylinder(radius=radius, height=z1 - z0, sections=sections)
    m.apply_translation([0, 0, (z0 + z1) / 2])
    if axis == "x":
        m.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))
    m.apply_translation([xy[0], xy[1], 0])
    return m


def _superellipse_warp(mesh: trimesh.Trimesh, ax: float, ay: float, exponent: float) -> trimesh.Trimesh:
    """Map circular cross-sections to superellipses |x/ax|^n + |y/ay|^n = r^n (n=2 ellipse, 4 rounded box)."""
    v = mesh.vertices.copy()
    r = np.linalg.norm(v[:, :2], axis=1)
    th = np.arctan2(v[:, 1], v[:, 0])
    c, s = np.cos(th), np.sin(th)
    e = 2.0 / exponent
    v[:, 0] = r * ax * np.sign(c) * np.abs(c) ** e
    v[:, 1] = r * ay * np.sign(s) * np.abs(s) ** e
    return trimesh.Trimesh(v, mesh.faces.copy(), process=False)


def _side_handle(x_wall: float, z_low: float, z_high: float, reach: float, radius: float) -> trimesh.Trimesh:
    """A D-shaped handle in the xz-plane leaving the wall at x_wall and bulging to +x by ``reach``."""
    t = np.linspace(-np.pi / 2, np.pi / 2, 17)
    zc, hz = (z_low + z_high) / 2, (z_high - z_low) / 2
    # Ends sink 1 mm into the wall so the tube caps hide inside the body.
    x = x_wall - 0.001 + (reach + 0.001) * np.cos(t) ** 0.7
    z = zc + hz * np.sin(t)
    return _tube(np.stack([x, np.zeros_like(x), z], axis=1), radius)


# --------------------------------------------------------------------------- categories
def _u(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.uniform(lo, hi))


def _bottle(rng, sections):
    p = {
        "height": _u(rng, 0.18, 0.32),
        "radius": _u(rng, 0.028, 0.045),
        "neck_radius": _u(rng, 0.01, 0.016),
        "neck_height": _u(rng, 0.015, 0.05),
        "shoulder_frac": _u(rng, 0.12, 0.35),
        "bulge": _u(rng, 0.4, 1.6),
    }
    h, r, nr = p["height"], p["radius"], p["neck_radius"]
    z_sh = h - p["neck_height"] - 0.012
    z_body = z_sh - p["shoulder_frac"] * h
    prof = [[0, 0], [r * 0.92, 0], [r, 0.006], [r, z_body]]
    prof += _arc(r, z_body, nr, z_sh, 8, p["bulge"]).tolist()
    prof += [[nr, h - 0.012], [nr * 1.15, h - 0.012], [nr * 1.15, h], [0, h]]
    return _revolve(prof, sections), p


def _can(rng, sections):
    p = {"height": _u(rng, 0.09, 0.17), "radius": _u(rng, 0.026, 0.045), "rim": _u(rng, 0.002, 0.006)}
    h, r, c = p["height"], p["radius"], p["rim"]
    prof = [[0, 0], [r - c, 0], [r, c], [r, h - c], [r - c, h], [r - 2 * c, h - 0.6 * c], [0, h - 0.6 * c]]
    return _revolve(prof, sections), p


def _open_vessel(r_bottom, r_top, h, wall, base, sections, foot=None):
    """Thick-walled open vessel: outer wall up, over the lip, inner wall down to the inner floor."""
    prof = [[0, 0], [r_bottom, 0]]
    if foot is not None:
        prof = [[0, 0], [foot, 0], [foot, 0.004], [r_bottom, 0.006]]
    prof += [[r_top, h], [r_top - wall, h]]
    slope = (r_top - r_bottom) / h
    prof += [[r_bottom - wall + slope * base, base], [0, base]]
    return _revolve(prof, sections)


def _cup(rng, sections):
    p = {
        "height": _u(rng, 0.07, 0.13),
        "r_bottom": _u(rng, 0.022, 0.035),
        "flare": _u(rng, 0.005, 0.02),
        "wall": _u(rng, 0.002, 0.004),
    }
    m = _open_vessel(p["r_bottom"], p["r_bottom"] + p["flare"], p["height"], p["wall"], 0.006, sections)
    return m, p


def _mug(rng, sections):
    p = {
        "height": _u(rng, 0.08, 0.12),
        "radius": _u(rng, 0.035, 0.05),
        "wall": _u(rng, 0.003, 0.006),
        "handle_reach": _u(rng, 0.022, 0.04),
        "handle_span": _u(rng, 0.45, 0.75),
        "handle_radius": _u(rng, 0.005, 0.008),
    }
    h, r = p["height"], p["radius"]
    body = _open_vessel(r, r, h, p["wall"], 0.008, sections)
    zc, span = h * 0.52, p["handle_span"] * h / 2
    handle = _side_handle(r, zc - span, zc + span, p["handle_reach"], p["handle_radius"])
    return trimesh.util.concatenate([body, handle]), p


def _wineglass(rng, sections):
    p = {
        "foot_radius": _u(rng, 0.028, 0.045),
        "stem_radius": _u(rng, 0.003, 0.005),
        "stem_height": _u(rng, 0.045, 0.1),
        "bowl_radius": _u(rng, 0.032, 0.05),
        "bowl_height": _u(rng, 0.07, 0.12),
        "rim_frac": _u(rng, 0.65, 1.0),
        "wall": 0.0015,
    }
    fr, sr, sh = p["foot_radius"], p["stem_radius"], p["stem_height"]
    br, bh, w = p["bowl_radius"], p["bowl_height"], p["wall"]
    z0 = 0.004 + sh
    # Bowl outline: from the stem, widen like a sphere to br, then narrow to the rim radius.
    t = np.linspace(0.05, 1.0, 14)
    ang = t * (np.pi / 2 + np.arccos(np.clip(p["rim_frac"], -1, 1)))
    outer = np.stack(
        [np.maximum(br * np.sin(ang), sr), z0 + bh * (1 - np.cos(ang)) / (1 - np.cos(ang[-1]))], 1
    )
    inner = outer[::-1].copy()
    inner[:, 0] = np.maximum(inner[:, 0] - w, 0.0)
    inner = inner[inner[:, 1] > z0 + 0.006]
    prof = [[0, 0], [fr, 0], [fr, 0.002], [sr * 1.6, 0.004], [sr, 0.008], [sr, z0]]
    prof += outer.tolist() + inner.tolist() + [[0, inner[-1, 1]]]
    return _revolve(prof, sections), p


def _spray_bottle(rng, sections):
    p = {
        "height": _u(rng, 0.13, 0.2),
        "radius": _u(rng, 0.03, 0.045),
        "neck_radius": _u(rng, 0.012, 0.016),
        "head_height": _u(rng, 0.035, 0.055),
        "head_length": _u(rng, 0.05, 0.075),
        "trigger_length": _u(rng, 0.025, 0.045),
    }
    h, r, nr = p["height"], p["radius"], p["neck_radius"]
    prof = [[0, 0], [r, 0], [r, h * 0.8]] + _arc(r, h * 0.8, nr, h * 0.92, 6).tolist() + [[nr, h], [0, h]]
    body = _revolve(prof, sections)
    hh, hl, hw = p["head_height"], p["head_length"], nr * 2.2
    # Head overlaps the neck top by 5 mm; nozzle points to +x; trigger hangs below the nozzle.
    head = _box([hl, hw, hh], [hl * 0.25, 0, h - 0.005 + hh / 2])
    nozzle = _cylinder(0.006, 0, 0.012, 16, axis="x")
    nozzle.apply_translation([hl * 0.75 - 0.001, 0, h - 0.005 + hh * 0.7])
    tl = p["trigger_length"]
    trigger = _box([0.008, hw * 0.6, tl], [hl * 0.6, 0, h - 0.005 - tl / 2 + 0.004])
    return trimesh.util.concatenate([body, head, nozzle, trigger]), p


def _detergent_bottle(rng, sections):
    p = {
        "height": _u(rng, 0.18, 0.28),
        "half_width": _u(rng, 0.04, 0.065),
        "half_depth": _u(rng, 0.025, 0.04),
        "squareness": _u(rng, 3.0, 6.0),
        "cap_radius": _u(rng, 0.015, 0.022),
        "handle_radius": _u(rng, 0.007, 0.011),
    }
    h, a, b = p["height"], p["half_width"], p["half_depth"]
    prof = [[0, 0], [0.96, 0], [1.0, 0.01], [1.0, h * 0.78]]
    prof += _arc(1.0, h * 0.78, 0.35, h * 0.9, 6).tolist() + [[0.35, h * 0.9], [0, h * 0.9]]
    body = _superellipse_warp(_revolve(prof, sections), a, b, p["squareness"])
    cap = _cylinder(p["cap_radius"], h * 0.9 - 0.004, h, 24, xy=(-a * 0.35, 0))
    # Handle arches over the back-right shoulder from the top of the body to the upper side wall.
    t = np.linspace(0, np.pi / 2, 14)
    path = np.stack(
        [
            a * 0.2 + (a * 0.78) * np.sin(t),
            np.zeros_like(t),
            h * 0.86 + 0.03 * np.cos(t) - 0.1 * h * (1 - np.cos(t)) * np.sin(t),
        ],
        1,
    )
    handle = _tube(path, p["handle_radius"])
    return trimesh.util.concatenate([body, cap, handle]), p


def _box_shape(rng, sections):
    p = {"x": _u(rng, 0.05, 0.25), "y": _u(rng, 0.04, 0.18), "z": _u(rng, 0.03, 0.25)}
    return _box([p["x"], p["y"], p["z"]], [0, 0, p["z"] / 2]), p


def _jar(rng, sections):
    p = {
        "height": _u(rng, 0.07, 0.15),
        "radius": _u(rng, 0.035, 0.06),
        "shoulder": _u(rng, 0.005, 0.02),
        "lid_height": _u(rng, 0.012, 0.03),
        "lid_overhang": _u(rng, 0.0, 0.004),
    }
    h, r, s = p["height"], p["radius"], p["shoulder"]
    neck = r - s
    lid = neck + p["lid_overhang"]
    hb = h - p["lid_height"]
    prof = [[0, 0], [r - 0.004, 0], [r, 0.004], [r, hb - s - 0.004]] + _arc(
        r, hb - s - 0.004, neck, hb, 5
    ).tolist()
    prof += [[lid, hb], [lid, h - 0.002], [lid - 0.002, h], [0, h]]
    return _revolve(prof, sections), p


def _bowl(rng, sections):
    p = {
        "radius": _u(rng, 0.06, 0.1),
        "height": _u(rng, 0.04, 0.08),
        "foot_frac": _u(rng, 0.3, 0.5),
        "wall": _u(rng, 0.003, 0.006),
        "roundness": _u(rng, 0.6, 1.4),
    }
    r, h, w = p["radius"], p["height"], p["wall"]
    foot = r * p["foot_frac"]
    t = np.linspace(0.0, 1.0, 12)
    outer = np.stack(
        [foot + (r - foot) * np.sin(t * np.pi / 2) ** p["roundness"], 0.006 + (h - 0.006) * t], 1
    )
    inner = outer[::-1].copy()
    inner[:, 0] -= w
    inner[-1] = [0.0, inner[-1, 1]]
    inner[:, 1] = np.maximum(inner[:, 1], 0.006 + w)
    keep = np.concatenate([np.diff(inner[:, 1]) != 0, [True]]) | (inner[:, 0] == 0)
    inner = inner[keep]
    prof = [[0, 0], [foot, 0]] + outer.tolist() + inner.tolist()
    prof[-1] = [0.0, inner[-1, 1]]
    return _revolve(prof, sections), p


def _tape_roll(rng, sections):
    p = {
        "outer_radius": _u(rng, 0.04, 0.065),
        "inner_frac": _u(rng, 0.55, 0.8),
        "width": _u(rng, 0.012, 0.05),
    }
    ro, w = p["outer_radius"], p["width"]
    ri = ro * p["inner_frac"]
    prof = [[ri, 0], [ro, 0], [ro, w], [ri, w], [ri, 0]]
    return _revolve(prof, sections), p


def _shampoo_bottle(rng, sections):
    p = {
        "height": _u(rng, 0.14, 0.24),
        "half_width": _u(rng, 0.03, 0.045),
        "depth_ratio": _u(rng, 0.4, 0.7),
        "taper": _u(rng, 0.7, 1.0),
        "cap_height": _u(rng, 0.02, 0.04),
    }
    h, a, hc = p["height"], p["half_width"], p["cap_height"]
    hb = h - hc
    prof = [[0, 0], [0.9 * p["taper"], 0], [p["taper"], 0.012], [1.0, hb * 0.6], [0.95, hb * 0.85]]
    prof += _arc(0.95, hb * 0.85, 0.55, hb, 4).tolist() + [[0, hb]]
    body = _superellipse_warp(_revolve(prof, sections), a, a * p["depth_ratio"], 2.0)
    cap = _superellipse_warp(
        _revolve([[0, hb - 0.003], [0.55, hb - 0.003], [0.55, h], [0, h]], sections),
        a,
        a * p["depth_ratio"],
        2.0,
    )
    return trimesh.util.concatenate([body, cap]), p


_BUILDERS: dict[str, Callable] = {
    "bottle": _bottle,
    "can": _can,
    "cup": _cup,
    "mug": _mug,
    "wineglass": _wineglass,
    "spray_bottle": _spray_bottle,
    "detergent_bottle": _detergent_bottle,
    "box": _box_shape,
    "jar": _jar,
    "bowl": _bowl,
    "tape_roll": _tape_roll,
    "shampoo_bottle": _shampoo_bottle,
}


# --------------------------------------------------------------------------- public API
def check_out_dir(out_dir, name: str = "out_dir") -> Path:
    """``out_dir`` as a Path; a ``ValueError`` naming ``name`` if it exists but is not a directory (or has a
    non-directory ancestor), before any work is done."""
    out = Path(out_dir)
    for q in (out, *out.parents):
        if q.exists():
            if not q.is_dir():
                raise ValueError(f"{name}: {q} exists and is not a directory")
            break
    return out


def normalize_mesh(mesh_m: trimesh.Trimesh) -> tuple[trimesh.Trimesh, float]:
    """Centre the bounding box at the origin and scale the largest extent to 1 (ShapeNet-style).

    Returns the canonical mesh and ``scale_m`` (metres per canonical unit). ``mesh_m`` must be a
    ``trimesh.Trimesh`` with at least one face, finite vertices and a positive surface area (``ValueError``
    naming ``mesh_m`` otherwise).

    Shapes:
        mesh_m vertices (V, 3) metres -> canonical vertices (V, 3) in [-0.5, 0.5]^3, scale_m float
    """
    as_surface_mesh(mesh_m, "mesh_m")
    lo, hi = mesh_m.bounds
    scale = float(np.max(hi - lo))
    if not np.isfinite(scale) or scale <= 0:
        raise ValueError(f"mesh_m: degenerate bounding box {hi - lo}")
    v = (mesh_m.vertices - (lo + hi) / 2) / scale
    return trimesh.Trimesh(v, mesh_m.faces.copy(), process=False), scale


def generate_shape(category: str, seed: int, sections: int = 48) -> tuple[trimesh.Trimesh, ShapeRecord]:
    """One procedural instance of ``category`` in the canonical unit-cube frame, plus its record.

    Args:
        category: one of :data:`CATEGORIES`.
        seed: instance seed; the same (category, seed, sections) always gives the same mesh.
        sections: angular resolution of revolved parts (more sections, more faces), an integer >= 8.

    Raises ``ValueError`` naming the argument for an unknown category, a negative or non-integer seed, or
    bad ``sections``.

    Shapes:
        -> mesh with vertices (V, 3) in the canonical frame (``* record.scale_m`` = metres), faces (F, 3)
    """
    if not isinstance(category, str) or category not in _BUILDERS:
        raise ValueError(f"category: unknown {category!r}, expected one of {CATEGORIES}")
    sections = as_int(sections, "sections", 8)
    seed = as_int(seed, "seed", 0)
    rng = np.random.default_rng([int(seed), CATEGORIES.index(category)])
    mesh_m, params = _BUILDERS[category](rng, int(sections))
    transparent = bool(rng.uniform() < TRANSPARENT_PROB.get(category, 0.0))
    mesh, scale = normalize_mesh(mesh_m)
    record = ShapeRecord(
        category=category,
        seed=int(seed),
        params={k: round(float(v), 6) for k, v in params.items()},
        size_m=[float(x) for x in mesh_m.extents],
        scale_m=scale,
        transparent=transparent,
        watertight=bool(mesh.is_watertight),
        num_faces=int(len(mesh.faces)),
    )
    return mesh, record


def instance_seed(seed: int, category: str, index: int) -> int:
    """The per-instance seed used by gen-shapes and gen-data, derived from (seed, category, index).

    ``seed`` and ``index`` are non-negative integers and ``category`` one of :data:`CATEGORIES`
    (``ValueError`` naming the argument otherwise).
    """
    if not isinstance(category, str) or category not in CATEGORIES:
        raise ValueError(f"category: unknown {category!r}, expected one of {CATEGORIES}")
    seed = as_int(seed, "seed", 0)
    index = as_int(index, "index", 0)
    ss = np.random.SeedSequence([seed, CATEGORIES.index(category), index])
    return int(ss.generate_state(1, dtype=np.uint32)[0])


def write_shapes(
    out_dir: str | Path,
    categories: Sequence[str] = CATEGORIES,
    per_category: int = 10,
    seed: int = 0,
    sections: int = 48,
    progress: bool = True,
) -> list[dict]:
    """Write ``<out>/<category>/<category>_<i>.obj`` + ``.json`` for each instance; returns the records.

    ``out_dir`` must be (or become) a directory, ``categories`` a non-empty list of known categories and
    ``seed`` a non-negative integer (``ValueError`` naming the argument otherwise).
    """
    from tqdm import tqdm

    per_category = as_int(per_category, "per_category")
    if len(categories) == 0:
        raise ValueError(f"categories: need at least one of {CATEGORIES}, got none")
    for c in categories:
        if c not in _BUILDERS:
            raise ValueError(f"categories: unknown {c!r}, expected some of {CATEGORIES}")
    as_int(seed, "seed", 0)
    as_int(sections, "sections", 8)
    out = check_out_dir(out_dir)
    jobs = [(c, i) for c in categories for i in range(per_category)]
    records = []
    for c, i in tqdm(jobs, desc="gen-shapes", disable=not progress):
        mesh, rec = generate_shape(c, instance_seed(seed, c, i), sections)
        d = out / c
        d.mkdir(parents=True, exist_ok=True)
        name = f"{c}_{i:04d}"
        mesh.export(d / f"{name}.obj")
        rd = rec.to_dict() | {"name": name, "file": f"{c}/{name}.obj"}
        (d / f"{name}.json").write_text(json.dumps(rd, indent=1, sort_keys=True))
        records.append(rd)
    return records
