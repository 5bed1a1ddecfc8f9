"""SMPL linear blend skinning in plain PyTorch: the independent reference for flsh's C++ forward
pass (tests, benchmarks/body_forward_vs_torch.py).

Written from the formulas of ARCHITECTURE.md §2, with no flsh code in the loop:

    v_shaped = v_template + shapedirs · β            J = J_regressor · v_shaped
    R_j = Rodrigues(θ_j)                              pose_feature = vec(R_j − I), j = 1..23
    v_posed = v_shaped + posedirs · pose_feature
    G_0 = [R_0 | J_0],  G_j = G_parent(j) · [R_j | J_j − J_parent(j)]
    A_j = G_j · [I | −J_j],  v_i = Σ_j w_ij A_j [v_posed_i; 1] + trans

Everything is differentiable (torch.autograd), exact at θ = 0 (Taylor branch in Rodrigues),
and batched over frames. Use float64 on the CPU to compare with flsh to round-off.
"""
from __future__ import annotations

import numpy as np
import torch

__all__ = [
    "SmplTorch",
    "batch_rodrigues",
    "check_rotation_vectors",
    "pose_feature",
    "skew",
    "to_smpl_poses",
]

NUM_JOINTS = 24
SMPL_POSE_SIZE = 72
SMPLH_POSE_SIZE = 156
NUM_BODY_JOINTS_SMPLH = 22

# Below this squared angle (rad²) Rodrigues' coefficients use their Taylor series: the closed
# forms lose digits there, and sqrt(0) has no derivative.
_SMALL_ANGLE_SQUARED = 1e-12


def skew(v: torch.Tensor) -> torch.Tensor:
    """Cross-product matrices [v]× (..., 3, 3) of vectors v (..., 3)."""
    zero = torch.zeros_like(v[..., 0])
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    rows = [
        torch.stack([zero, -z, y], dim=-1),
        torch.stack([z, zero, -x], dim=-1),
        torch.stack([-y, x, zero], dim=-1),
    ]
    return torch.stack(rows, dim=-2)


def batch_rodrigues(theta: torch.Tensor) -> torch.Tensor:
    """Rotation matrices R = exp([θ]×) (..., 3, 3) of rotation vectors θ (..., 3), rad.

    R = I + a K + b K² with K = [θ]×, a = sin|θ|/|θ|, b = (1 − cos|θ|)/|θ|².
    """
    angle_squared = (theta * theta).sum(dim=-1)
    small = angle_squared < _SMALL_ANGLE_SQUARED
    # Keep the unused branch finite so that its gradient (masked by where) is not NaN.
    safe_squared = torch.where(small, torch.ones_like(angle_squared), angle_squared)
    angle = torch.sqrt(safe_squared)
    a = torch.where(small, 1.0 - angle_squared / 6.0, torch.sin(angle) / angle)
    b = torch.where(small, 0.5 - angle_squared / 24.0, (1.0 - torch.cos(angle)) / safe_squared)
    K = skew(theta)
    eye = torch.eye(3, dtype=theta.dtype, device=theta.device).expand(K.shape)
    return eye + a[..., None, None] * K + b[..., None, None] * (K @ K)


# Largest angle |θ| (rad) of a pose's rotation vector, as flsh.MAX_ROTATION_ANGLE in C++
# (kMaxRotationAngle): beyond it an angle means no rotation anyone meant.
MAX_ROTATION_ANGLE = 1e6


def check_rotation_vectors(poses: torch.Tensor, name: str) -> None:
    """ValueError naming `name` unless every rotation vector of poses (..., 3J) is finite with
    angle |θ| ≤ MAX_ROTATION_ANGLE (as the C++ forward pass; Rodrigues' |θ|² overflows to NaN
    above 1e154)."""
    with torch.no_grad():
        theta = poses.detach().reshape(poses.shape[:-1] + (-1, 3))
        if not bool(torch.isfinite(theta).all()):
            raise ValueError(f"{name}: contains NaN or Inf")
        # Scaled so that the norm of huge finite vectors does not overflow.
        scale = theta.abs().amax(dim=-1, keepdim=True).clamp_min(1e-300)
        angle = (theta / scale).norm(dim=-1) * scale[..., 0]
        if bool((angle > MAX_ROTATION_ANGLE).any()):
            raise ValueError(f"{name}: a rotation vector has angle |θ| = "
                             f"{float(angle.max()):.6g} rad, expected at most 1e6 rad")


def pose_feature(rotations: torch.Tensor) -> torch.Tensor:
    """Pose blend-shape feature (B, 207): entries (r, c) of R_j − I, row-major, j = 1..23,
    from joint rotations (B, 24, 3, 3)."""
    eye = torch.eye(3, dtype=rotations.dtype, device=rotations.device)
    return (rotations[:, 1:] - eye).reshape(rotations.shape[0], -1)


def to_smpl_poses(poses: torch.Tensor) -> torch.Tensor:
    """(B, 72) SMPL poses from (B, 72) or SMPL-H (B, 156) poses: SMPL-H body joints 0–21 are
    SMPL joints 0–21; SMPL's hand joints 22–23 become identity (zero)."""
    if poses.shape[-1] == SMPL_POSE_SIZE:
        return poses
    if poses.shape[-1] != SMPLH_POSE_SIZE:
        raise ValueError(f"poses: expected (B, 72) or (B, 156), got {tuple(poses.shape)}")
    body = poses[..., : 3 * NUM_BODY_JOINTS_SMPLH]
    hands = torch.zeros(poses.shape[:-1] + (6,), dtype=poses.dtype, device=poses.device)
    return torch.cat([body, hands], dim=-1)


