"""The scalar checks of the public API go through ``vtlearn.validation.as_real`` / ``as_int``: a string in
place of a number is a ``ValueError`` that names the argument, not a numpy ``TypeError`` from a comparison."""

import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree

from vtlearn.active.actions import (
    OrientedBox,
    ReachFeasibility,
    sample_pinch_actions,
    sample_touch_actions,
    sample_view_actions,
)
from vtlearn.active.exploration import simulate_touch
from vtlearn.active.mc_dropout import select_power
from vtlearn.active.occupancy import OccupancyGrid
from vtlearn.active.reconstruction_nbt import ExpectedBoxFitGain, box_fit_error, predict_tactile_contacts
from vtlearn.active.selection import EnergyCosts, cloud_top_down_box, detect_transparent
from vtlearn.active.sensors import PinchSensor, TactileArray, ToFCamera
from vtlearn.classical.artreg import ArtRegTracker
from vtlearn.classical.correspondences import TangentPlanes
from vtlearn.classical.stiqf import STIQF, DistanceField, best_buddy_pairs
from vtlearn.classical.tiqf import TIQF
from vtlearn.classical.ukf import sigma_weights
from vtlearn.geometry.sampling import voxel_downsample
from vtlearn.geometry.transforms import canonical_box
from vtlearn.losses.contrastive import nt_xent
from vtlearn.losses.dann import dann_lambda, grad_reverse
from vtlearn.losses.mmd import gaussian_bandwidths
from vtlearn.models.components.class_balance import sinkhorn_balance
from vtlearn.models.components.feature_queue import FeatureQueue
from vtlearn.models.components.mean_teacher import perturb_padded, sigmoid_rampup
from vtlearn.models.gpis import fit_gpis
from vtlearn.models.xavtnet import XAVTNet
from vtlearn.runtime.articulation import classify_relative_motion
from vtlearn.runtime.declutter import edge_weight
from vtlearn.runtime.pushing import PushPID
from vtlearn.sim_data.articulated import look_at_45
from vtlearn.sim_data.camera import RGBDCamera, sample_hemisphere_views
from vtlearn.sim_data.cloud_touch import touch_cloud
from vtlearn.sim_data.tactile import TactileConfig
from vtlearn.sim_data.writer import crop_to_box
from vtlearn.validation import as_real

CLOUD = np.random.default_rng(0).normal(size=(20, 3)) * 0.05
BOX = OrientedBox(np.eye(4), [0.05, 0.05, 0.1])
RNG = np.random.default_rng(0)
ONE_RAY = dict(points=CLOUD, origins=np.zeros((1, 3)), directions=[[0.0, 0.0, 1.0]], max_range=[0.1],
               pad_index=np.array([0]))

