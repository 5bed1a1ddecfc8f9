"""flsh.torch.point_to_surface and flsh.closest_surface_points: the closest point of a triangle
(the region tests the torch side's reference uses) against a dense sampling of it, distances
against a search over every face of the synthetic body, zero for points on the surface,
gradcheck in the vertices, and clear errors."""
import numpy as np
import pytest
import torch

import flsh
import flsh.torch


def _closest_barycentric(p, a, b, c):
    """Reference for the search over every face: barycentric coordinates (…, 3) of the point of
    triangle abc closest to p (…, 3), vectorized (the region tests of Ericson, Real-Time
    Collision Detection, 5.1.5)."""
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

@pytest.fixture(scope="module")
def surface(body):
    vertices, _ = flsh.torch.smpl(body, torch.zeros(body.num_betas, dtype=torch.float64),
                                  torch.zeros(72, dtype=torch.float64))
    return vertices.detach(), torch.tensor(np.asarray(body.faces), dtype=torch.long)


def test_closest_point_of_a_triangle_is_the_minimum_over_the_triangle():
    generator = torch.Generator().manual_seed(3)
    n = 120  # barycentric grid: (n + 1)(n + 2) / 2 points per triangle
    i, j = torch.meshgrid(torch.arange(n + 1), torch.arange(n + 1), indexing="ij")
    keep = i + j <= n
    grid = torch.stack([i[keep], j[keep], n - i[keep] - j[keep]], -1).double() / n
    for _ in range(40):
        a, b, c = torch.randn(3, 3, generator=generator, dtype=torch.float64)
        p = 1.5 * torch.randn(3, generator=generator, dtype=torch.float64)
        _, w, _ = flsh.closest_surface_points(torch.stack([a, b, c]).numpy(), [[0, 1, 2]],
                                              p[None].numpy())
        w = torch.from_numpy(w[0])
        assert torch.all(w >= -1e-12) and abs(float(w.sum()) - 1.0) < 1e-12
        q = w[0] * a + w[1] * b + w[2] * c
        samples = grid @ torch.stack([a, b, c])
        sampled = float(((samples - p) ** 2).sum(-1).min())
        exact = float(((q - p) ** 2).sum())
        assert exact <= sampled + 1e-14
        # The grid's spacing bounds how far above the minimum its best sample can be.
        spacing = float(max((a - b).norm(), (b - c).norm(), (a - c).norm())) / n
        assert sampled - exact <= 2.0 * spacing * (exact ** 0.5 + spacing)


def test_matches_a_search_over_every_face(surface):
    x, faces = surface
    generator = torch.Generator().manual_seed(5)
    picks = torch.randint(0, x.shape[0], (300,), generator=generator)
    points = x[picks] + 0.03 * torch.randn(300, 3, generator=generator, dtype=torch.float64)
    d = flsh.torch.point_to_surface(points, x, faces)
    tri = x[faces]  # (F, 3, 3)
    w = _closest_barycentric(points[:, None, :], tri[None, :, 0], tri[None, :, 1],
                             tri[None, :, 2])
    q = (w[..., None] * tri[None]).sum(-2)
    brute = ((points[:, None, :] - q) ** 2).sum(-1).min(-1).values
    assert float(brute.max()) > 1e-5
    assert torch.allclose(d, brute, rtol=0.0, atol=1e-15)


def test_points_on_the_surface_are_at_zero_and_frames_batch(surface):
    x, faces = surface
    generator = torch.Generator().manual_seed(9)
    f = torch.randint(0, faces.shape[0], (200,), generator=generator)
    w = torch.rand(200, 3, generator=generator, dtype=torch.float64)
    w = w / w.sum(-1, keepdim=True)
    on = (w[:, :, None] * x[faces[f]]).sum(-2)
    frames_points = torch.stack([on, on + torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)])
    frames_vertices = torch.stack([x, x + torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)])
    d = flsh.torch.point_to_surface(frames_points, frames_vertices, faces)
    assert d.shape == (2, 200)
    assert float(d.max()) < 1e-24


def test_gradcheck_in_the_vertices(surface):
    x, faces = surface
    generator = torch.Generator().manual_seed(13)
    points = x[:40] + 0.02 * torch.randn(40, 3, generator=generator, dtype=torch.float64)
    moved = torch.arange(60)  # the vertices near the points (gradcheck perturbs each entry)

    def distances(rows):
        return flsh.torch.point_to_surface(points, x.index_put((moved,), rows), faces)

    rows = x[moved].clone().requires_grad_(True)
    (grad,) = torch.autograd.grad(distances(rows).sum(), rows)
    assert float(grad.abs().max()) > 0.0
    assert torch.autograd.gradcheck(distances, (rows,), eps=1e-7, atol=1e-8)


def test_errors_say_what_was_expected(surface):
    x, faces = surface
    with pytest.raises(ValueError, match="same leading shape"):
        flsh.torch.point_to_surface(x[None], x, faces)
    with pytest.raises(ValueError, match="indices"):
        flsh.torch.point_to_surface(x, x, faces + x.shape[0])
    with pytest.raises(ValueError, match="points"):
        flsh.closest_surface_points(x.numpy(), faces.numpy(), np.zeros((4, 2)))
    with pytest.raises(ValueError, match="NaN"):
        flsh.closest_surface_points(x.numpy(), faces.numpy(), np.full((4, 3), np.nan))
