"""Bad data and bad flags of `gen-data`, `reconstruct` and `bench actor`: one `vtlearn: error:` line that
names the flag, exit code 2, before any long work (no table printed, no output file written)."""

import json
import os
import shutil

os.environ.setdefault("WANDB_MODE", "disabled")

import lightning as L
import pytest
import torch
from _tiny_models import TINY_ACTOR_256 as TINY  # 256 output points, as test_actor_cli's

from vtlearn.cli import main
from vtlearn.datamodules import ActivePoolDataModule, CrossModalDataModule, ReconstructionDataModule
from vtlearn.datamodules.shards import check_kind, load_manifest, load_split
from vtlearn.models.actor import ACTOR
from vtlearn.sim_data.writer import GenConfig, generate_dataset, min_per_category


def _save(model: L.LightningModule, path) -> str:
    trainer = L.Trainer(max_steps=0, logger=False, enable_checkpointing=False, enable_progress_bar=False,
                        enable_model_summary=False, accelerator="cpu")
    trainer.strategy.connect(model)
    trainer.save_checkpoint(path)
    return str(path)


@pytest.fixture(scope="module")
def actor_ckpt(tmp_path_factory):
    torch.manual_seed(0)
    return _save(ACTOR(**TINY), tmp_path_factory.mktemp("ckpt") / "actor.ckpt")


def _copy(src, dst, edit=None):
    """A copy of dataset ``src`` in ``dst`` with its manifest passed through ``edit``."""
    shutil.copytree(src, dst)
    if edit is not None:
        m = json.loads((dst / "manifest.json").read_text())
        (dst / "manifest.json").write_text(json.dumps(edit(m)))
    return dst


def _empty_test_split(m, per_category=2, fractions=None):
    """The manifest `gen-data --per-category 2` wrote before it refused that: a test split with no shard."""
    m["shards"] = [s for s in m["shards"] if s["split"] != "test"]
    m["splits"]["test"] = {"instances": 0, "tactile_clouds": 0, "visual_clouds": 0, "shards": []}
    m["config"]["per_category"] = per_category
    if fractions is not None:
        m["config"]["split_fractions"] = fractions
    return m


def _error(capsys, argv) -> str:
    """Run the CLI, check it refused with exit code 2 and one error line; return stderr."""
    assert main(argv) == 2
    out = capsys.readouterr()
    assert out.err.startswith("vtlearn: error: ") and "Traceback" not in out.err
    assert "ACTOR vs GPIS" not in out.out  # refused before the benchmark ran
    return out.err


# ------------------------------------------------------------------ 1a: an empty split
@pytest.fixture(scope="module")
def empty_recon(recon_dir, tmp_path_factory):
    return _copy(recon_dir, tmp_path_factory.mktemp("e") / "recon", _empty_test_split)


@pytest.fixture(scope="module")
def empty_cross(cross_dir, tmp_path_factory):
    return _copy(cross_dir, tmp_path_factory.mktemp("e") / "cross", _empty_test_split)


def test_load_split_refuses_an_empty_split(empty_recon):
    msg = (r"--data: split 'test' of .* is empty \(2 instance\(s\) per category left none for it\); "
           r"regenerate with more --per-category \(at least 3\)")
    with pytest.raises(ValueError, match=msg):
        load_split(empty_recon, "test", name="--data")
    assert len(load_split(empty_recon, "train")["label"]) > 0


def test_an_empty_split_made_by_a_zero_fraction_says_so(recon_dir, tmp_path):
    """`gen-data --splits 1,0,0` leaves val empty on purpose; the error advised more --per-category."""
    def no_val(m):
        m["config"]["split_fractions"] = [0.85, 0.0, 0.15]
        m["shards"] = [s for s in m["shards"] if s["split"] != "val"]
        return m

    data = _copy(recon_dir, tmp_path / "recon", no_val)
    msg = (r"--data: split 'val' of .* is empty \(its --splits fraction is 0, so it was made empty on "
           r"purpose\); regenerate with a val fraction above 0 in --splits")
    with pytest.raises(ValueError, match=msg):
        load_split(data, "val", name="--data")


