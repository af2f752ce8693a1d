"""Output paths of the CLI: a folder where a file goes (or the reverse) is refused with the flag's name before
the command runs, not with an OSError traceback after a long bench."""

import pytest

from vtlearn.bench_utils import save_figure, write_json
from vtlearn.cli import main
from vtlearn.pipeline import run_quickstart


@pytest.fixture
def paths(tmp_path):
    (tmp_path / "adir").mkdir()
    (tmp_path / "afile").write_text("x")
    return tmp_path


@pytest.mark.parametrize("argv, message", [
    (["bench", "articulation", "--trials", "1", "--json", "{d}/adir"],
     "--json: {d}/adir is a folder; give a file name for the JSON inside it"),
    (["bench", "articulation", "--trials", "1", "--json", "{d}/afile/x.json"],
     "--json: cannot write the JSON to {d}/afile/x.json, {d}/afile is a file, not a folder"),
    (["bench", "pushing", "--trials", "1", "--figure", "{d}/adir"],
     "--figure: {d}/adir is a folder; give a file name for the figure inside it"),
    (["bench", "tracking", "--trials", "1", "--plots", "{d}/afile"],
     "--plots: {d}/afile is a file; need a folder for the plots"),
    # a format matplotlib cannot write: the bench ran to its end, then failed, and wrote no JSON
    (["bench", "declutter", "--scenes", "1", "--json", "{d}/d.json", "--figure", "{d}/d.txt"],
     "--figure: unsupported figure format '.txt' ({d}/d.txt); expected one of "),
    (["bench", "articulation", "--trials", "1", "--figure", "{d}/a"],
     "--figure: unsupported figure file without a suffix ({d}/a); expected one of "),
    (["bench", "active-learning", "--plot", "{d}/p.csv"],
     "--plot: unsupported figure format '.csv' ({d}/p.csv); expected one of "),
])
def test_output_flag_of_the_wrong_kind_is_refused_before_the_run(paths, capsys, argv, message):
    argv = [a.format(d=paths) for a in argv]
    assert main(argv) == 2
    captured = capsys.readouterr()
    expected = "vtlearn: error: " + message.format(d=paths)
    if expected.endswith("expected one of "):
        assert captured.err.strip().startswith(expected) and ".png" in captured.err
    else:
        assert captured.err.strip() == expected
    assert "###" not in captured.out  # refused before any trial ran
    assert not (paths / "d.json").exists()


def test_results_are_written_before_their_figure(paths):
    """A figure that fails leaves the bench's JSON on disk (the figure was drawn first, and its failure lost
    the results); the JSON names the figure once it is written."""
    import json

    from vtlearn.bench_utils import write_json_and_figure

    def broken(result, path):
        raise RuntimeError("no display")

    with pytest.raises(RuntimeError, match="no display"):
        write_json_and_figure(paths / "r.json", {"rows": [1, 2]}, paths / "r.png", broken)
    assert json.loads((paths / "r.json").read_text()) == {"rows": [1, 2]}

    def draw(result, path):
        path.write_bytes(b"png")

    write_json_and_figure(paths / "s.json", {"rows": [3]}, paths / "s.png", draw)
    assert json.loads((paths / "s.json").read_text()) == {"rows": [3], "figure": str(paths / "s.png")}


def test_writers_refuse_a_folder_and_write_a_file(paths):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with pytest.raises(ValueError, match="path: .*adir is a folder; give a file name for the JSON"):
        write_json(paths / "adir", {"a": 1})
    with pytest.raises(ValueError, match="path: .*afile is a file, not a folder"):
        save_figure(plt.figure(), paths / "afile" / "f.png")
    assert write_json(paths / "new" / "x.json", {"a": 1}).read_text().strip().startswith("{")


def test_quickstart_out_must_be_a_folder(paths, capsys):
    with pytest.raises(ValueError, match="out: .*afile is a file; the quickstart needs a folder"):
        run_quickstart(paths / "afile")
    assert main(["quickstart", "--tiny", "--out", str(paths / "afile")]) == 2
    assert "out: " in capsys.readouterr().err


def test_a_file_system_error_is_one_line(paths, capsys):
    (paths / "c.xyz").write_text("0 0 0\n1 0 0\n0 1 0\n0 0 1\n")
    assert main(["convert", str(paths / "c.xyz"), str(paths / "afile" / "x.ply")]) == 2
    assert capsys.readouterr().err.strip() == f"vtlearn: error: cannot use {paths / 'afile'}: file exists"
