"""flsh.torch.simulate: a whole simulated rollout as a torch.autograd.Function, with the adjoint
(flsh.Rollout) as its backward. torch.autograd.gradcheck on every input group (β, pose and root
targets, stiffnesses, initial state and velocity), on joints and SMPL vertices, with and without
ground contact; no mutation of the inputs or the shared model; interleaved calls; input errors;
a short training loop; and the flsh.Rollout bindings (reverse pass against forward
sensitivities, argument checks). A 600-vertex synthetic body walking for T = 6 steps."""
import numpy as np
import pytest
import torch

import flsh
import flsh.torch

STEPS = 6
INPUT_NAMES = ("betas", "pose_targets", "root_targets", "stiffnesses", "initial_state",
               "initial_velocity")


@pytest.fixture(scope="module")
def body():
    return flsh.make_synthetic_body(vertices=600)


def ground_under(body, walk):
    """A ground plane 1 cm above the lowest vertex of the walk's initial state: the foot is
    in contact from the first step."""
    avatar = flsh.SoftAvatar(body)
    avatar.init_volumetric_data()
    sim = flsh.Simulable(avatar, walk)
    sim.initialize()
    lowest = sim.get_nodes()[:, 1].min()
    return flsh.Collider.plane(point=[0.0, lowest + 0.01, 0.0], normal=[0.0, 1.0, 0.0])


@pytest.fixture(scope="module")
def free(body, walk):
    return flsh.torch.RolloutSimulator(body, walk, steps=STEPS)


@pytest.fixture(scope="module")
def grounded(body, walk):
    return flsh.torch.RolloutSimulator(body, walk, steps=STEPS, colliders=[ground_under(body, walk)])


def base_inputs(simulator, rng):
    """Every input group as a float64 tensor near the simulable's own values (moved a little so
    that nothing sits on a special value), none requiring grad."""
    own = simulator.own_inputs()
    values = {
        "betas": rng.uniform(-0.5, 0.5, simulator.num_betas),
        "pose_targets": own["pose_targets"] + rng.uniform(-0.05, 0.05, (STEPS, 72)),
        "root_targets": own["root_targets"] + rng.uniform(-0.01, 0.01, (STEPS, 3)),
        "stiffnesses": own["stiffnesses"] * rng.uniform(0.8, 1.2, 4),
        "initial_state": own["initial_state"] + rng.uniform(-0.005, 0.005, simulator.num_dofs),
        "initial_velocity": own["initial_velocity"] + rng.uniform(-0.1, 0.1, simulator.num_dofs),
    }
    return {k: torch.tensor(v, dtype=torch.float64) for k, v in values.items()}


def simulate_with(simulator, inputs, name, vertices=False):
    """simulate() as a function of the group `name` only, the other groups fixed."""
    def f(x):
        return flsh.torch.simulate(simulator, **{**inputs, name: x}, vertices=vertices)
    return f


@pytest.mark.parametrize("contact", [False, True], ids=["free", "ground"])
@pytest.mark.parametrize("name", INPUT_NAMES)
def test_gradcheck_joints(request, name, contact, rng):
    simulator = request.getfixturevalue("grounded" if contact else "free")
    inputs = base_inputs(simulator, rng)
    x = inputs[name].clone().requires_grad_(True)
    f = simulate_with(simulator, inputs, name)
    # The analytic gradient is not zero (a gradcheck of a constant would pass trivially).
    weights = torch.tensor(rng.normal(size=(STEPS, 24, 3)))
    (grad,) = torch.autograd.grad((weights * f(x)).sum(), x)
    assert grad.abs().max() > 1e-6, name
    if name == "stiffnesses":
        # Without colliders the contact stiffness has no effect; with the ground it has.
        assert (grad[3] != 0) == contact
    # Full Jacobian: every input column against its central difference (2 rollouts each) and
    # every output row by a backward pass (T·72 of them).
    assert torch.autograd.gradcheck(f, (x,), eps=1e-6, atol=5e-9, rtol=1e-6)


@pytest.mark.parametrize("name", ["betas", "pose_targets", "initial_state"])
def test_gradcheck_vertices(grounded, name, rng):
    """SMPL vertex trajectories: β also enters them directly (shape and pose blend shapes)."""
    inputs = base_inputs(grounded, rng)
    x = inputs[name].clone().requires_grad_(True)
    f = simulate_with(grounded, inputs, name, vertices=True)
    joints, vertices = f(x)
    assert joints.shape == (STEPS, 24, 3) and vertices.shape == (STEPS, 600, 3)
    weights = torch.tensor(rng.normal(size=vertices.shape))
    (grad,) = torch.autograd.grad((weights * vertices).sum(), x)
    assert grad.abs().max() > 1e-6, name
    # Fast mode checks a random projection vᵀ(∂outputs/∂x)u of all T·(24 + V)·3 outputs; the
    # full mode every input column, on per-step projections of the vertices (T outputs, sums of
    # 1800 terms of size ~1: their central differences carry ~1e-8 of rounding).
    assert torch.autograd.gradcheck(f, (x,), eps=1e-6, atol=5e-9, rtol=1e-6, fast_mode=True)
    assert torch.autograd.gradcheck(lambda x: (weights * f(x)[1]).sum(dim=(1, 2)), (x,),
                                    eps=1e-6, atol=5e-8, rtol=1e-6)


