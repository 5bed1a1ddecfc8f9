"""flsh.torch.smpl: the C++ SMPL forward pass as a torch.autograd.Function with analytic
backward. Checked by torch.autograd.gradcheck (float64, unbatched and batched), against the
independent PyTorch reference (values and autograd gradients), in a torch.optim loop, for
not mutating the model or its inputs, and for its input errors."""
import numpy as np
import pytest
import torch

import flsh
import flsh.torch
from flsh import smpl_torch


@pytest.fixture(scope="module")
def tiny_body():
    """A 200-vertex synthetic body: gradcheck differentiates every input column numerically."""
    return flsh.make_synthetic_body(vertices=200)


def random_inputs(model, rng, frames=None, num_betas=None):
    shape = () if frames is None else (frames,)
    K = model.num_betas if num_betas is None else num_betas

    def tensor(values):
        return torch.tensor(values, dtype=torch.float64, requires_grad=True)

    return (tensor(rng.uniform(-1.0, 1.0, shape + (K,))),
            tensor(rng.uniform(-0.5, 0.5, shape + (72,))),
            tensor(rng.uniform(-0.3, 0.3, shape + (3,))))


def test_gradcheck_unbatched(tiny_body, rng):
    betas, pose, trans = random_inputs(tiny_body, rng, num_betas=7)
    vertices, joints = flsh.torch.smpl(tiny_body, betas, pose, trans)
    assert vertices.shape == (200, 3) and joints.shape == (24, 3)
    assert vertices.dtype == joints.dtype == torch.float64
    # The analytic gradient is not zero (a gradcheck of a constant would pass trivially).
    (vertices.sum() + joints.square().sum()).backward()
    for name, t in (("betas", betas), ("pose", pose), ("trans", trans)):
        assert t.grad.abs().max() > 1e-3, name
    assert torch.autograd.gradcheck(
        lambda b, p, t: flsh.torch.smpl(tiny_body, b, p, t), (betas, pose, trans),
        eps=1e-6, atol=1e-7, rtol=1e-6)


def test_gradcheck_batched_with_shared_betas(tiny_body, rng):
    _, pose, trans = random_inputs(tiny_body, rng, frames=2)
    betas, _, _ = random_inputs(tiny_body, rng)  # (K,) shared by both frames
    vertices, joints = flsh.torch.smpl(tiny_body, betas, pose, trans)
    assert vertices.shape == (2, 200, 3) and joints.shape == (2, 24, 3)
    assert torch.autograd.gradcheck(
        lambda b, p, t: flsh.torch.smpl(tiny_body, b, p, t), (betas, pose, trans),
        eps=1e-6, atol=1e-7, rtol=1e-6)


def test_batched_frames_equal_single_frames(body, rng):
    betas, pose, trans = random_inputs(body, rng, frames=3)
    vertices, joints = flsh.torch.smpl(body, betas, pose, trans)
    for f in range(3):
        v, j = flsh.torch.smpl(body, betas[f], pose[f], trans[f])
        torch.testing.assert_close(vertices[f], v, rtol=0, atol=1e-13)
        torch.testing.assert_close(joints[f], j, rtol=0, atol=1e-13)


def test_values_and_gradients_match_the_pytorch_reference(body, reference, rng):
    betas, pose, trans = random_inputs(body, rng, num_betas=8)
    weights_v = torch.tensor(rng.normal(size=(body.num_vertices, 3)))
    weights_j = torch.tensor(rng.normal(size=(24, 3)))

    vertices, joints = flsh.torch.smpl(body, betas, pose, trans)
    loss = (weights_v * vertices).sum() + (weights_j * joints).square().sum()
    ours = torch.autograd.grad(loss, (betas, pose, trans))

    ref_vertices, ref_joints, _, _ = reference(betas, pose[None], trans[None])
    ref_loss = (weights_v * ref_vertices[0]).sum() + (weights_j * ref_joints[0]).square().sum()
    theirs = torch.autograd.grad(ref_loss, (betas, pose, trans))

    torch.testing.assert_close(vertices, ref_vertices[0], rtol=0, atol=1e-12)
    torch.testing.assert_close(joints, ref_joints[0], rtol=0, atol=1e-12)
    for name, a, b in zip(("betas", "pose", "trans"), ours, theirs):
        assert b.abs().max() > 1e-3, name
        torch.testing.assert_close(a, b, rtol=1e-9, atol=1e-10, msg=name)


