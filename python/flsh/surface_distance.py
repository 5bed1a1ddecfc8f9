"""Distance from unordered points (a scan) to a triangle surface, differentiable in the surface's
vertices: the loss for fitting a simulation to scans without known correspondences (issue 25's
point-to-surface fit). Re-exported as flsh.torch.point_to_surface.

For each point p the exact closest point q of the surface is found by flsh.closest_surface_points
(C++, a bounding-box tree, points in parallel): its triangle and barycentric coordinates b.
Then q = Σ_i b_i x_i in torch, and the returned squared distance ‖p − q‖² is differentiable in
the vertices x and in p with b held, which is the exact gradient (Danskin: at the minimum over
the triangle the minimizer's own derivative does not contribute), wherever the closest point is
unique.
"""
from __future__ import annotations

import numpy as np
import torch

from . import _flsh

__all__ = ["point_to_surface"]


def point_to_surface(points: torch.Tensor, vertices: torch.Tensor, faces) -> torch.Tensor:
    """Squared distance from each point to the surface.

    points: (…, P, 3) and vertices (…, V, 3), float64, with the same leading (batch) shape, e.g.
    (T, P, 3) scan points per frame and (T, V, 3) simulated vertices; faces: (F, 3) vertex
    indices (e.g. a flsh body model's .faces). Returns (…, P): ‖p − q‖², m², differentiable in
    vertices and points. ValueError on shapes or indices that do not match.
    """
    if not isinstance(points, torch.Tensor) or not isinstance(vertices, torch.Tensor):
        raise ValueError("point_to_surface: points and vertices must be torch tensors")
    faces = faces.long() if isinstance(faces, torch.Tensor) else \
        torch.tensor(np.asarray(faces), dtype=torch.long)
    if points.shape[-1:] != (3,) or vertices.shape[-1:] != (3,) or points.dim() < 2 \
            or points.shape[:-2] != vertices.shape[:-2]:
        raise ValueError(f"point_to_surface: points {tuple(points.shape)} and vertices "
                         f"{tuple(vertices.shape)} must be (…, P, 3) and (…, V, 3) with the "
                         "same leading shape")
    V = vertices.shape[-2]
    if faces.dim() != 2 or faces.shape[1] != 3 or faces.numel() == 0 \
            or int(faces.min()) < 0 or int(faces.max()) >= V:
        raise ValueError(f"point_to_surface: faces {tuple(faces.shape)} must be (F, 3) indices "
                         f"into the {V} vertices")
    batch = points.shape[:-2]
    P = points.shape[-2]
    pts = points.reshape(-1, P, 3)
    verts = vertices.reshape(-1, V, 3)
    faces_np = faces.numpy().astype(np.int32)
    out = []
    for s in range(pts.shape[0]):
        p, x = pts[s], verts[s]
        face, weights, _ = _flsh.closest_surface_points(x.detach().numpy(), faces_np,
                                                        p.detach().numpy())
        face = torch.from_numpy(face).long()
        weights = torch.from_numpy(weights)
        q = (weights[..., None] * x[faces[face]]).sum(-2)  # differentiable in x
        out.append(((p - q) ** 2).sum(-1))
    return torch.stack(out).reshape(*batch, P)
