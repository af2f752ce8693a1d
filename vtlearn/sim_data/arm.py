"""Arm mode: a Franka Panda carrying the taxel sensor through IK (thesis ch.5 5.3.1, ch.8 8.3: the
Panda / UR5 robots touch the objects; taxel positions come from the robot kinematics, thesis 4.3.1:
"the 3D positions of the contacted taxels are transformed into the robot base frame using robot
kinematics").

The Panda is loaded from ``pybullet_data/franka_panda/panda.urdf`` with a fixed base at
``T_world_base``. The sensor pad is mounted on ``panda_hand`` at ``T_hand_pad`` (default: 12 cm along
the hand's approach axis z, beyond the fingertips, pad z = hand z). Each action:

1. pybullet IK puts the pad at the touch start (pad z along the touch direction);
2. the joint angles are set kinematically (no dynamics; the object is fixed);
3. taxel world positions are computed from the joint angles with pytorch-kinematics forward
   kinematics of the same URDF: ``T_world_pad = T_world_base @ FK(q) @ T_hand_pad``;
4. the guarded motion along the pad z-axis runs from that FK pose with the free-sensor contact model
   (:class:`vtlearn.sim_data.tactile.TactileSimulator`), and IK then moves the arm to the stop pose.

Shapes:
    taxel_positions_world(q) -> (num_taxels, 3); q is (7,) joint angles in radians
"""

from __future__ import annotations

import contextlib
import io
import os

import numpy as np
import pybullet as p
import pybullet_data

from vtlearn.sim_data.scene import Scene, pose_to_matrix
from vtlearn.sim_data.tactile import TactileConfig, TactileSimulator, TouchResult, pad_frame

PANDA_URDF = os.path.join(pybullet_data.getDataPath(), "franka_panda", "panda.urdf")
HAND_LINK = "panda_hand"
ARM_JOINTS = 7


def default_mount() -> np.ndarray:
    T = np.eye(4)
    T[2, 3] = 0.12
    return T