def test_optimization_loop_fits_joints(body, rng):
    """Pose and translation fitted to target joints with torch.optim (Adam, then LBFGS)."""
    target_pose = torch.tensor(rng.uniform(-0.3, 0.3, 72))
    target_trans = torch.tensor([0.1, -0.05, 0.2], dtype=torch.float64)
    betas = torch.zeros(10, dtype=torch.float64)
    with torch.no_grad():
        _, target_joints = flsh.torch.smpl(body, betas, target_pose, target_trans)

    pose = torch.zeros(72, dtype=torch.float64, requires_grad=True)
    trans = torch.zeros(3, dtype=torch.float64, requires_grad=True)

    def loss_fn():
        _, joints = flsh.torch.smpl(body, betas, pose, trans)
        return (joints - target_joints).square().sum()

    initial = loss_fn().item()
    adam = torch.optim.Adam([pose, trans], lr=0.02)
    for _ in range(30):
        adam.zero_grad()
        loss = loss_fn()
        loss.backward()
        adam.step()
    after_adam = loss_fn().item()
    lbfgs = torch.optim.LBFGS([pose, trans], max_iter=50, line_search_fn="strong_wolfe")

    def closure():
        lbfgs.zero_grad()
        loss = loss_fn()
        loss.backward()
        return loss

    lbfgs.step(closure)
    final = loss_fn().item()
    # Joints alone leave bone twists free (a flat valley), so LBFGS is given a modest target.
    assert after_adam < 0.1 * initial, (initial, after_adam)
    assert final < min(1e-3 * initial, 0.1 * after_adam), (initial, after_adam, final)


def test_no_mutation_of_model_or_inputs(body, rng):
    arrays = {name: np.array(getattr(body, name)) for name in
              ("v_template", "shapedirs", "posedirs", "J_regressor", "weights", "faces")}
    betas, pose, trans = random_inputs(body, rng, frames=2)
    copies = [t.detach().clone() for t in (betas, pose, trans)]
    first = flsh.torch.smpl(body, betas, pose, trans)
    (first[0].sum() + first[1].sum()).backward()
    grads = [t.grad.clone() for t in (betas, pose, trans)]
    for t in (betas, pose, trans):
        t.grad = None
    second = flsh.torch.smpl(body, betas, pose, trans)
    (second[0].sum() + second[1].sum()).backward()
    for name, a in arrays.items():
        np.testing.assert_array_equal(getattr(body, name), a, err_msg=name)
    for t, c, g in zip((betas, pose, trans), copies, grads):
        assert torch.equal(t.detach(), c)
        assert torch.equal(t.grad, g)  # the same again: no state carried between calls
    assert torch.equal(first[0], second[0]) and torch.equal(first[1], second[1])


def test_no_graph_without_requires_grad(body):
    zeros = torch.zeros(72, dtype=torch.float64)
    vertices, joints = flsh.torch.smpl(body, torch.zeros(10, dtype=torch.float64), zeros)
    assert vertices.grad_fn is None and joints.grad_fn is None
    posed = flsh.pose_body(body, np.zeros(10), np.zeros(72))
    np.testing.assert_array_equal(vertices.numpy(), posed.vertices)


def test_input_errors_name_the_argument(body):
    d = dict(dtype=torch.float64)
    betas, pose = torch.zeros(10, **d), torch.zeros(72, **d)
    with pytest.raises(ValueError, match=r"pose: expected dtype torch.float64, got torch.float32"):
        flsh.torch.smpl(body, betas, pose.float())
    with pytest.raises(ValueError, match=r"pose: expected shape \(72,\) or \(B, 72\), got \(71,\)"):
        flsh.torch.smpl(body, betas, torch.zeros(71, **d))
    with pytest.raises(ValueError, match=r"betas: expected at most 10 values"):
        flsh.torch.smpl(body, torch.zeros(11, **d), pose)
    with pytest.raises(ValueError, match=r"trans: expected shape \(3,\) or \(B, 3\), got \(2, 4\)"):
        flsh.torch.smpl(body, betas, pose, torch.zeros(2, 4, **d))
    with pytest.raises(ValueError, match=r"batch sizes differ"):
        flsh.torch.smpl(body, betas, torch.zeros(2, 72, **d), torch.zeros(3, 3, **d))
    with pytest.raises(ValueError, match=r"pose: expected a torch.Tensor"):
        flsh.torch.smpl(body, betas, np.zeros(72))
    with pytest.raises(ValueError, match=r"pose: expected shape"):
        flsh.torch.smpl(body, betas, torch.zeros(1, 1, 72, **d))
    with pytest.raises(TypeError, match=r"flsh.BodyModel"):
        flsh.torch.smpl("model.npz", betas, pose)
    bad = pose.clone()
    bad[5] = float("nan")
    with pytest.raises(ValueError, match=r"NaN"):
        flsh.torch.smpl(body, betas, bad)


def test_absurd_pose_values_raise_value_error(body):
    # Issue 23: a pose value of 1e300 gave all-NaN vertices without an error.
    betas = torch.zeros(body.num_betas, dtype=torch.float64)
    pose = torch.zeros(72, dtype=torch.float64)
    pose[3 * 7] = 1e300
    with pytest.raises(ValueError, match="joint 7 .* 1e\\+300 rad, expected at most 1e6 rad"):
        flsh.torch.smpl(body, betas, pose)
    pose[3 * 7] = float("nan")
    with pytest.raises(ValueError, match="NaN"):
        flsh.torch.smpl(body, betas, pose)
    reference = smpl_torch.SmplTorch.from_flsh(body)
    with pytest.raises(ValueError, match="NaN or Inf"):
        reference(betas, pose[None])
    pose[3 * 7] = -2e6
    with pytest.raises(ValueError, match="angle .* 2e\\+06 rad"):
        reference(betas, pose[None])
