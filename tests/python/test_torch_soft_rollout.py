"""flsh.torch.simulate through the soft skeletons (model="fem" and "rom", the ROM with the handle
basis and with modes and handles, "rom_modes"): torch.autograd.gradcheck
on the input groups (pose and root targets, stiffnesses, initial state and velocity, the soft
state included, the material coefficients, β), on joints and on the simulated surface, with
ground contact. A 800-vertex synthetic body with a coarse interior walking for T = 4 steps; the
FEM's large groups are checked by random projections (fast_mode), its small ones column by
column."""
import numpy as np
import pytest
import torch

import flsh
import flsh.torch

STEPS = 4


@pytest.fixture(scope="module")
def simulators(body, walk, tmp_path_factory):
    """FEM and ROM simulators of the small soft avatar (conftest's 800-vertex body), with a
    ground plane 1 cm above the lowest surface node of the walk's initial state. "rom_modes":
    the ROM with modes and handles (the static modes and 6 vibration modes in 24 columns),
    converged to a gradient of 1e-12 instead of the default 1e-10: at 1e-10 its rollouts differ
    by up to ~1e-10 in the weighted surface sums, which central differences over 2e-4 turn into
    ~1e-6 (β: 9e-7 at 1e-4 against 1.7e-9 at 1e-12)."""
    cache = tmp_path_factory.mktemp("soft_cache")
    settings = dict(handles=16, elastic_cubature_points=60, inertial_cubature_points=60,
                    cubature_training_samples=80)
    modal = dict(settings, basis="modes+handles", vibration_modes=6, modal_columns=24)
    tight = flsh.RolloutOptions().reduced_newton
    tight.gradient_tolerance = 1e-12
    tight.max_iterations = 100
    out = {}
    for name, model, kwargs, newton in (("fem", "fem", settings, None),
                                        ("rom", "rom", settings, None),
                                        ("rom_modes", "rom", modal, tight)):
        free = flsh.torch.RolloutSimulator(body, walk, steps=STEPS, model=model, voxel_size=0.02,
                                           resolution=0.5, cache_dir=cache,
                                           avatar_settings=kwargs)
        sim = free.make_simulable()
        sim.initialize()
        lowest = sim.get_nodes()[:, 1].min()
        ground = flsh.Collider.plane(point=[0.0, lowest + 0.01, 0.0], normal=[0.0, 1.0, 0.0])
        out[name] = flsh.torch.RolloutSimulator(
            body, walk, steps=STEPS, model=model, voxel_size=0.02, resolution=0.5,
            cache_dir=cache, avatar_settings=kwargs, colliders=[ground], newton=newton)
    return out


def base_inputs(simulator, rng):
    """Every input group near the simulable's own values, the soft state moving a little."""
    own = simulator.own_inputs()
    n = simulator.num_dofs
    state = own["initial_state"] + np.concatenate(
        [rng.uniform(-0.005, 0.005, 144), rng.uniform(-2e-4, 2e-4, n - 144)])
    velocity = own["initial_velocity"] + np.concatenate(
        [rng.uniform(-0.1, 0.1, 144), rng.uniform(-0.005, 0.005, n - 144)])
    values = {
        "pose_targets": own["pose_targets"] + rng.uniform(-0.05, 0.05, (STEPS, 72)),
        "root_targets": own["root_targets"] + rng.uniform(-0.01, 0.01, (STEPS, 3)),
        "stiffnesses": own["stiffnesses"] * rng.uniform(0.8, 1.2, 4),
        "initial_state": state,
        "initial_velocity": velocity,
    }
    return {k: torch.tensor(v, dtype=torch.float64) for k, v in values.items()}


def simulate_with(simulator, inputs, name, vertices=False):
    def f(x):
        return flsh.torch.simulate(simulator, **{**inputs, name: x}, vertices=vertices)
    return f


@pytest.mark.parametrize("model", ["fem", "rom"])
@pytest.mark.parametrize("name", ["pose_targets", "root_targets", "stiffnesses", "initial_state",
                                  "initial_velocity"])
def test_gradcheck_joints(simulators, model, name, rng):
    simulator = simulators[model]
    assert simulator.num_dofs > 144  # the soft state follows the bones
    inputs = base_inputs(simulator, rng)
    x = inputs[name].clone().requires_grad_(True)
    f = simulate_with(simulator, inputs, name)
    weights = torch.tensor(rng.normal(size=(STEPS, 24, 3)))
    (grad,) = torch.autograd.grad((weights * f(x)).sum(), x)
    assert grad.abs().max() > 1e-6, name
    if name in ("initial_state", "initial_velocity"):
        assert grad[144:].abs().max() > 0, "the soft state reaches the joints"
    # Column by column where that is cheap (the ROM; the FEM's stiffnesses and root targets),
    # else random projections. The soft models' Newton (relative tolerance 1e-10, lagged
    # factor) leaves up to ~2e-12 m in a joint between two nearby rollouts, which a central
    # difference over 2e-4 turns into ~1e-8 (the same offset in every column of that joint;
    # over 2e-6 it would be ~1e-6): steps of 1e-4 and atol 5e-8.
    fast = model == "fem" and x.numel() > 12
    assert torch.autograd.gradcheck(f, (x,), eps=1e-4, atol=5e-8, rtol=1e-5, fast_mode=fast)