class SmplTorch:
    """SMPL forward pass over the arrays of an SMPL-format model.

    Arrays (numpy or torch): v_template (V, 3), shapedirs (V, 3, K), posedirs (V, 3, 207),
    J_regressor (24, V), weights (V, 24), parents (24,) with parents[0] = −1.
    """

    def __init__(self, v_template, shapedirs, posedirs, J_regressor, weights, parents,
                 dtype=torch.float64, device="cpu"):
        def tensor(a):  # a copy: the reference never aliases the model's (read-only) arrays
            return torch.tensor(np.asarray(a, dtype=np.float64), dtype=dtype, device=device)

        self.v_template = tensor(v_template)
        V = self.v_template.shape[0]
        self.num_vertices = V
        # Blend shapes flattened to rows 3i + c and stored transposed (K × 3V, 207 × 3V), so
        # that one row-vector × contiguous-matrix product applies them (twice as fast as .T).
        self.shapedirs_t = tensor(shapedirs).reshape(3 * V, -1).T.contiguous()
        self.posedirs_t = tensor(posedirs).reshape(3 * V, -1).T.contiguous()
        self.J_regressor = tensor(J_regressor)
        self.weights = tensor(weights)
        self.parents = [int(p) for p in np.asarray(parents).reshape(-1)]
        if self.parents[0] != -1 or any(not 0 <= p < j for j, p in enumerate(self.parents) if j):
            raise ValueError(f"parents: expected a tree with parents[j] < j, got {self.parents}")
        self.num_betas = self.shapedirs_t.shape[0]

    @classmethod
    def from_flsh(cls, model, **kwargs) -> "SmplTorch":
        """The reference over the arrays of a flsh.BodyModel."""
        return cls(model.v_template, model.shapedirs, model.posedirs, model.J_regressor,
                   model.weights, model.parents, **kwargs)

    def _as_tensor(self, a):
        if isinstance(a, torch.Tensor):
            return a
        return torch.as_tensor(np.asarray(a, dtype=np.float64), dtype=self.v_template.dtype)

    def forward(self, betas, poses, trans=None):
        """Posed vertices (B, V, 3) and joints (B, 24, 3), m, plus the global transforms
        G (B, 24, 4, 4) and the shaped rest joints J (B, 24, 3).

        betas (K',) or (B, K') with K' ≤ K (zero padded); poses (B, 72) or (B, 156), rad;
        trans (B, 3), m, or None.
        """
        betas = self._as_tensor(betas)
        poses = to_smpl_poses(self._as_tensor(poses))
        check_rotation_vectors(poses, "poses")
        B = poses.shape[0]
        if betas.shape[-1] < self.num_betas:
            padding = torch.zeros(betas.shape[:-1] + (self.num_betas - betas.shape[-1],),
                                  dtype=betas.dtype)
            betas = torch.cat([betas, padding], dim=-1)
        betas = betas.expand(B, -1) if betas.dim() == 1 else betas

        V = self.num_vertices
        v_shaped = self.v_template + (betas @ self.shapedirs_t).reshape(B, V, 3)
        J = self.J_regressor @ v_shaped  # (B, 24, 3)

        R = batch_rodrigues(poses.reshape(B, NUM_JOINTS, 3))  # (B, 24, 3, 3)
        v_posed = v_shaped + (pose_feature(R) @ self.posedirs_t).reshape(B, V, 3)

        # Kinematic chain: G_j = G_parent · [R_j | J_j − J_parent].
        bottom = torch.zeros(B, 1, 4, dtype=R.dtype)
        bottom[..., 3] = 1.0

        def rigid(rotation, translation):  # (B, 3, 3), (B, 3) -> (B, 4, 4)
            top = torch.cat([rotation, translation[..., None]], dim=-1)
            return torch.cat([top, bottom], dim=-2)

        G = [rigid(R[:, 0], J[:, 0])]
        for j in range(1, NUM_JOINTS):
            p = self.parents[j]
            G.append(G[p] @ rigid(R[:, j], J[:, j] - J[:, p]))
        G = torch.stack(G, dim=1)  # (B, 24, 4, 4)

        # A_j = G_j · [I | −J_j]: rotation of G_j, translation t_j − R_j^global J_j.
        rotation = G[..., :3, :3]
        translation = G[..., :3, 3] - (rotation @ J[..., None])[..., 0]
        A = torch.cat([rotation, translation[..., None]], dim=-1)  # (B, 24, 3, 4)

        blended = (self.weights @ A.reshape(B, NUM_JOINTS, 12)).reshape(B, V, 3, 4)
        vertices = (blended[..., :3] @ v_posed[..., None])[..., 0] + blended[..., 3]
        joints = G[..., :3, 3]
        if trans is not None:
            trans = self._as_tensor(trans).reshape(B, 1, 3)
            vertices = vertices + trans
            joints = joints + trans
        return vertices, joints, G, J

    __call__ = forward
