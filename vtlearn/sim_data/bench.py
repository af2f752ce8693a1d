"""`vtlearn bench sim`: touches/s (free sensor, ~5k-face mesh), camera frame -> cloud ms, shapes/s.

Timings are wall-clock on one process; pybullet runs single-threaded. Treat them as indicative on a
shared machine.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from vtlearn.validation import as_int


def bench_touches(n: int, sensor: str = "xela_4x4") -> dict:
    from vtlearn.sim_data.scene import Scene
    from vtlearn.sim_data.shapes import generate_shape
    from vtlearn.sim_data.tactile import TactileSimulator, sample_touches

    n = as_int(n, "n")
    mesh, rec = generate_shape("bottle", 0, sections=180)  # ~5k faces
    with Scene() as scene:
        T = np.eye(4)
        T[2, 3] = -mesh.bounds[0, 2] * rec.scale_m
        body = scene.add_mesh(mesh, rec.scale_m, T)
        sim = TactileSimulator(scene, sensor, objects=[body])
        lo, hi = scene.objects[body].mesh_m.bounds + T[:3, 3]
        acts = sample_touches(lo, hi, n, np.random.default_rng(0))
        sim.touch(*acts[0])
        t0 = time.perf_counter()
        contacts = [sim.touch(*a).num_contacts for a in acts]
        dt = time.perf_counter() - t0
    return {
        "faces": len(mesh.faces),
        "touches": n,
        "seconds": dt,
        "touches_per_s": n / dt,
        "contact_rate": float(np.mean(np.array(contacts) > 0)),
        "mean_contacts": float(np.mean(contacts)),
    }


def bench_camera(frames: int, width: int = 320, height: int = 240) -> dict:
    from vtlearn.sim_data.camera import RGBDCamera, sample_hemisphere_views
    from vtlearn.sim_data.scene import Scene
    from vtlearn.sim_data.shapes import generate_shape

    frames = as_int(frames, "frames")
    mesh, rec = generate_shape("mug", 0)
    with Scene() as scene:
        T = np.eye(4)
        T[2, 3] = -mesh.bounds[0, 2] * rec.scale_m
        body = scene.add_mesh(mesh, rec.scale_m, T)
        cam = RGBDCamera(width, height)
        rng = np.random.default_rng(0)
        views = sample_hemisphere_views(T[:3, 3] + [0, 0, 0.05], 0.6, frames, rng)
        cam.point_cloud(cam.render(scene, views[0], rng), body, rng)
        ms, npts = [], []
        for V in views:
            t0 = time.perf_counter()
            pts = cam.point_cloud(cam.render(scene, V, rng), body, rng)
            ms.append(1000 * (time.perf_counter() - t0))
            npts.append(len(pts))
    return {
        "resolution": f"{width}x{height}",
        "frames": frames,
        "ms_mean": float(np.mean(ms)),
        "ms_median": float(np.median(ms)),
        "points_mean": float(np.mean(npts)),
    }


def bench_shapes(n: int) -> dict:
    from vtlearn.sim_data.shapes import CATEGORIES, generate_shape

    n = as_int(n, "n")
    t0 = time.perf_counter()
    for i in range(n):
        generate_shape(CATEGORIES[i % len(CATEGORIES)], i)
    dt = time.perf_counter() - t0
    return {"shapes": n, "categories": min(n, len(CATEGORIES)), "seconds": dt, "shapes_per_s": n / dt}


def run(args: argparse.Namespace) -> int:
    from vtlearn.bench_utils import machine_info, print_table, write_json

    touch = bench_touches(args.touches)
    cam = bench_camera(args.frames)
    shapes = bench_shapes(args.shapes)
    rows = [
        {
            "metric": "touch actions / s (free sensor, xela_4x4)",
            "value": touch["touches_per_s"],
            "goal": ">= 200",
            "detail": f"{touch['faces']} faces, contact rate {touch['contact_rate']:.2f}",
        },
        {
            "metric": "camera frame -> cloud (ms, median)",
            "value": cam["ms_median"],
            "goal": "<= 50",
            "detail": f"{cam['resolution']}, mean {cam['ms_mean']:.1f} ms, {cam['points_mean']:.0f} pts",
        },
        {
            "metric": "gen-shapes shapes / s",
            "value": shapes["shapes_per_s"],
            "goal": "-",
            "detail": f"{shapes['shapes']} shapes, {shapes['categories']} categories, 48 sections",
        },
    ]
    print_table(rows, ["metric", "value", "goal", "detail"], title="vtlearn bench sim (single process)")
    path = write_json(args.json, {"touch": touch, "camera": cam, "shapes": shapes, "machine": machine_info()})
    print(f"wrote {path}")
    return 0