class PandaArm:
    """A Panda in a :class:`Scene` whose hand carries a taxel sensor.

    Args:
        scene: the pybullet scene (objects are added to it as usual).
        sensor: sensor preset or :class:`TaxelSensor`.
        config: tactile realism knobs.
        T_world_base: pose of the robot base (default: 0.55 m behind the table centre along -x).
        T_hand_pad: sensor mount on ``panda_hand``.
    """

    def __init__(
        self,
        scene: Scene,
        sensor="xela_4x4",
        config: TactileConfig | None = None,
        T_world_base: np.ndarray | None = None,
        T_hand_pad: np.ndarray | None = None,
        objects: list[int] | None = None,
    ):
        import pytorch_kinematics as pk

        self.scene = scene
        self.T_world_base = np.eye(4) if T_world_base is None else np.asarray(T_world_base, dtype=np.float64)
        if T_world_base is None:
            self.T_world_base[0, 3] = -0.55
        self.T_hand_pad = default_mount() if T_hand_pad is None else np.asarray(T_hand_pad, dtype=np.float64)
        from vtlearn.geometry import matrix_to_quat

        w, x, y, z = np.asarray(matrix_to_quat(self.T_world_base[:3, :3]), dtype=np.float64)
        self.robot = p.loadURDF(
            PANDA_URDF,
            self.T_world_base[:3, 3].tolist(),
            [x, y, z, w],
            useFixedBase=True,
            physicsClientId=scene.client,
        )
        self.hand_index = next(
            j
            for j in range(p.getNumJoints(self.robot, physicsClientId=scene.client))
            if p.getJointInfo(self.robot, j, physicsClientId=scene.client)[12].decode() == HAND_LINK
        )
        info = [p.getJointInfo(self.robot, j, physicsClientId=scene.client) for j in range(ARM_JOINTS)]
        self.lower = np.array([i[8] for i in info])
        self.upper = np.array([i[9] for i in info])
        with (
            open(PANDA_URDF, "rb") as f,
            contextlib.redirect_stdout(io.StringIO()),
            contextlib.redirect_stderr(io.StringIO()),
        ):
            self.chain = pk.build_serial_chain_from_urdf(f.read(), HAND_LINK).to(
                dtype=__import__("torch").float64
            )
        self.sim = TactileSimulator(scene, sensor, config, objects)
        self.q = np.array([0.0, -0.4, 0.0, -2.2, 0.0, 1.9, 0.8])
        self.set_joints(self.q)

    # ------------------------------------------------------------------ kinematics
    def set_joints(self, q) -> None:
        q = np.asarray(q, dtype=np.float64)
        if q.shape != (ARM_JOINTS,) or not np.all(np.isfinite(q)):
            raise ValueError(f"q: need 7 finite joint angles, got {q}")
        for j in range(ARM_JOINTS):
            p.resetJointState(self.robot, j, float(q[j]), physicsClientId=self.scene.client)
        self.q = q.copy()

    def fk_hand(self, q) -> np.ndarray:
        """T_world_hand from joint angles by pytorch-kinematics."""
        import torch

        m = self.chain.forward_kinematics(torch.as_tensor(np.asarray(q, dtype=np.float64))).get_matrix()[0]
        return self.T_world_base @ m.numpy()

    def T_world_pad(self, q) -> np.ndarray:
        return self.fk_hand(q) @ self.T_hand_pad

    def taxel_positions_world(self, q) -> np.ndarray:
        T = self.T_world_pad(q)
        return self.sim.sensor.taxel_positions() @ T[:3, :3].T + T[:3, 3]

    def pybullet_hand(self) -> np.ndarray:
        """T_world_hand of the current joint state from pybullet's own link state."""
        st = p.getLinkState(
            self.robot, self.hand_index, computeForwardKinematics=True, physicsClientId=self.scene.client
        )
        return pose_to_matrix(st[4], st[5])

    def ik(self, T_world_pad: np.ndarray, iterations: int = 5) -> np.ndarray:
        """Joint angles that put the pad at ``T_world_pad`` (pybullet damped IK, refined iteratively)."""
        from vtlearn.geometry import matrix_to_quat

        T_hand = T_world_pad @ np.linalg.inv(self.T_hand_pad)
        w, x, y, z = np.asarray(matrix_to_quat(T_hand[:3, :3]), dtype=np.float64)
        q = self.q
        for _ in range(iterations):
            sol = p.calculateInverseKinematics(
                self.robot,
                self.hand_index,
                T_hand[:3, 3].tolist(),
                [x, y, z, w],
                lowerLimits=self.lower.tolist(),
                upperLimits=self.upper.tolist(),
                jointRanges=(self.upper - self.lower).tolist(),
                restPoses=q.tolist(),
                maxNumIterations=200,
                residualThreshold=1e-6,
                physicsClientId=self.scene.client,
            )
            q = np.clip(np.asarray(sol[:ARM_JOINTS]), self.lower, self.upper)
            self.set_joints(q)
        return q

    # ------------------------------------------------------------------ actions
    def touch(self, start, direction, roll: float = 0.0, rng=None, tolerance: float = 0.005) -> TouchResult:
        """Touch as in free mode, but with the pad carried by the arm (FK pose, then IK to the stop).

        Returns no contact when IK cannot reach the start within ``tolerance`` metres.
        """
        target = pad_frame(start, direction, roll)
        q = self.ik(target)
        T_pad = self.T_world_pad(q)
        if np.linalg.norm(T_pad[:3, 3] - target[:3, 3]) > tolerance or T_pad[:3, 2] @ target[:3, 2] < 0.99:
            return TouchResult(T_world_pad=T_pad)
        res = self.sim.touch_from(T_pad, rng)
        if res.T_world_pad is not None:
            self.ik(res.T_world_pad)
        return res
