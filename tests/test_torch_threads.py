"""Commands that set torch's thread count for themselves (``--threads``, the quickstart) give the Python
caller its own back (vtlearn.torch_threads)."""

import pytest
import torch

from vtlearn.cli import main
from vtlearn.torch_threads import keep_torch_threads


@pytest.fixture
def other_threads():
    """A thread count other than the session's, set for the test and undone after it."""
    before = torch.get_num_threads()
    mine = 3 if before != 3 else 2
    torch.set_num_threads(mine)
    yield mine
    torch.set_num_threads(before)


def test_keep_torch_threads_restores_after_a_set_and_after_an_error(other_threads):
    with keep_torch_threads():
        torch.set_num_threads(1)
        assert torch.get_num_threads() == 1
    assert torch.get_num_threads() == other_threads
    with pytest.raises(RuntimeError, match="inside"), keep_torch_threads():
        torch.set_num_threads(1)
        raise RuntimeError("inside")
    assert torch.get_num_threads() == other_threads


def test_a_command_with_threads_gives_the_caller_its_count_back(other_threads, tmp_path, capsys):
    """``recognize --threads 1`` sets the count before it refuses the missing inputs; ``main`` puts the
    caller's back (it used to stay at 1)."""
    assert main(["recognize", "--ckpt", str(tmp_path / "none.ckpt"), "--threads", "1"]) == 2
    assert "inputs: give cloud files, or --data DIR" in capsys.readouterr().err
    assert torch.get_num_threads() == other_threads


def test_quickstart_gives_the_caller_its_count_back(other_threads, tmp_path):
    """run_quickstart runs on min(2, cores) threads and leaves the caller's count as it was (its data step is
    the cheapest that passes the set)."""
    from vtlearn.pipeline import run_quickstart, tiny_quickstart_config

    run_quickstart(tmp_path / "qs", tiny_quickstart_config(), stop_after="data")
    assert torch.get_num_threads() == other_threads