def test_load_split_takes_a_manifest_already_read(empty_recon, actor_ckpt, tmp_path, monkeypatch, capsys):
    """`reconstruct --data` and `bench actor` read the manifest to check the data before the model, then
    read it again in load_split; given the manifest, load_split reads no file for it and still checks it."""
    import vtlearn.datamodules.shards as shards

    manifest = load_manifest(empty_recon, "--data")
    reads = []
    real_load = shards.load_manifest
    monkeypatch.setattr(shards, "load_manifest", lambda *a, **k: reads.append(a) or real_load(*a, **k))
    assert len(load_split(empty_recon, "train", manifest=manifest)["label"]) > 0
    assert reads == []
    with pytest.raises(ValueError, match="--data: split 'test' of .* is empty"):
        load_split(empty_recon, "test", name="--data", manifest=manifest)
    with pytest.raises(ValueError, match="--data: .* is a .reconstruction. dataset, need .crossmodal."):
        load_split(empty_recon, "train", name="--data", kind="crossmodal", manifest=manifest)
    assert main(["reconstruct", "--ckpt", actor_ckpt, "--data", str(empty_recon), "--split", "train",
                 "--out", str(tmp_path / "d.ply")]) == 0
    assert len(reads) == 1, reads


def test_commands_refuse_an_empty_split(empty_recon, actor_ckpt, tmp_path, capsys):
    err = _error(capsys, ["reconstruct", "--ckpt", actor_ckpt, "--data", str(empty_recon), "--out",
                          str(tmp_path / "d.ply")])
    assert "--data: split 'test'" in err and "is empty" in err
    assert not (tmp_path / "d.ply").exists()
    err = _error(capsys, ["bench", "actor", "--ckpt", actor_ckpt, "--data", str(empty_recon), "--json",
                          str(tmp_path / "a.json")])
    assert "--data: split 'test'" in err and "--per-category" in err
    assert not (tmp_path / "a.json").exists()


def test_datamodules_refuse_an_empty_split_where_it_is_read(empty_recon, empty_cross):
    """A split the datamodule trains on is refused at construction (train.py reports it in one line); an
    unused empty split only by the loader that reads it: a dataset with an empty test split still trains."""
    with pytest.raises(ValueError, match="data_dir: split 'test' of .* is empty"):
        CrossModalDataModule(str(empty_cross), target_split="test")  # the target stream trains on it
    for dm in (ReconstructionDataModule(str(empty_recon), batch_size=2),
               CrossModalDataModule(str(empty_cross), batch_size=2),
               ActivePoolDataModule(str(empty_cross), initial_labels=1, modality="visual", batch_size=2)):
        dm.setup("fit")
        assert dm.train_dataloader() is not None
        # active learning on visual clouds: the split is empty, the dataset does have visual clouds
        with pytest.raises(ValueError, match="data_dir: split 'test' of .* is empty") as info:
            dm.setup("test")
            dm.test_dataloader()
        assert "no visual clouds" not in str(info.value)


def test_an_empty_split_left_so_on_purpose_is_refused_only_when_used(recon_dir, tmp_path):
    d = _copy(recon_dir, tmp_path / "d", lambda m: _empty_test_split(m, 3, [0.7, 0.3, 0.0]))
    dm = ReconstructionDataModule(str(d), batch_size=2)  # a zero test fraction: train and val still work
    dm.setup("fit")
    assert len(dm.train_dataloader().dataset) > 0
    with pytest.raises(ValueError, match="split 'test' of .* is empty"):
        dm.test_dataloader()


# ------------------------------------------------------------------ 1b: gen-data refuses too few instances
def test_min_per_category():
    assert min_per_category([0.7, 0.15, 0.15]) == 3
    assert min_per_category([0.5, 0.5, 0.0]) == 2
    assert min_per_category([1.0, 0.0, 0.0]) == 1


