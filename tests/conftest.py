import os

import pytest

# Tests never talk to wandb and never compete for more than the machine's cores.
os.environ["WANDB_MODE"] = "disabled"
os.environ.setdefault("OMP_NUM_THREADS", "2")


@pytest.fixture(scope="module")
def recon_dir(tmp_path_factory):
    """A tiny reconstruction dataset (vtlearn.sim_data.fixtures), one per test module."""
    from vtlearn.sim_data.fixtures import make_tiny_dataset

    return make_tiny_dataset("reconstruction", tmp_path_factory.mktemp("recon"))


@pytest.fixture(scope="module")
def cross_dir(tmp_path_factory):
    """A tiny crossmodal dataset (vtlearn.sim_data.fixtures), one per test module."""
    from vtlearn.sim_data.fixtures import make_tiny_dataset

    return make_tiny_dataset("crossmodal", tmp_path_factory.mktemp("cross"))
