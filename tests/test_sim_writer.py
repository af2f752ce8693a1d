"""gen-data writer: shard format, splits by instance, determinism, kill-then-resume gives the same
manifest, and the crossmodal visual crop."""

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from _interrupt import ended_pid, interrupt_once_started

from vtlearn.sim_data.writer import GenConfig, _split_counts, generate_dataset, sha256_file

ARGS = [
    "reconstruction",
    "--categories",
    "can,box,cup",
    "--per-category",
    "4",
    "--shard-size",
    "1",
    "--touches",
    "6",
    "--pinches",
    "2",
    "--sections",
    "16",
    "--seed",
    "5",
]


def _cfg():
    return GenConfig(
        kind="reconstruction",
        categories=["can", "box", "cup"],
        per_category=4,
        shard_size=1,
        touches=6,
        pinches=2,
        sections=16,
        seed=5,
    )


def test_split_counts():
    assert _split_counts(3, [0.7, 0.15, 0.15]) == [1, 1, 1]
    assert _split_counts(20, [0.7, 0.15, 0.15]) == [14, 3, 3]
    assert sum(_split_counts(7, [0.5, 0.5, 0.0])) == 7 and _split_counts(7, [0.5, 0.5, 0.0])[2] == 0


def test_shards_format_and_manifest(tmp_path):
    m = generate_dataset(_cfg(), tmp_path, progress=False)
    assert m["class_names"] == ["can", "box", "cup"] and m["kind"] == "reconstruction"
    assert sum(m["splits"][s]["instances"] for s in ("train", "val", "test")) == 12
    for meta in m["shards"]:
        assert sha256_file(tmp_path / meta["file"]) == meta["sha256"]
        with np.load(tmp_path / meta["file"], allow_pickle=False) as z:
            assert z["dense"].shape == (meta["instances"], 2048, 3) and z["dense"].dtype == np.float32
            off = z["tactile_offsets"]
            assert off[0] == 0 and off[-1] == len(z["tactile_points"]) and np.all(np.diff(off) >= 0)
    assert not list(tmp_path.glob("*.tmp*"))
    # same config, same directory: nothing to redo and an identical manifest
    assert generate_dataset(_cfg(), tmp_path, progress=False) == m
    with pytest.raises(ValueError, match="out_dir"):
        generate_dataset(
            GenConfig(kind="reconstruction", categories=["can"], per_category=3), tmp_path, progress=False
        )


