"""The scalar checks of the public API go through ``vtlearn.validation.as_real``: a string in place of a
number is a ``ValueError`` that names the argument, not a numpy ``TypeError`` from a comparison."""

import numpy as np
import pytest
import torch

from vtlearn.active.actions import (
    OrientedBox,
    sample_pinch_actions,
    sample_touch_actions,
    sample_view_actions,
)
from vtlearn.active.exploration import simulate_touch
from vtlearn.active.mc_dropout import select_power
from vtlearn.active.occupancy import OccupancyGrid
from vtlearn.active.reconstruction_nbt import ExpectedBoxFitGain, predict_tactile_contacts
from vtlearn.active.selection import EnergyCosts, cloud_top_down_box
from vtlearn.active.sensors import PinchSensor, TactileArray, ToFCamera
from vtlearn.classical.artreg import ArtRegTracker
from vtlearn.classical.stiqf import DistanceField, best_buddy_pairs
from vtlearn.classical.ukf import sigma_weights
from vtlearn.geometry.transforms import canonical_box
from vtlearn.losses.contrastive import nt_xent
from vtlearn.losses.dann import grad_reverse
from vtlearn.models.components.mean_teacher import perturb_padded
from vtlearn.models.xavtnet import XAVTNet
from vtlearn.runtime.articulation import classify_relative_motion
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
}


@pytest.mark.parametrize("call, name", list(CASES.values()), ids=list(CASES))
def test_a_string_for_a_number_is_a_value_error_naming_the_argument(call, name):
    with pytest.raises(ValueError, match=rf"^{name}\b.*: need a finite number"):
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