@pytest.mark.parametrize("kind", ["crossmodal", "reconstruction"])
def test_gen_data_refuses_too_few_per_category(kind, tmp_path, capsys):
    out = tmp_path / "cm"
    err = _error(capsys, ["gen-data", kind, "--out", str(out), "--per-category", "2", "--categories",
                          "wineglass,mug", "--views", "2", "--tactile-clouds", "2"])
    assert err.startswith("vtlearn: error: --per-category: 2 instance(s) per category leave split 'test'")
    assert "need at least 3" in err
    assert not out.exists()  # refused before anything was written
    err = _error(capsys, ["gen-data", kind, "--out", str(out), "--per-category", "1",
                          "--splits", "0.5,0.5,0"])
    assert "--per-category: 1 instance(s) per category leave split 'val'" in err and "at least 2" in err
    with pytest.raises(ValueError, match="per_category: 2 instance"):
        generate_dataset(GenConfig(kind=kind, categories=["mug"], per_category=2), out, progress=False)
    assert not out.exists()


def test_gen_data_errors_name_the_flag(tmp_path, capsys):
    err = _error(capsys, ["gen-data", "reconstruction", "--out", str(tmp_path / "x"),
                          "--categories", "bogus"])
    assert err.startswith("vtlearn: error: --categories: ")
    (tmp_path / "f").write_text("x")
    err = _error(capsys, ["gen-data", "reconstruction", "--out", str(tmp_path / "f")])
    assert err.startswith("vtlearn: error: --out: ")


def test_gen_data_tactile_points_errors_name_the_flag(tmp_path, capsys):
    out = tmp_path / "cm"
    err = _error(capsys, ["gen-data", "crossmodal", "--out", str(out), "--tactile-points", "80", "30"])
    assert err.startswith("vtlearn: error: --tactile-points: need 1 <= min <= max, got 80, 30")
    with pytest.raises(SystemExit) as exc:  # refused by argparse, before the config is built
        main(["gen-data", "crossmodal", "--out", str(out), "--tactile-points", "0", "30"])
    assert exc.value.code == 2
    assert "argument --tactile-points: must be >= 1, got 0" in capsys.readouterr().err
    assert not out.exists()


# ------------------------------------------------------------------ 2: a dataset of another kind
@pytest.fixture(scope="module")
def episodes(recon_dir, tmp_path_factory):
    """A dataset whose manifest says `gen-episodes` made it (no dense clouds)."""
    return _copy(recon_dir, tmp_path_factory.mktemp("ep") / "ep", lambda m: {**m, "kind": "tactile-episodes"})


def test_commands_refuse_a_dataset_of_another_kind(episodes, actor_ckpt, tmp_path, capsys):
    for argv in (["reconstruct", "--ckpt", actor_ckpt, "--data", str(episodes), "--split", "train", "--out",
                  str(tmp_path / "d.ply")],
                 ["bench", "actor", "--ckpt", actor_ckpt, "--data", str(episodes), "--split", "train",
                  "--json", str(tmp_path / "a.json")]):
        err = _error(capsys, argv)
        assert "--data: " in err
        assert "is a 'tactile-episodes' dataset, need 'reconstruction' or 'crossmodal'" in err
        assert "`vtlearn gen-episodes`" in err
    with pytest.raises(ValueError, match="data_dir: .* 'tactile-episodes' dataset, need 'reconstruction'"):
        load_split(episodes, "train", kind="reconstruction")
    assert check_kind(load_manifest(episodes), episodes, "tactile-episodes") == "tactile-episodes"


# ------------------------------------------------------------------ 3: checkpoints checked up front
def test_bench_actor_checks_checkpoints_before_the_benchmark(recon_dir, actor_ckpt, tmp_path, capsys):
    base = ["bench", "actor", "--ckpt", actor_ckpt, "--data", str(recon_dir),
            "--json", str(tmp_path / "a.json")]
    err = _error(capsys, [*base, "--recognition-ckpt", actor_ckpt])
    assert err.startswith("vtlearn: error: --recognition-ckpt: ") and "not an ACTORRecognition" in err
    err = _error(capsys, [*base, "--ckpt-noattn", actor_ckpt])
    assert err.startswith("vtlearn: error: --ckpt-noattn: ") and "attention: true" in err
    err = _error(capsys, [*base[:3], str(tmp_path / "nope.ckpt"), *base[4:]])
    assert err.startswith("vtlearn: error: --ckpt: ")
    assert not (tmp_path / "a.json").exists()