@pytest.mark.parametrize("model", ["fem", "rom"])
def test_gradcheck_surface(simulators, model, rng):
    """The simulated surface: it moves with the soft state and with the pose blend held from
    the previous step."""
    simulator = simulators[model]
    inputs = base_inputs(simulator, rng)
    x = inputs["pose_targets"].clone().requires_grad_(True)
    f = simulate_with(simulator, inputs, "pose_targets", vertices=True)
    joints, vertices = f(x)
    assert vertices.shape == (STEPS, 800, 3)
    weights = torch.tensor(rng.normal(size=vertices.shape))
    (grad,) = torch.autograd.grad((weights * vertices).sum(), x)
    assert grad.abs().max() > 1e-6
    assert torch.autograd.gradcheck(lambda x: (weights * f(x)[1]).sum(dim=(1, 2)), (x,),
                                    eps=1e-4, atol=5e-8, rtol=1e-5, fast_mode=True)


@pytest.mark.parametrize("model", ["fem", "rom", "rom_modes"])
def test_gradcheck_material(simulators, model, rng):
    """The material coefficients, on the surface and the joints: gradcheck on a few log-values
    (soft-tissue and skin moduli, densities, the Fung exponent; the vector's other entries
    fixed at the avatar's own)."""
    simulator = simulators[model]
    own = simulator.own_material()
    names = simulator.material_names()
    assert len(names) == len(own) == 40 * (1 + simulator.num_betas)
    picked = [names.index(f"layers.{layer}.{q}.log_value")
              for layer, q in (("soft_tissue", "E1"), ("soft_tissue", "density"),
                               ("soft_tissue", "fung_gamma"), ("skin", "G12"))]
    base = torch.tensor(own, dtype=torch.float64)
    inputs = base_inputs(simulator, rng)
    weights = torch.tensor(rng.normal(size=(STEPS, 800, 3)))

    def f(x):
        material = base.index_put((torch.tensor(picked),), base[picked] + x)
        joints, vertices = flsh.torch.simulate(simulator, **inputs, material=material,
                                               vertices=True)
        return torch.cat([(weights * vertices).sum(dim=(1, 2)), joints.reshape(-1)[:12]])

    x = torch.zeros(len(picked), dtype=torch.float64, requires_grad=True)
    (grad,) = torch.autograd.grad(f(x).sum(), x)
    assert grad.abs().max() > 1e-6
    assert torch.autograd.gradcheck(f, (x,), eps=1e-4, atol=5e-8, rtol=1e-5)


def test_material_is_for_soft_models_only(body, walk, simulators):
    skeleton = flsh.torch.RolloutSimulator(body, walk, steps=2)
    with pytest.raises(ValueError, match="material"):
        skeleton.own_material()
    simulator = simulators["fem"]
    with pytest.raises(ValueError, match="material"):
        flsh.torch.simulate(simulator, material=torch.zeros(3, dtype=torch.float64))


@pytest.mark.parametrize("model", ["fem", "rom", "rom_modes"])
def test_gradcheck_betas(simulators, model, rng):
    """β through the soft tissue (rest nodes, masses, materials, joints, the simulated surface),
    on the surface and the joints: the avatar at β keeps the default one's discretization."""
    simulator = simulators[model]
    inputs = base_inputs(simulator, rng)
    weights = torch.tensor(rng.normal(size=(STEPS, 800, 3)))

    def f(betas):
        joints, vertices = flsh.torch.simulate(simulator, betas=betas, **inputs, vertices=True)
        return torch.cat([(weights * vertices).sum(dim=(1, 2)), joints.reshape(-1)[:12]])

    x = torch.tensor(rng.uniform(-0.5, 0.5, 3), dtype=torch.float64, requires_grad=True)
    (grad,) = torch.autograd.grad(f(x).sum(), x)
    assert grad.abs().max() > 1e-6
    assert torch.autograd.gradcheck(f, (x,), eps=1e-4, atol=5e-8, rtol=1e-5)


def test_unknown_model_is_refused(body):
    with pytest.raises(ValueError, match="model"):
        flsh.torch.RolloutSimulator(body, steps=2, model="spring")


def test_rollout_options_tape_storage():
    options = flsh.RolloutOptions()
    assert options.tape_storage == "auto"
    options.tape_storage = "snapshots"
    assert options.tape_storage == "snapshots"
    with pytest.raises(ValueError, match="tape_storage"):
        options.tape_storage = "disk"


def test_rollout_options_tape_solve():
    options = flsh.RolloutOptions()
    solve = options.tape_solve
    assert solve.iterative and solve.relative_tolerance == 1e-12
    assert solve.max_iterations == 60 and solve.refactor_after_iterations == 25
    assert solve.max_right_hand_sides == 3
    solve.iterative = False
    solve.max_iterations = 7
    options.tape_solve = solve
    assert not options.tape_solve.iterative and options.tape_solve.max_iterations == 7
    assert "iterative=False" in repr(options.tape_solve)


def test_rollout_checks_tape_solve(body, walk):
    avatar = flsh.SoftAvatar(body)
    avatar.init_volumetric_data()
    options = flsh.RolloutOptions()
    solve = options.tape_solve
    solve.relative_tolerance = 2.0
    options.tape_solve = solve
    sim = flsh.Simulable(avatar, walk)
    with pytest.raises(ValueError, match="relative_tolerance must be in \\(0, 1\\)"):
        flsh.Rollout(sim, options)