def test_all_groups_at_once_and_defaults(grounded, rng):
    """Every group requiring grad in one call; None inputs give the simulable's own values."""
    inputs = {k: v.requires_grad_(True) for k, v in base_inputs(grounded, rng).items()}
    joints = flsh.torch.simulate(grounded, **inputs)
    joints[-1].square().sum().backward()
    for name, t in inputs.items():
        assert t.grad is not None and t.grad.shape == t.shape and t.grad.abs().max() > 0, name

    own = {k: torch.tensor(v) for k, v in grounded.own_inputs().items()}
    by_default = flsh.torch.simulate(grounded)
    explicit = flsh.torch.simulate(grounded, betas=torch.zeros(grounded.num_betas,
                                                               dtype=torch.float64), **own)
    torch.testing.assert_close(by_default, explicit, rtol=0, atol=1e-9)


def test_short_betas_are_zero_padded(free, rng):
    betas = torch.tensor(rng.uniform(-0.5, 0.5, 3), requires_grad=True)
    padded = torch.cat([betas.detach(), torch.zeros(free.num_betas - 3, dtype=torch.float64)])
    joints = flsh.torch.simulate(free, betas=betas)
    torch.testing.assert_close(joints, flsh.torch.simulate(free, betas=padded), rtol=0, atol=0)
    joints.sum().backward()
    assert betas.grad.shape == (3,) and betas.grad.abs().max() > 0


def test_no_mutation_and_interleaved_calls(grounded, body, rng):
    """Inputs, the body model and the simulator are left as they were; a forward call between
    another call's forward and backward does not change that call's gradient."""
    inputs = {k: v.requires_grad_(True) for k, v in base_inputs(grounded, rng).items()}
    before = {k: v.detach().clone() for k, v in inputs.items()}
    template = body.v_template.copy()
    default_betas = grounded.default_betas.copy()

    joints = flsh.torch.simulate(grounded, **inputs)
    first = torch.autograd.grad(joints.sum(), list(inputs.values()), retain_graph=True)
    other = {k: (v.detach() * 1.01).requires_grad_(True) for k, v in inputs.items()}
    other_joints = flsh.torch.simulate(grounded, **other)  # another rollout in between
    other_joints.sum().backward()
    second = torch.autograd.grad(joints.sum(), list(inputs.values()))
    for name, a, b in zip(inputs, first, second):
        torch.testing.assert_close(a, b, rtol=0, atol=0, msg=name)

    for name, t in inputs.items():
        assert torch.equal(t.detach(), before[name]), name
    np.testing.assert_array_equal(body.v_template, template)
    np.testing.assert_array_equal(grounded.default_betas, default_betas)
    # Same inputs, same outputs: no state carried from one call to the next.
    again = flsh.torch.simulate(grounded, **{k: v.detach() for k, v in inputs.items()})
    torch.testing.assert_close(again, joints.detach(), rtol=0, atol=0)


def test_input_errors(free, body, rng):
    T, n = STEPS, free.num_dofs
    with pytest.raises(ValueError, match=r"betas: expected dtype torch.float64, got torch.float32"):
        flsh.torch.simulate(free, betas=torch.zeros(10, dtype=torch.float32))
    with pytest.raises(ValueError, match=r"pose_targets: expected shape \(T, 72\) = \(6, 72\), "
                                         r"got \(5, 72\)"):
        flsh.torch.simulate(free, pose_targets=torch.zeros(5, 72, dtype=torch.float64))
    with pytest.raises(ValueError, match=r"initial_velocity: expected shape \(numDofs,\) = "
                                         r"\(144,\), got \(143,\)"):
        flsh.torch.simulate(free, initial_velocity=torch.zeros(n - 1, dtype=torch.float64))
    with pytest.raises(ValueError, match=r"stiffnesses: contains NaN or Inf"):
        flsh.torch.simulate(free, stiffnesses=torch.full((4,), float("nan"), dtype=torch.float64))
    with pytest.raises(ValueError, match=rf"betas: expected at most {free.num_betas} values"):
        flsh.torch.simulate(free, betas=torch.zeros(free.num_betas + 1, dtype=torch.float64))
    with pytest.raises(ValueError, match=r"root_targets: expected a torch.Tensor"):
        flsh.torch.simulate(free, root_targets=np.zeros((T, 3)))
    passive = flsh.torch.RolloutSimulator(body, None, steps=T)
    with pytest.raises(ValueError, match="no mocap"):
        flsh.torch.simulate(passive, pose_targets=torch.zeros(T, 72, dtype=torch.float64))
    with pytest.raises(TypeError, match="RolloutSimulator"):
        flsh.torch.simulate(body)
    with pytest.raises(ValueError, match="steps: expected an integer ≥ 1, got 0"):
        flsh.torch.RolloutSimulator(body, None, steps=0)