# (call with a string where the named argument wants a number, that argument's name)
CASES = {
    "OccupancyGrid.resolution": (lambda: OccupancyGrid([0, 0, 0], "a", (4, 4, 4)), "resolution"),
    "ToFCamera.max_range": (lambda: ToFCamera(max_range="a"), "max_range"),
    "TactileArray.ray_length": (lambda: TactileArray(ray_length="a"), "ray_length"),
    "PinchSensor.opening": (lambda: PinchSensor(opening="a"), "opening"),
    "sample_touch_actions.standoff": (lambda: sample_touch_actions(BOX, 4, standoff="a"), "standoff"),
    "sample_pinch_actions.approach_height": (
        lambda: sample_pinch_actions(BOX, 4, approach_height="a"), "approach_height"),
    "sample_view_actions.radius": (lambda: sample_view_actions([0, 0, 0], "a", 4), "radius"),
    "simulate_touch.compliance": (lambda: simulate_touch(None, None, compliance="a"), "compliance"),
    "select_power.beta": (lambda: select_power(torch.ones(5), 2, "a"), "beta"),
    "predict_tactile_contacts.radius": (
        lambda: predict_tactile_contacts(**ONE_RAY, radius="a", stop_depth=0.0), "radius"),
    "predict_tactile_contacts.stop_depth": (
        lambda: predict_tactile_contacts(**ONE_RAY, radius=0.01, stop_depth="a"), "stop_depth"),
    "ExpectedBoxFitGain.contact_tolerance": (
        lambda: ExpectedBoxFitGain(None, contact_tolerance="a"), "contact_tolerance"),
    "EnergyCosts.opaque": (lambda: EnergyCosts(opaque=(("view", "a"),)), "opaque"),
    "cloud_top_down_box.plane_distance": (lambda: cloud_top_down_box(CLOUD, plane_distance="a"),
                                          "plane_distance"),
    "ArtRegTracker.visual_std": (lambda: ArtRegTracker([CLOUD], [np.eye(4)], visual_std="a"), "visual_std"),
    "best_buddy_pairs.normal_angle_deg": (lambda: best_buddy_pairs(CLOUD, CLOUD, normal_angle_deg="a"),
                                          "normal_angle_deg"),
    "DistanceField.pad": (lambda: DistanceField(CLOUD, pad="a"), "pad"),
    "sigma_weights.alpha": (lambda: sigma_weights(6, alpha="a"), "alpha"),
    "sigma_weights.kappa": (lambda: sigma_weights(6, kappa="a"), "kappa"),
    "canonical_box.extent_m": (lambda: canonical_box(CLOUD, extent_m="a"), "extent_m"),
    "nt_xent.temperature": (
        lambda: nt_xent(torch.ones(3, 4), torch.ones(3, 4), temperature="a"), "temperature"),
    "grad_reverse.lambd": (lambda: grad_reverse(torch.ones(2), lambd="a"), "lambd"),
    "perturb_padded.jitter": (
        lambda: perturb_padded(torch.zeros(1, 4, 3), torch.tensor([4]), 1.0, "a"), "jitter"),
    "XAVTNet.mix_alpha": (lambda: XAVTNet(num_classes=3, mix_alpha="a"), "mix_alpha"),
    "XAVTNet.student_jitter": (lambda: XAVTNet(num_classes=3, student_jitter="a"), "student_jitter"),
    "classify_relative_motion.rot_threshold": (
        lambda: classify_relative_motion(np.eye(4), np.eye(4), rot_threshold="a"), "rot_threshold"),
    "PushPID.kd": (lambda: PushPID(kd="a"), "kd"),
    "PushPID.limit": (lambda: PushPID(limit="a"), "limit"),
    "look_at_45.distance": (lambda: look_at_45([0, 0, 0], "a"), "distance"),
    "look_at_45.azimuth": (lambda: look_at_45([0, 0, 0], 0.5, azimuth="a"), "azimuth"),
    "RGBDCamera.far": (lambda: RGBDCamera(far="a"), "far"),
    "sample_hemisphere_views.min_elevation_deg": (
        lambda: sample_hemisphere_views([0, 0, 0], 0.5, 3, RNG, min_elevation_deg="a"), "min_elevation_deg"),
    "touch_cloud.pitch": (lambda: touch_cloud(CLOUD, 5, RNG, pitch="a"), "pitch"),
    "touch_cloud.margin": (lambda: touch_cloud(CLOUD, 5, RNG, pitch=0.005, margin="a"), "margin"),
    "TactileConfig.position_noise": (lambda: TactileConfig(position_noise="a"), "position_noise"),
    "crop_to_box.margin": (lambda: crop_to_box(CLOUD, -np.ones(3), np.ones(3), margin="a"), "margin"),
    # hand-written range checks converted to as_real / as_int: a string used to raise a TypeError
    "OccupancyGrid.p_hit": (lambda: OccupancyGrid([0, 0, 0], 0.1, (2, 2, 2), p_hit="a"), "p_hit"),
    "OccupancyGrid.p_miss": (lambda: OccupancyGrid([0, 0, 0], 0.1, (2, 2, 2), p_miss=None), "p_miss"),
    "sample_view_actions.min_elevation_deg": (
        lambda: sample_view_actions([0, 0, 0], 0.5, 4, min_elevation_deg="a"), "min_elevation_deg"),
    "ReachFeasibility.max_reach": (lambda: ReachFeasibility([0, 0, 0], max_reach="a"), "max_reach"),
    "box_fit_error.percentile": (
        lambda: box_fit_error(np.zeros((1, 4, 3)), [1.0, 1.0, 1.0], percentile="a"), "percentile"),
    "detect_transparent.omega": (lambda: detect_transparent([0, 0, 1, 1], CLOUD, omega="a"), "omega"),
    "perturb_padded.keep_min": (
        lambda: perturb_padded(torch.zeros(1, 4, 3), torch.tensor([4]), "a", 0.0), "keep_min"),
    "XAVTNet.pseudo_label_start": (
        lambda: XAVTNet(num_classes=3, pseudo_label_start="a"), "pseudo_label_start"),
    "XAVTNet.ema_decay": (lambda: XAVTNet(num_classes=3, ema_decay=None), "ema_decay"),
    "XAVTNet.neighbour_k": (lambda: XAVTNet(num_classes=3, neighbour_k="a"), "neighbour_k"),
    "TactileConfig.dropout": (lambda: TactileConfig(dropout="a"), "dropout"),
    "TactileConfig.min_force": (lambda: TactileConfig(min_force="a"), "min_force"),
    "touch_cloud.depth_tol": (lambda: touch_cloud(CLOUD, 5, RNG, pitch=0.005, depth_tol="a"), "depth_tol"),
    "edge_weight.iou": (lambda: edge_weight("a", 0.1), "iou"),
    "ArtRegTracker.n_iterations": (
        lambda: ArtRegTracker([CLOUD], [np.eye(4)], n_iterations="a"), "n_iterations"),
    "ArtRegTracker.max_points_per_part": (
        lambda: ArtRegTracker([CLOUD], [np.eye(4)], max_points_per_part="a"), "max_points_per_part"),
    "sigma_weights.n": (lambda: sigma_weights("a"), "n"),
    "STIQF.zeta": (lambda: STIQF(zeta="a"), "zeta"),
    "TIQF.rho": (lambda: TIQF(rho="a"), "rho"),
    "voxel_downsample.voxel_size": (lambda: voxel_downsample(CLOUD, "a"), "voxel_size"),
    "dann_lambda.progress": (lambda: dann_lambda("a"), "progress"),
    "FeatureQueue.capacity": (lambda: FeatureQueue("a"), "capacity"),
    "sinkhorn_balance.tol": (lambda: sinkhorn_balance(torch.full((3, 2), 0.5), tol="a"), "tol"),
    # ... and NaN used to pass checks written as ``if x <= 0: raise`` / ``if x < 0: raise``
    "XAVTNet.lr=nan": (lambda: XAVTNet(num_classes=3, lr=float("nan")), "lr"),
    "gaussian_bandwidths.kernel_mul=nan": (
        lambda: gaussian_bandwidths(torch.ones(3, 2), kernel_mul=float("nan")), "kernel_mul"),
    "sigmoid_rampup.length=nan": (lambda: sigmoid_rampup(0.5, float("nan")), "length"),
    "STIQF.tangent_cap=nan": (lambda: STIQF(tangent_cap=float("nan")), "tangent_cap"),
    "TangentPlanes.cap_factor=nan": (
        lambda: TangentPlanes(CLOUD, cKDTree(CLOUD), cap_factor=float("nan")), "cap_factor"),
    "fit_gpis.offset=nan": (lambda: fit_gpis(CLOUD, CLOUD, offset=float("nan")), "offset"),
}


@pytest.mark.parametrize("call, name", list(CASES.values()), ids=list(CASES))
def test_a_string_for_a_number_is_a_value_error_naming_the_argument(call, name):
    with pytest.raises(ValueError, match=rf"^{name}\b.*: need (a finite number|an integer)"):
        call()


def test_as_real_states_the_unit_after_the_bound():
    for kw, msg in [
        (dict(low=0.0, open_low=True, unit="m"), "voxel: need a finite number > 0 (m), got 'a'"),
        (dict(unit="rad"), "voxel: need a finite number (rad), got 'a'"),
        (dict(low=0.2, high=0.9, unit="m"), "voxel: need a finite number in [0.2, 0.9] (m), got 'a'"),
        (dict(low=0.0), "voxel: need a finite number >= 0, got 'a'"),
    ]:
        with pytest.raises(ValueError) as info:
            as_real("a", "voxel", **kw)
        assert str(info.value) == msg
    assert as_real(0.5, "voxel", low=0.0, unit="m") == 0.5
