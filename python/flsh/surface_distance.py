"""Distance from unordered points (a scan) to a triangle surface, differentiable in the surface's
vertices: the loss for fitting a simulation to scans without known correspondences (issue 25's
point-to-surface fit). Re-exported as flsh.torch.point_to_surface.

For each point p the closest point q on the surface is searched among the triangles around its
k nearest vertices (exact unless the closest triangle touches none of them: a coarse surface with
k far below its vertex valence), then q = Σ_i b_i x_i with the barycentric coordinates b of the
closest point. The returned squared distance ‖p − q‖² is differentiable in the vertices x and in
p; b is held, which gives the exact gradient (Danskin: at the minimum over the triangle the
derivative of the minimizer does not contribute), wherever the closest point is unique.
"""
from __future__ import annotations

import numpy as np
import torch

__all__ = ["point_to_surface"]


def _vertex_faces(faces: torch.Tensor, num_vertices: int) -> torch.Tensor:
    """(V, D) the faces around each vertex, padded with −1 (D: the largest valence)."""
    flat = faces.reshape(-1)
    owner = torch.arange(faces.shape[0]).repeat_interleave(3)
    order = torch.argsort(flat, stable=True)
    flat, owner = flat[order], owner[order]
    counts = torch.bincount(flat, minlength=num_vertices)
    start = torch.cumsum(counts, 0) - counts
    slot = torch.arange(flat.shape[0]) - start[flat]
    table = torch.full((num_vertices, int(counts.max())), -1, dtype=torch.long)
    table[flat, slot] = owner
    return table


def _closest_barycentric(p, a, b, c):
    """Barycentric coordinates (…, 3) of the point of triangle abc closest to p (…, 3) (the
    region tests of Ericson, Real-Time Collision Detection, 5.1.5)."""
    ab, ac, ap = b - a, c - a, p - a
    bp, cp = p - b, p - c
    d1, d2 = (ab * ap).sum(-1), (ac * ap).sum(-1)
    d3, d4 = (ab * bp).sum(-1), (ac * bp).sum(-1)
    d5, d6 = (ab * cp).sum(-1), (ac * cp).sum(-1)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    tiny = torch.finfo(p.dtype).tiny

    def bary(u, v, w):
        return torch.stack(torch.broadcast_tensors(u, v, w), -1)

    zero, one = torch.zeros_like(d1), torch.ones_like(d1)
    denom = va + vb + vc
    denom = torch.where(denom.abs() > tiny, denom, torch.full_like(denom, tiny))
    v, w = vb / denom, vc / denom
    out = bary(1 - v - w, v, w)  # inside the face
    # The edges and corners, in reverse order of Ericson's tests so that the first test wins.
    e_bc = (d4 - d3) + (d5 - d6)
    w_bc = (d4 - d3) / torch.where(e_bc.abs() > tiny, e_bc, torch.full_like(e_bc, tiny))
    out = torch.where(((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0))[..., None],
                      bary(zero, 1 - w_bc, w_bc), out)
    e_ac = d2 - d6
    w_ac = d2 / torch.where(e_ac.abs() > tiny, e_ac, torch.full_like(e_ac, tiny))
    out = torch.where(((vb <= 0) & (d2 >= 0) & (d6 <= 0))[..., None], bary(1 - w_ac, zero, w_ac),
                      out)
    out = torch.where(((d6 >= 0) & (d5 <= d6))[..., None], bary(zero, zero, one), out)
    e_ab = d1 - d3
    v_ab = d1 / torch.where(e_ab.abs() > tiny, e_ab, torch.full_like(e_ab, tiny))
    out = torch.where(((vc <= 0) & (d1 >= 0) & (d3 <= 0))[..., None], bary(1 - v_ab, v_ab, zero),
                      out)
    out = torch.where(((d3 >= 0) & (d4 <= d3))[..., None], bary(zero, one, zero), out)
    out = torch.where(((d1 <= 0) & (d2 <= 0))[..., None], bary(one, zero, zero), out)
    return out


def point_to_surface(points: torch.Tensor, vertices: torch.Tensor, faces, k: int = 8,
                     chunk: int = 1024) -> torch.Tensor:
    """Squared distance from each point to the surface.

    points: (…, P, 3) and vertices (…, V, 3), float64, with the same leading (batch) shape, e.g.
    (T, P, 3) scan points per frame and (T, V, 3) simulated vertices; faces: (F, 3) vertex
    indices (e.g. flsh body model .faces). k: nearest vertices whose triangles are searched
    (1..V); chunk: points searched at once (memory ~ chunk × V). Returns (…, P): ‖p − q‖², m², differentiable in vertices and points.
    ValueError on shapes that do not match.
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
    if not 1 <= k <= V:
        raise ValueError(f"point_to_surface: k = {k}, expected 1..{V}")
    batch = points.shape[:-2]
    P = points.shape[-2]
    pts = points.reshape(-1, P, 3)
    verts = vertices.reshape(-1, V, 3)
    around = _vertex_faces(faces, V)  # (V, D)
    out = []
    for s in range(pts.shape[0]):
        p_all, x = pts[s], verts[s]
        with torch.no_grad():
            x_d, p_d = x.detach(), p_all.detach()
            chosen = []  # per point: (face, barycentric) of the closest candidate
            for begin in range(0, P, chunk):
                p = p_d[begin:begin + chunk]
                near = torch.cdist(p, x_d).topk(k, largest=False).indices  # (n, k)
                candidates = around[near].reshape(p.shape[0], -1)  # (n, k·D), −1 padded
                valid = candidates >= 0
                f = torch.where(valid, candidates, torch.zeros_like(candidates))
                tri = x_d[faces[f]]  # (n, C, 3 corners, 3)
                b = _closest_barycentric(p[:, None, :], tri[..., 0, :], tri[..., 1, :],
                                         tri[..., 2, :])
                q = (b[..., None] * tri).sum(-2)
                d = ((p[:, None, :] - q) ** 2).sum(-1)
                d = torch.where(valid, d, torch.full_like(d, float("inf")))
                best = d.argmin(-1)
                rows = torch.arange(p.shape[0])
                chosen.append((f[rows, best], b[rows, best]))
            face = torch.cat([c[0] for c in chosen])
            weights = torch.cat([c[1] for c in chosen])
        q = (weights[..., None] * x[faces[face]]).sum(-2)  # differentiable in x
        out.append(((p_all - q) ** 2).sum(-1))
    return torch.stack(out).reshape(*batch, P)
