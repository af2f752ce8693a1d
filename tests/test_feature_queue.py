"""The detached feature queue behind ``XAVTNet(da_memory=...)`` and its gradient scaling."""

import pytest
import torch

from vtlearn.models.components.feature_queue import FeatureQueue, scale_grad


def _feats(rows, start):
    """(rows, 2) and (rows, 1) features whose first column counts start, start + 1, ..."""
    col = torch.arange(start, start + rows, dtype=torch.float32)[:, None]
    return {"fc1": torch.cat([col, -col], 1), "fc2": col.clone()}


def test_queue_keeps_the_newest_rows_first_up_to_capacity():
    q = FeatureQueue(5)
    assert len(q) == 0
    first = _feats(3, 0)
    assert q.extend(first)["fc1"] is first["fc1"]  # empty queue: the batch alone
    q.push(first)  # rows 0 1 2
    q.push(_feats(3, 10))  # rows 10 11 12, then 0 1 (2 dropped: oldest beyond capacity)
    assert len(q) == 5
    out = q.extend(_feats(2, 20))
    assert out["fc1"][:, 0].tolist() == [20, 21, 10, 11, 12, 0, 1]
    assert out["fc2"][:, 0].tolist() == [20, 21, 10, 11, 12, 0, 1]
    q.push(_feats(7, 30))  # a batch larger than the queue keeps its first `capacity` rows
    assert q.extend(_feats(1, 0))["fc2"][1:, 0].tolist() == [30, 31, 32, 33, 34]
    q.clear()
    assert len(q) == 0


def test_queued_rows_carry_no_gradient_and_current_rows_keep_theirs():
    q = FeatureQueue(4)
    old = {"fc1": torch.randn(2, 3, requires_grad=True)}
    q.push(old)
    new = {"fc1": torch.randn(2, 3, requires_grad=True)}
    both = q.extend(new)["fc1"]
    both.sum().backward()
    assert old["fc1"].grad is None
    assert torch.equal(new["fc1"].grad, torch.ones(2, 3))
    old["fc1"].data.add_(1.0)  # the queue holds a copy, not a view of the pushed tensor
    assert not torch.equal(q.extend(new)["fc1"][2:], old["fc1"].detach())


def test_queue_rejects_inconsistent_features():
    with pytest.raises(ValueError, match="capacity"):
        FeatureQueue(0)
    q = FeatureQueue(3)
    with pytest.raises(ValueError, match="features"):
        q.push({})
    with pytest.raises(ValueError, match="one b for every layer"):
        q.push({"fc1": torch.zeros(2, 3), "fc2": torch.zeros(3, 3)})
    with pytest.raises(ValueError, match=r"\(b, d\)"):
        q.push({"fc1": torch.zeros(2)})
    q.push({"fc1": torch.zeros(2, 3)})
    with pytest.raises(ValueError, match="layers"):
        q.extend({"fc2": torch.zeros(2, 3)})
    with pytest.raises(ValueError, match="width 4"):
        q.extend({"fc1": torch.zeros(2, 4)})


def test_scale_grad_keeps_the_value_and_scales_the_gradient():
    x = torch.tensor([1.0, -2.0, 3.0], requires_grad=True)
    y = scale_grad(x, 4.0)
    assert torch.equal(y, x.detach())
    (y * torch.tensor([1.0, 2.0, 3.0])).sum().backward()
    assert x.grad.tolist() == [4.0, 8.0, 12.0]
    assert scale_grad(x, 1.0) is x
    for bad in (0.0, -1.0, float("inf"), float("nan")):
        with pytest.raises(ValueError, match="scale"):
            scale_grad(x, bad)
    with pytest.raises(ValueError, match="x must be"):
        scale_grad([1.0], 2.0)