def test_another_config_in_the_folder_names_the_settings_that_differ(tmp_path, capsys):
    from dataclasses import asdict

    from vtlearn.cli import main
    from vtlearn.sim_data.writer import claim_out_dir

    out = tmp_path / "ds"
    folder_cfg = GenConfig(kind="reconstruction", categories=["can", "box", "cup"], per_category=6)
    claim_out_dir(out, asdict(folder_cfg))
    argv = ["gen-data", "reconstruction", "--out", str(out), "--categories", "can,box,cup"]
    assert main([*argv, "--per-category", "5", "--seed", "3", "--tactile-points", "30", "80"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"vtlearn: error: --out: {out} holds a dataset made with another config")
    # the settings that differ, each named by the flag that sets it (the config's field names before)
    assert ("(--per-category: 6 in the folder, 5 asked; --seed: 0 in the folder, 3 asked; --tactile-points "
            "(max): 120 in the folder, 80 asked)") in err
    assert err.count(" in the folder, ") == 3  # only the settings that differ
    assert not list(out.glob("*.npz"))
    # called from Python, the refusal names the config's fields
    from vtlearn.sim_data.writer import OutDirConfigError

    with pytest.raises(OutDirConfigError, match=r"^out_dir: .*\(per_category: 6 in the folder, 5 asked\)"):
        claim_out_dir(out, asdict(GenConfig(kind="reconstruction", categories=["can", "box", "cup"],
                                            per_category=5)))
    from vtlearn.sim_data.writer import config_differences

    assert config_differences({"a": 1}, {"a": 1, "b": [1, 2]}) == "b: not set in the folder, [1, 2] asked"
    # long values: the difference itself, not two equal truncated prefixes
    many = [f"category_{i}" for i in range(12)]
    assert config_differences({"c": many}, {"c": many[:-1]}) == 'c: ["category_11"] only in the folder'
    a, b = "/data/meshes/" + "x" * 80 + "/v1", "/data/meshes/" + "x" * 80 + "/v2"
    said = config_differences({"m": a}, {"m": b})
    assert '/v1" in the folder' in said and '/v2" asked' in said


def test_a_folder_of_the_old_touch_sampler_is_not_resumed(tmp_path, capsys):
    """Sampler 1 pressed the -x and -y faces from inside the box: its shards must not be mixed with new ones.
    Its config.json has no touch_sampler key, and the refusal names it."""
    import json
    from dataclasses import asdict

    from vtlearn.cli import main

    out = tmp_path / "ds"
    out.mkdir()
    old = asdict(GenConfig(kind="reconstruction", categories=["can", "box", "cup"], per_category=6))
    del old["touch_sampler"]
    (out / "config.json").write_text(json.dumps(old))
    argv = ["gen-data", "reconstruction", "--out", str(out), "--categories", "can,box,cup",
            "--per-category", "6"]
    assert main(argv) == 2
    assert "touch_sampler: 1 in the folder, 2 asked" in capsys.readouterr().err
    with pytest.raises(ValueError, match="touch_sampler: this vtlearn generates with touch sampler 2 only"):
        GenConfig(touch_sampler=1)


def test_killed_then_rerun_gives_identical_manifest(tmp_path):
    """Acceptance: kill gen-data halfway, rerun it: the manifest equals an uninterrupted run's."""
    ref = generate_dataset(_cfg(), tmp_path / "ref", progress=False)
    out = tmp_path / "killed"
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen(
        [sys.executable, "-m", "vtlearn.cli", "gen-data", *ARGS, "--out", str(out)],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and len(list(out.glob("*.npz.json"))) < 3:
            time.sleep(0.05)
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    finally:
        if proc.poll() is None:
            proc.kill()
    finished = len(list(out.glob("*.npz.json")))
    assert 3 <= finished < 12 and not (out / "manifest.json").exists()
    # simulate shards caught mid-write (by the killed run, and by a run of the writer from before atomic_path)
    # and a shard whose sidecar is stale
    ended = ended_pid()
    (out / f".train-00099.tmp-{ended}.npz").write_bytes(b"partial")
    (out / f"train-00098.npz.tmp{ended}").write_bytes(b"partial")
    first = sorted(out.glob("*.npz"))[0]
    first.write_bytes(b"corrupt")
    resumed = generate_dataset(_cfg(), out, progress=False)
    assert resumed == ref
    assert (out / "manifest.json").read_text() == (tmp_path / "ref" / "manifest.json").read_text()
    assert not list(out.glob("*.tmp*"))


def test_resuming_removes_the_temporaries_of_ended_writers_only(tmp_path):
    """A resumed folder loses the partial files of writers that have ended; a writer still running in the
    same folder keeps its temporary file, and a user's file whose name holds ``.tmp`` stays."""
    from vtlearn.io import remove_stale_temporaries_in

    out = tmp_path / "d"
    generate_dataset(_cfg(), out, progress=False)
    ended = ended_pid()
    running = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        stale = [out / f".train-00099.tmp-{ended}.npz", out / f".config.tmp-{ended}.json",
                 out / f"train-00098.npz.tmp{ended}"]
        kept = [out / f".train-00097.tmp-{running.pid}.npz", out / "notes.tmp.txt", out / "train.tmp",
                out / f".train-00096.tmp-{os.getpid()}.npz", out / ".x.tmp-0.npz", out / f"a.tmp{10**40}"]
        for f in stale + kept:
            f.write_bytes(b"partial")
        assert generate_dataset(_cfg(), out, progress=False)  # resumes: every shard is there
        assert sorted(f.name for f in out.iterdir() if ".tmp" in f.name) == sorted(f.name for f in kept)
        assert remove_stale_temporaries_in(out) == []
        assert remove_stale_temporaries_in(tmp_path / "missing") == []
        with pytest.raises(ValueError, match="folder: need a path"):
            remove_stale_temporaries_in(None)
    finally:
        running.kill()
        running.wait()


def test_shards_record_their_host_and_a_resume_elsewhere_is_flagged(tmp_path, caplog):
    """Each side file names the host that wrote the shard (outside the fingerprint); resuming shards that
    another host finished warns that the dataset mixes two hosts' rounding."""
    import json
    import logging

    from vtlearn.bench_utils import host_info
    from vtlearn.datamodules.shards import dataset_fingerprint

    out = tmp_path / "out"
    assert generate_dataset(_cfg(), out, progress=False, max_shards=2) == {}
    sides = sorted(out.glob("*.npz.json"))
    assert len(sides) == 2 and all(json.loads(f.read_text())["host"] == host_info() for f in sides)
    # the same host resuming: no warning
    with caplog.at_level(logging.WARNING, logger="vtlearn.sim_data.writer"):
        assert generate_dataset(_cfg(), out, progress=False, max_shards=1) == {}
    assert "mixes two hosts" not in caplog.text
    # a shard finished on an AVX-512 host, resumed here
    meta = json.loads(sides[0].read_text())
    meta["host"] = {**meta["host"], "cpu_capability": "AVX512-elsewhere"}
    sides[0].write_text(json.dumps(meta))
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="vtlearn.sim_data.writer"):
        manifest = generate_dataset(_cfg(), out, progress=False)
    assert "mixes two hosts" in caplog.text and sides[0].name.removesuffix(".json") in caplog.text
    assert "AVX512-elsewhere" in caplog.text
    # the host record rides in the manifest but not in the fingerprint, which is the checksums' alone
    hosts = [m["host"]["cpu_capability"] for m in manifest["shards"]]
    assert hosts.count("AVX512-elsewhere") == 1
    ref = generate_dataset(_cfg(), tmp_path / "ref", progress=False)
    assert [m["sha256"] for m in manifest["shards"]] == [m["sha256"] for m in ref["shards"]]
    assert dataset_fingerprint(out) == dataset_fingerprint(tmp_path / "ref")


@pytest.mark.slow
def test_two_workers_write_the_same_bytes_and_resume(tmp_path):
    """Shards are planned up front and seeded per shard, so worker processes change nothing."""
    ref = generate_dataset(_cfg(), tmp_path / "serial", progress=False)
    out = tmp_path / "two"
    assert generate_dataset(_cfg(), out, workers=2, progress=False, max_shards=5) == {}
    assert len(list(out.glob("*.npz"))) == 5
    assert generate_dataset(_cfg(), out, workers=2, progress=False) == ref
    assert (out / "manifest.json").read_text() == (tmp_path / "serial" / "manifest.json").read_text()


def test_crossmodal_shard_contents(tmp_path):
    from vtlearn.sim_data.fixtures import tiny_config

    cfg = tiny_config("crossmodal")
    cfg.categories, cfg.per_category, cfg.split_fractions = ["can"], 1, [1.0, 0.0, 0.0]
    m = generate_dataset(cfg, tmp_path, progress=False)
    with np.load(tmp_path / m["shards"][0]["file"], allow_pickle=False) as z:
        assert z["visual"].shape[1:] == (1024, 3) and len(z["visual_label"]) == len(z["visual"]) == 2
        sizes = np.diff(z["tactile_offsets"])
        assert np.all((sizes >= 30) & (sizes <= 120))
        assert not bool(z["transparent"][0])
    assert json.loads((tmp_path / "manifest.json").read_text())["kind"] == "crossmodal"


def test_gen_data_tactile_points_bounds_every_cloud(tmp_path, capsys):
    """``gen-data --tactile-points 30 40`` (thesis 7.2.3's tactile clouds "usually contain 30-80 points"):
    every stored tactile cloud has 30-40 contacts, and the manifest records the range, so that a resume with
    another range is refused."""
    from vtlearn.cli import main

    out = tmp_path / "cm"
    assert main(["gen-data", "crossmodal", "--out", str(out), "--categories", "can", "--per-category", "1",
                 "--splits", "1,0,0", "--views", "1", "--tactile-clouds", "4", "--width", "160", "--height",
                 "120", "--tactile-points", "30", "40"]) == 0
    m = json.loads((out / "manifest.json").read_text())
    assert (m["config"]["tactile_min_points"], m["config"]["tactile_max_points"]) == (30, 40)
    with np.load(out / m["shards"][0]["file"], allow_pickle=False) as z:
        sizes = np.diff(z["tactile_offsets"])
    assert len(sizes) == 4 and np.all((sizes >= 30) & (sizes <= 40))
    argv = ["gen-data", "crossmodal", "--out", str(out), "--categories", "can", "--per-category", "1",
            "--splits", "1,0,0", "--views", "1", "--tactile-clouds", "4", "--width", "160", "--height", "120"]
    assert main(argv) == 2  # the default 30 120 into the 30-40 folder: refused, nothing rewritten
    assert "--tactile-points (max): 40 in the folder, 120 asked" in capsys.readouterr().err
    assert json.loads((out / "manifest.json").read_text()) == m


def test_crossmodal_visual_crop_drops_see_through_returns(tmp_path):
    """A glass's visual cloud is segmented by its box: the see-through returns (2-30 cm too deep, on or
    under the table) are dropped, which the uncropped mask keeps."""
    from vtlearn.sim_data.fixtures import tiny_config

    def outside(margin, out):
        cfg = tiny_config("crossmodal")
        cfg.categories, cfg.per_category, cfg.split_fractions = ["wineglass"], 1, [1.0, 0.0, 0.0]
        cfg.visual_crop_margin, cfg.image_width, cfg.image_height, cfg.views = margin, 320, 240, 1
        cfg.tactile_clouds = 1
        m = generate_dataset(cfg, out, progress=False)
        with np.load(out / m["shards"][0]["file"], allow_pickle=False) as z:
            lo, hi = z["dense"][0].min(0), z["dense"][0].max(0)  # canonical: largest extent 1
            v = z["visual"].reshape(-1, 3)
            assert bool(z["transparent"][0]) and len(v) > 0  # wineglasses are glass
        tol = 0.05 + 0.01  # the margin, plus the gap between sampled and true mesh bounds
        return np.mean(np.any((v < lo - tol) | (v > hi + tol), axis=1))

    assert outside(0.05, tmp_path / "crop") == 0.0
    assert outside(None, tmp_path / "mask") > 0.2


def test_opaque_gives_a_glass_category_a_dense_visual_cloud_and_keeps_its_shapes(tmp_path):
    """With ``transparency=False`` (``gen-data --opaque``) a wineglass is rendered opaque: its visual clouds
    hold hundreds of distinct points where the glass failure leaves a few dozen, and its mesh is the same
    instance as with glass. An older folder's config, without the key, resumes as the default."""
    from vtlearn.sim_data.fixtures import tiny_config

    def distinct(transparency, out):
        cfg = tiny_config("crossmodal")
        cfg.categories, cfg.per_category, cfg.split_fractions = ["wineglass"], 1, [1.0, 0.0, 0.0]
        cfg.image_width, cfg.image_height, cfg.views, cfg.tactile_clouds = 320, 240, 1, 1
        cfg.transparency = transparency
        m = generate_dataset(cfg, out, progress=False)
        with np.load(out / m["shards"][0]["file"], allow_pickle=False) as z:
            n = [len(np.unique(v.round(5), axis=0)) for v in z["visual"]]
            return bool(z["transparent"][0]), n, z["dense"][0].copy()

    glass, n_glass, dense_glass = distinct(True, tmp_path / "glass")
    opaque, n_opaque, dense_opaque = distinct(False, tmp_path / "opaque")
    assert glass and not opaque
    assert max(n_glass) < 100 and min(n_opaque) > 200, (n_glass, n_opaque)
    np.testing.assert_array_equal(dense_glass, dense_opaque)
    # a folder made before the option (no key in config.json) resumes with the default, not with --opaque
    cfg_path = tmp_path / "glass" / "config.json"
    old = json.loads(cfg_path.read_text())
    del old["transparency"]
    cfg_path.write_text(json.dumps(old))
    assert distinct(True, tmp_path / "glass")[1] == n_glass
    with pytest.raises(ValueError, match="transparency"):
        distinct(False, tmp_path / "glass")
    with pytest.raises(ValueError, match="transparency"):
        GenConfig(kind="crossmodal", transparency="no")


def test_crop_to_box_and_bad_margin():
    from vtlearn.sim_data.writer import crop_to_box

    pts = np.array([[0.0, 0, 0], [1.05, 0, 0], [1.2, 0, 0], [-0.15, 0.5, 0.5]])
    kept = crop_to_box(pts, np.zeros(3), np.ones(3), 0.1)  # box grown by 0.1 on every side
    np.testing.assert_array_equal(kept, pts[[0, 1]])
    assert len(crop_to_box(pts, np.zeros(3), np.ones(3), None)) == 4
    with pytest.raises(ValueError, match="visual_crop_margin"):
        GenConfig(kind="crossmodal", visual_crop_margin=-0.1).validate()


_SLOW_WORKER = """
import time
from pathlib import Path


def work(job, out):
    (Path(out) / ("started-" + job["name"])).touch()
    time.sleep(1.0)
    return {"file": job["name"]}
"""


def test_ctrl_c_stops_a_multi_worker_run_at_once(tmp_path):
    """Ctrl-C (SIGINT to the whole process group) during ``--workers 2``: the run stops within seconds
    with one KeyboardInterrupt (leaving the pool used to wait for every queued shard, or hang), and the
    workers print no traceback of their own."""
    (tmp_path / "slow_worker.py").write_text(_SLOW_WORKER)
    code = (
        "import sys; from pathlib import Path; import slow_worker; "
        "from vtlearn.sim_data.writer import run_shard_jobs; "
        "run_shard_jobs(Path(sys.argv[1]), [{'name': f'train-{i:05d}.npz'} for i in range(60)], "
        "slow_worker.work, (), workers=2, progress=False)"
    )
    returncode, err, seconds = interrupt_once_started(code, tmp_path, workers=2)
    assert seconds < 10
    assert returncode != 0 and err.count("KeyboardInterrupt") == 1, err