# ------------------------------------------------------------------ 4: output paths
def test_reconstruct_checks_output_paths_first(recon_dir, actor_ckpt, tmp_path, capsys):
    base = ["reconstruct", "--ckpt", actor_ckpt, "--data", str(recon_dir)]
    err = _error(capsys, [*base, "--out", str(tmp_path)])
    assert err.startswith("vtlearn: error: --out: ") and "is a folder" in err
    err = _error(capsys, [*base, "--out", str(tmp_path / "dense")])
    assert err.startswith("vtlearn: error: --out: unsupported dense cloud file without a suffix")
    dense = tmp_path / "dense.ply"
    err = _error(capsys, [*base, "--out", str(dense), "--mesh", str(tmp_path / "m.xyz")])
    assert err.startswith("vtlearn: error: --mesh: unsupported mesh format '.xyz'")
    err = _error(capsys, [*base, "--out", str(dense), "--figure", str(tmp_path / "f.xyz")])
    assert err.startswith("vtlearn: error: --figure: unsupported figure format '.xyz'")
    err = _error(capsys, [*base, "--out", str(dense), "--gt", str(tmp_path / "nope.ply")])
    assert err.startswith("vtlearn: error: --gt: ")
    assert not dense.exists()  # nothing written by any refused run


def test_reconstruct_names_input_for_a_missing_or_bad_file(actor_ckpt, tmp_path, capsys):
    """`reconstruct --input nope.ply` said `nope.ply: no such file` without the flag."""
    base = ["reconstruct", "--ckpt", actor_ckpt, "--out", str(tmp_path / "dense.ply")]
    err = _error(capsys, [*base, "--input", str(tmp_path / "nope.ply")])
    assert err == f"vtlearn: error: --input: no such file: {tmp_path / 'nope.ply'}\n"
    err = _error(capsys, [*base, "--input", str(tmp_path)])
    assert err.startswith("vtlearn: error: --input: ") and "not a regular file" in err
    (tmp_path / "bad.xyz").write_text("1 2\nnot numbers\n")
    err = _error(capsys, [*base, "--input", str(tmp_path / "bad.xyz")])
    assert err.startswith("vtlearn: error: --input: ")
    assert not (tmp_path / "dense.ply").exists()


def test_bench_actor_checks_markdown_first(recon_dir, actor_ckpt, tmp_path, capsys):
    err = _error(capsys, ["bench", "actor", "--ckpt", actor_ckpt, "--data", str(recon_dir), "--markdown",
                          str(tmp_path), "--json", str(tmp_path / "a.json")])
    assert err.startswith("vtlearn: error: --markdown: ") and "is a folder" in err
    assert not (tmp_path / "a.json").exists()


# ------------------------------------------------------------------ 5: the input point range
@pytest.mark.parametrize("flags", [["--min-points", "500"], ["--max-points", "5"]])
def test_bench_actor_checks_the_point_range(flags, recon_dir, actor_ckpt, tmp_path, capsys):
    err = _error(capsys, ["bench", "actor", "--ckpt", actor_ckpt, "--data", str(recon_dir), *flags, "--json",
                          str(tmp_path / "a.json")])
    assert err.startswith("vtlearn: error: --min-points/--max-points: need --min-points <= --max-points")


def test_gen_episodes_refuses_an_empty_source_split(cross_dir, tmp_path, capsys):
    """An empty split of the source gave an empty episode set, exit 0."""
    import json
    import shutil

    from vtlearn.cli import main

    src = tmp_path / "src"
    shutil.copytree(cross_dir, src)
    manifest = json.loads((src / "manifest.json").read_text())
    manifest["shards"] = [m for m in manifest["shards"] if m["split"] != "test"]
    (src / "manifest.json").write_text(json.dumps(manifest))
    assert main(["gen-episodes", "--source", str(src), "--split", "test", "--out", str(tmp_path / "ep")]) == 2
    assert f"error: --source: split 'test' of {src} is empty" in capsys.readouterr().err
    assert not (tmp_path / "ep").exists()


