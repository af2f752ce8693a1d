"""PointDAN (Qin et al. 2019) beside VTLoss: the self-adaptive nodes, their node attention and the local
alignment's MMD, and the XAVTNet rows that use them."""

import os
import sys
from pathlib import Path

import lightning as L
import pytest
import torch

from vtlearn.losses.mmd import mk_mmd
from vtlearn.losses.pointdan import POINTDAN_BANDWIDTHS, node_alignment_loss
from vtlearn.models.components.pointnet_tnet import lengths_to_mask
from vtlearn.models.components.sa_nodes import NodeAttention, SelfAdaptiveNodes, farthest_point_indices
from vtlearn.models.xavtnet import XAVTNet

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_xavtnet import TINY, TinyCrossModalDM  # noqa: E402

os.environ.setdefault("WANDB_MODE", "disabled")

CUBE = torch.tensor([[x, y, z] for x in (-1.0, 1.0) for y in (-1.0, 1.0) for z in (-1.0, 1.0)])


def test_farthest_point_sampling_picks_the_cube_corners_before_any_inner_point():
    """Corners, then face centres and the centre: eight picks are exactly the eight corners, started from
    the first point; padded points are never picked and a short cloud repeats its own points."""
    inner = torch.tensor([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [0.0, -0.5, 0.2], [0.3, 0.3, 0.3]])
    cloud = torch.cat([CUBE[:1], inner, CUBE[1:]])  # a corner first, the inner points among the corners
    picks = farthest_point_indices(cloud[None], torch.ones(1, 12, dtype=torch.bool), 8)[0]
    assert picks[0] == 0 and picks[1] == 11  # the corner opposite the first
    assert sorted(picks.tolist()) == [0, *range(5, 12)]
    padded = torch.cat([cloud[:3], torch.full((5, 3), 100.0)])[None]  # padding far away
    short = farthest_point_indices(padded, lengths_to_mask(torch.tensor([3]), 8), 6)[0]
    assert short.max() < 3 and set(short.tolist()) == {0, 1, 2}


def _sa(**kwargs):
    torch.manual_seed(0)
    return SelfAdaptiveNodes(channels=8, node_dim=5, **{"num_nodes": 6, "group_size": 10, **kwargs}).eval()


@pytest.mark.parametrize("feature_ball", [False, True])
def test_self_adaptive_nodes_do_not_depend_on_padding(feature_ball):
    """Each cloud of a padded batch gets the nodes, offsets and per-point features it gets alone (evaluation
    mode: batch norm with running statistics), clouds shorter than the node count and group size included;
    the ball spans most of the cloud, so every group's offset has members besides its node."""
    sa = _sa(radius=1.0, feature_ball=feature_ball)
    torch.manual_seed(1)
    lengths = torch.tensor([30, 4, 7])
    xyz, feats = torch.randn(3, 30, 3), torch.randn(3, 30, 8)
    mask = lengths_to_mask(lengths, 30)
    xyz[~mask], feats[~mask] = 7.0, -3.0  # garbage in the padding
    out, nodes, offsets = sa(feats, xyz, mask)
    assert out.shape == (3, 30, 13) and nodes.shape == (3, 6, 5) and offsets.shape == (3, 6, 3)
    assert torch.all(out[~mask] == 0)
    for b, n in enumerate(lengths.tolist()):
        alone = sa(feats[b:b + 1, :n], xyz[b:b + 1, :n], torch.ones(1, n, dtype=torch.bool))
        torch.testing.assert_close(alone[0][0], out[b, :n])
        torch.testing.assert_close(alone[1][0], nodes[b])
        torch.testing.assert_close(alone[2][0], offsets[b])


def test_node_offsets_stay_inside_the_group_ball_and_vanish_without_offset_weights():
    """Step 3's offset averages tanh(·) ∈ (−1, 1) times each member's displacement, so it is shorter than the
    ball's radius (0.3 of the cloud's radius); with W = 0 the nodes stay on their sampled points, and a node's
    feature is the max of the residual features over its k nearest points."""
    sa = _sa(radius=0.3)
    torch.manual_seed(2)
    xyz, feats = torch.randn(2, 40, 3), torch.randn(2, 40, 8) * 5
    mask = torch.ones(2, 40, dtype=torch.bool)
    _, _, offsets = sa(feats, xyz, mask)
    radius = 0.3 * (xyz - xyz.mean(1, keepdim=True)).norm(dim=-1).amax(1)
    assert offsets.abs().sum() > 0
    assert torch.all(offsets.norm(dim=-1) <= radius[:, None] + 1e-6)
    with torch.no_grad():
        sa.offset.weight.zero_()
    out, nodes, offsets = sa(feats, xyz, mask)
    assert torch.all(offsets == 0)
    picks = farthest_point_indices(xyz, mask, 6)
    residual = sa.residual(feats, mask)
    for b in range(2):
        for m in range(6):
            near = (xyz[b] - xyz[b, picks[b, m]]).norm(dim=-1).topk(10, largest=False).indices
            torch.testing.assert_close(nodes[b, m], residual[b, near].amax(0))
        # a point on a node reads that node's feature (its 1/d² weight dominates the other two)
        torch.testing.assert_close(out[b, picks[b, 0], 8:], nodes[b, 0], atol=1e-5, rtol=1e-5)
        torch.testing.assert_close(out[b, :, :8], feats[b])