def test_training_loop_fits_pose_targets(free, rng):
    """Adam on per-step pose-target corrections so that the simulated joints match those of a
    rollout with other (unknown) targets: the loss goes down."""
    own = torch.tensor(free.own_inputs()["pose_targets"])
    arms = [flsh.smpl_joint_index(n) for n in ("left_shoulder", "right_shoulder", "left_elbow")]
    truth = own.clone()
    for j in arms:
        truth[:, 3 * j:3 * j + 3] += torch.tensor(rng.uniform(-0.4, 0.4, 3))
    with torch.no_grad():
        observed = flsh.torch.simulate(free, pose_targets=truth)

    correction = torch.zeros(STEPS, 72, dtype=torch.float64, requires_grad=True)
    optimizer = torch.optim.Adam([correction], lr=0.05)
    losses = []
    for _ in range(12):
        optimizer.zero_grad()
        joints = flsh.torch.simulate(free, pose_targets=own + correction)
        loss = (joints - observed).square().sum()
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
    assert losses[0] > 1e-4
    assert losses[-1] < 0.2 * losses[0], losses


# ---- the flsh.Rollout bindings ---------------------------------------------------------------

def test_rollout_reverse_pass_matches_forward_sensitivities(grounded, rng):
    """vᵀ(dL/dp) from backward equals dL/dq · (dq/dp · v) from forward_sensitivities."""
    rollout = grounded.rollout()
    assert rollout.num_steps == STEPS and rollout.states.shape == (STEPS, 144)
    assert all(rollout.step_info(t).factorization in ("llt", "ldlt", "lu")
               and rollout.step_info(t).cg_iterations == 0 for t in range(1, STEPS + 1))
    assert all(rollout.step_info(t).line_search_steps >= 0
               and rollout.step_info(t).psd_fallbacks >= 0 for t in range(1, STEPS + 1))
    dL_djoints = rng.normal(size=(STEPS, 24, 3))
    dL_dstates, direct = rollout.trajectory_cotangent(dL_djoints)
    grad = rollout.backward(dL_dstates, direct)
    direction = flsh.RolloutVariables(
        shape=rng.normal(size=grounded.num_betas), pose_targets=rng.normal(size=(STEPS, 72)),
        stiffnesses=rng.normal(size=4) * grounded.own_inputs()["stiffnesses"] * 1e-3,
        initial_velocity=rng.normal(size=144))
    (dq,) = rollout.forward_sensitivities([direction])
    assert abs(grad.dot(direction)) > 1e-6
    assert grad.dot(direction) == pytest.approx(float((dL_dstates * dq).sum()), rel=1e-8)
    # The joints cotangent of one step is the t_b entries of the state cotangent.
    np.testing.assert_array_equal(rollout.joints_cotangent(dL_djoints[0]), dL_dstates[0])
    # Only the groups asked for: the same values, the others None.
    some = rollout.backward(dL_dstates, direct, groups=["pose_targets", "shape"])
    np.testing.assert_allclose(some.pose_targets, grad.pose_targets, rtol=1e-12, atol=1e-300)
    np.testing.assert_allclose(some.shape, grad.shape, rtol=1e-12, atol=1e-300)
    assert some.stiffnesses is None and some.root_targets is None
    with pytest.raises(ValueError, match="unknown group 'betas'"):
        rollout.backward(dL_dstates, direct, groups=["betas"])


def test_rollout_binding_errors(grounded):
    rollout = flsh.Rollout(grounded.make_simulable(), grounded.rollout_options)
    with pytest.raises(RuntimeError, match="call run"):
        rollout.backward(np.zeros((0, 144)))
    with pytest.raises(ValueError, match=r"pose_targets: expected shape \(N, 72\), got \(3, 71\)"):
        flsh.RolloutInputs(pose_targets=np.zeros((3, 71)))
    with pytest.raises(ValueError, match=r"pose_targets .* has shape \(7, 72\), expected \(6, 72\)"):
        rollout.run(STEPS, flsh.RolloutInputs(pose_targets=np.zeros((STEPS + 1, 72))))
    with pytest.raises(ValueError, match="initial_state has 7 values, expected 144"):
        rollout.run(STEPS, flsh.RolloutInputs(initial_state=np.zeros(7)))
    rollout.run(2)
    with pytest.raises(ValueError, match=r"dL_dstates: expected shape \(2, 144\)"):
        rollout.backward(np.zeros((3, 144)))
    with pytest.raises(ValueError, match=r"dL_djoints: expected shape"):
        rollout.trajectory_cotangent(np.zeros((2, 23, 3)))
    with pytest.raises(ValueError, match="t: expected a step in 1..2, got 3"):
        rollout.step_info(3)