@pytest.mark.parametrize("flags, message", [
    (["--strategies", "active,nope"], "--strategies: expected a non-empty list of"),
    (["--strategies", "random,random"], "--strategies: repeated names"),
    (["--gain-mode", "exact"], "--gain-mode: expected 'raycast' or 'probabilistic'"),
    (["--touches", "3", "--prefixes", "2,5"], "--prefixes: need values in [1, touches=3]"),
    (["--candidates", "1"], "--candidates: "),
    (["--split", "val2"], "--split: expected one of"),
])
def test_gen_episodes_errors_name_the_flag(flags, message, cross_dir, tmp_path, capsys):
    """The errors named EpisodeDataConfig's fields (`strategies`, `n_candidates`), not the flags typed."""
    err = _error(capsys, ["gen-episodes", "--source", str(cross_dir), "--out", str(tmp_path / "ep"), *flags])
    assert err.startswith(f"vtlearn: error: {message}"), err
    assert not (tmp_path / "ep").exists()


def test_gen_episodes_refusal_to_resume_names_the_flags(cross_dir, tmp_path, capsys):
    """A folder of episodes made with other settings is refused naming the flags that differ (it named
    EpisodeDataConfig's fields, ``n_candidates`` for ``--candidates``)."""
    from dataclasses import asdict

    from vtlearn.active.episode_data import EpisodeDataConfig

    out = tmp_path / "ep"
    out.mkdir()
    folder = asdict(EpisodeDataConfig(source=str(cross_dir), touches=8, prefixes=[4], n_candidates=32))
    (out / "config.json").write_text(json.dumps(folder))
    err = _error(capsys, ["gen-episodes", "--source", str(cross_dir), "--out", str(out), "--touches", "8",
                          "--prefixes", "4", "--candidates", "16"])
    assert err.startswith(f"vtlearn: error: --out: {out} holds a set of episodes made with another config "
                          "(--candidates: 32 in the folder, 16 asked); use a new directory"), err
    assert sorted(p.name for p in out.iterdir()) == ["config.json"]


def test_gen_data_mesh_folder_errors_name_the_flag_once(tmp_path, capsys):
    """A missing folder, a folder without meshes, a category it lacks and an empty category folder each
    give one line naming the flag; without --categories every category of the folder is taken."""
    import trimesh

    err = _error(capsys, ["gen-data", "reconstruction", "--out", str(tmp_path / "o"), "--meshes",
                          str(tmp_path / "nope")])
    assert err.startswith("vtlearn: error: --meshes: no such mesh directory")
    (tmp_path / "m" / "empty" / "train").mkdir(parents=True)
    err = _error(capsys, ["gen-data", "reconstruction", "--out", str(tmp_path / "o"), "--meshes",
                          str(tmp_path / "m")])
    assert err.startswith("vtlearn: error: --meshes: no meshes found in") and "spec" not in err
    (tmp_path / "m" / "box" / "train").mkdir(parents=True)
    for i in range(3):
        trimesh.creation.box(extents=(1, 2, 3 + i)).export(tmp_path / "m" / "box" / "train" / f"box_{i}.off")
    for cats in ("box,empty", "box,mug"):
        err = _error(capsys, ["gen-data", "reconstruction", "--out", str(tmp_path / "o"), "--meshes",
                              str(tmp_path / "m"), "--categories", cats])
        assert err.startswith(f"vtlearn: error: --categories: no meshes of ['{cats[4:]}']")
        assert "(it has: box)" in err
    assert not (tmp_path / "o").exists()
    assert main(["gen-data", "reconstruction", "--out", str(tmp_path / "o"), "--meshes", str(tmp_path / "m"),
                 "--per-category", "3", "--touches", "4", "--pinches", "1"]) == 0
    assert load_manifest(tmp_path / "o")["class_names"] == ["box"]