def test_feature_ball_makes_a_sparse_clouds_nodes_local():
    """A cloud with no more points than the group size: PointDAN's nodes (max over the k nearest points) all
    read the whole cloud's maximum, the same feature; with ``feature_ball`` each node reads the max over the
    points within the ball of its (unmoved, W = 0) place only, which differ from node to node. On a cloud
    whose ball holds every point the two agree."""
    torch.manual_seed(4)
    xyz, feats = torch.randn(1, 10, 3), torch.randn(1, 10, 8) * 5
    mask = torch.ones(1, 10, dtype=torch.bool)
    plain, ball = _sa(radius=0.3), _sa(radius=0.3, feature_ball=True)
    with torch.no_grad():
        plain.offset.weight.zero_()
        ball.offset.weight.zero_()
    residual = plain.residual(feats, mask)[0]
    _, nodes, _ = plain(feats, xyz, mask)
    torch.testing.assert_close(nodes[0], residual.amax(0).expand(6, -1))
    _, local, _ = ball(feats, xyz, mask)
    picks = farthest_point_indices(xyz, mask, 6)[0]
    radius = 0.3 * (xyz[0] - xyz[0].mean(0)).norm(dim=-1).max()
    for m in range(6):
        inside = (xyz[0] - xyz[0, picks[m]]).norm(dim=-1) <= radius  # the node itself is always inside
        torch.testing.assert_close(local[0, m], residual[inside].amax(0))
    assert not torch.allclose(local[0], local[0, :1].expand(6, -1))
    wide = _sa(radius=10.0, feature_ball=True)  # every point within 10 cloud radii of every moved node
    torch.testing.assert_close(wide(feats, xyz, mask)[1], _sa(radius=10.0)(feats, xyz, mask)[1])


def test_the_offsets_learn_through_the_interpolation():
    """The nodes' new places enter the output through the interpolation weights only: a loss on the
    per-point output reaches W, a loss on the node features alone does not (PointDAN's too)."""
    sa = _sa().train()
    torch.manual_seed(3)
    xyz, feats = torch.randn(2, 40, 3), torch.randn(2, 40, 8)
    out, nodes, _ = sa(feats, xyz, torch.ones(2, 40, dtype=torch.bool))
    out.pow(2).sum().backward(retain_graph=True)
    assert sa.offset.weight.grad.abs().sum() > 0
    sa.zero_grad()
    nodes.sum().backward()
    assert sa.offset.weight.grad is None or torch.all(sa.offset.weight.grad == 0)


def test_bad_node_inputs_are_value_errors():
    sa = _sa()
    with pytest.raises(ValueError, match="features, xyz, mask"):
        sa(torch.randn(2, 10, 7), torch.randn(2, 10, 3), torch.ones(2, 10, dtype=torch.bool))
    with pytest.raises(ValueError, match="radius"):
        SelfAdaptiveNodes(radius=0.0)
    with pytest.raises(ValueError, match="nodes"):
        NodeAttention(4, 5)(torch.randn(3, 5, 4))
    with pytest.raises(ValueError, match="feature_ball"):
        SelfAdaptiveNodes(feature_ball="yes")
    with pytest.raises(ValueError, match="sa_feature_ball"):
        XAVTNet(**{**TINY, "sa_nodes": 4, "sa_feature_ball": 1})


def test_node_alignment_is_zero_for_one_sample_and_grows_with_a_shift():
    """With the two domains' attention alike, the same node sample gives exactly 0; a shift of the target's
    nodes that batch norm cannot undo (a change of their spread in half the channels) gives more, and the
    value is MK-MMD² of the attended samples with PointDAN's h = 2σ²."""
    torch.manual_seed(4)
    att_s, att_t = NodeAttention(4, 3), NodeAttention(4, 3)
    att_t.load_state_dict(att_s.state_dict())
    nodes = torch.randn(16, 4, 3)
    assert node_alignment_loss(nodes, nodes, att_s, att_t) == 0
    spread = nodes.clone()
    spread[..., :2] = spread[..., :2] ** 3
    value = node_alignment_loss(nodes, spread, att_s, att_t)
    assert value > 1e-3
    expected = mk_mmd(att_s(nodes), att_t(spread), bandwidths=POINTDAN_BANDWIDTHS)
    torch.testing.assert_close(value, expected)
    assert POINTDAN_BANDWIDTHS == pytest.approx((2e-4, 2e-2, 2.0, 200.0, 2e4))
    with pytest.raises(ValueError, match="nodes_source"):
        node_alignment_loss(nodes[:1], nodes, att_s, att_t)
    with pytest.raises(ValueError, match="nodes_target"):
        node_alignment_loss(nodes, nodes[:, :3], att_s, att_t)


def test_pointdan_rows_train_log_their_terms_and_round_trip(tmp_path):
    """The pointdan row trains (fast_dev_run) with MCD's and the nodes' terms logged, the local alignment
    needs the nodes, and a checkpoint restores the nodes and attention with weights_only=True."""
    with pytest.raises(ValueError, match="node_mmd_weight"):
        XAVTNet(**TINY, node_mmd_weight=1.0)
    torch.manual_seed(0)
    model = XAVTNet(**TINY, da_method="none", mcd_weight=10.0, sa_nodes=4, sa_group=6, node_mmd_weight=50.0,
                    max_points=30)
    trainer = L.Trainer(fast_dev_run=1, accelerator="cpu", logger=False, enable_progress_bar=False,
                        enable_model_summary=False, default_root_dir=tmp_path)
    trainer.fit(model, datamodule=TinyCrossModalDM())
    logged = {k.removeprefix("train/") for k in trainer.logged_metrics if k.startswith("train/")}
    assert {"mcd", "ce_f2", "node_mmd"} <= logged
    path = tmp_path / "pointdan.ckpt"
    trainer.save_checkpoint(path)
    again = XAVTNet.load_from_checkpoint(path, map_location="cpu", weights_only=True).eval()
    assert again.encoder.sa is not None and again.node_attention is not None
    model.eval()
    x = torch.randn(2, 12, 3)
    assert torch.equal(again(x).logits, model(x).logits)
    assert again(x).nodes.shape == (2, 4, 64)
