"""The simulation core from Python: SoftAvatar, Collider, Simulable (the FLSH paper's runtime
API), Scene and newton_solve, against the same quantities computed another way (finite
differences, the C++ Newton solver against a Newton loop written in Python), and the
examples under examples/python."""
import gc
import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse

import flsh

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples" / "python"
NUM_DOFS = 6 * 24


@pytest.fixture(scope="module")
def avatar():
    """A small (600-vertex) synthetic avatar with its skeleton data, built once."""
    a = flsh.SoftAvatar(flsh.make_synthetic_body(vertices=600))
    a.init_volumetric_data()
    return a


def ground(avatar):
    return flsh.Collider.plane(point=[0.0, avatar.rest_vertices[:, 1].min(), 0.0],
                               normal=[0.0, 1.0, 0.0])


def make_simulable(avatar, motion, **options):
    sim = flsh.Simulable(avatar, motion, flsh.SimulableOptions(**options))
    sim.setColliders([ground(avatar)])
    sim.initialize()
    return sim


def stepped(avatar, walk, rng, steps=3):
    """A simulable a few steps into the walk, moved off its equilibrium by a random increment
    (so that inertia, springs and ground contact all contribute)."""
    sim = make_simulable(avatar, walk)
    for _ in range(steps):
        sim.preUpdate()
        sim.postUpdate()
    sim.preUpdate()
    dq = rng.normal(0.0, 0.02, NUM_DOFS)
    dq[1::6] -= 0.03  # every bone 3 cm down, the feet into the ground: contacts
    sim.updateState(dq)
    return sim


def load_example(name):
    spec = importlib.util.spec_from_file_location(name, EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


# --- SoftAvatar ----------------------------------------------------------------------------


def test_avatar_data_shapes_and_mass(avatar):
    assert avatar.initialized
    assert avatar.rest_vertices.shape == (600, 3)
    assert avatar.rest_joints.shape == (24, 3)
    assert avatar.vertex_areas.shape == (600,)
    inertia = avatar.bone_inertia
    assert len(inertia) == 24 and len(avatar.bone_capsules) == 24
    masses = np.array([b.mass for b in inertia])
    assert np.all(masses >= 0) and avatar.total_mass == pytest.approx(masses.sum())
    # A human-sized body of water-like density: tens of kilograms, volume × density.
    assert 20.0 < avatar.total_mass < 200.0
    assert avatar.total_mass == pytest.approx(avatar.volume * avatar.density, rel=0.05)
    for b in inertia:
        assert b.first_moment.shape == (3,)
        assert b.second_moment.shape == (3, 3)
        np.testing.assert_allclose(b.second_moment, b.second_moment.T, atol=1e-12)


def test_avatar_settings_have_paper_aliases(avatar):
    for snake, camel in [("enable_soft_tissue", "enableSoftTissue"),
                         ("enable_reduced_model", "enableReducedModel"),
                         ("enable_inertial_cubature", "enableInertialCubature"),
                         ("enable_elastic_cubature", "enableElasticCubature"),
                         ("init_volumetric_data", "initVolumetricData")]:
        assert callable(getattr(flsh.SoftAvatar, snake)) and callable(getattr(flsh.SoftAvatar, camel))
    fresh = flsh.SoftAvatar(avatar.body, np.zeros(3), density=1000.0, voxel_size=0.02)
    with pytest.raises(ValueError, match="rest_vertices: the avatar is not initialized"):
        fresh.rest_vertices
    fresh.enableSoftTissue()
    fresh.enableReducedModel()
    assert fresh.soft_tissue_enabled and fresh.reduced_model_enabled
    fresh.enable_soft_tissue(False)
    with pytest.raises(ValueError, match="soft tissue is off"):
        fresh.initVolumetricData()  # the reduced model is a soft-tissue model
    fresh.enable_reduced_model(False)
    fresh.initVolumetricData()
    assert not fresh.has_volumetric_data
    with pytest.raises(RuntimeError, match="soft tissue is off"):
        fresh.volumetric_data
    assert fresh.initialized and fresh.total_mass > 0
    with pytest.raises(ValueError, match="betas: expected shape"):
        flsh.SoftAvatar(avatar.body, np.zeros((2, 2)))


# --- Collider ------------------------------------------------------------------------------


def test_collider_signed_distances_and_derivatives(rng):
    sphere = flsh.Collider.sphere([0.0, 1.0, 0.0], 0.5)
    assert sphere.signed_distance([0.0, 2.0, 0.0]) == pytest.approx(0.5)
    plane = flsh.Collider.plane([0.0, -1.0, 0.0], [0.0, 2.0, 0.0])
    np.testing.assert_allclose(plane.p1, [0.0, 1.0, 0.0])
    capsule = flsh.Collider.capsule([0, 0, 0], [1, 0, 0], 0.2)
    points = rng.normal(0.0, 1.0, (20, 3))
    for collider in (sphere, plane, capsule):
        d, grad, hess = collider.signed_distance(points, 0.0, derivatives=True)
        assert d.shape == (20,) and grad.shape == (20, 3) and hess.shape == (20, 3, 3)
        assert np.abs(grad).max() > 0.5
        for i in range(3):
            scalar = collider.signed_distance(points[i])
            assert scalar == pytest.approx(d[i])
            eps = 1e-6
            fd = [(collider.signed_distance(points[i] + eps * e) -
                   collider.signed_distance(points[i] - eps * e)) / (2 * eps) for e in np.eye(3)]
            np.testing.assert_allclose(grad[i], fd, atol=1e-6)


def test_collider_path_moves_the_collider():
    ball = flsh.Collider.sphere([0.0, 0.0, 1.0], 0.1)
    ball.path = flsh.ColliderPath.constant_velocity([0.0, 0.0, -2.0], 1.0)
    np.testing.assert_allclose(ball.path.offset_at(0.25), [0.0, 0.0, -0.5])
    np.testing.assert_allclose(ball.path.velocity_at(0.25), [0.0, 0.0, -2.0])
    assert ball.signed_distance([0.0, 0.0, 0.5], 0.25) == pytest.approx(-0.1)
    keyed = flsh.ColliderPath([0.0, 1.0], [[0, 0, 0], [1, 0, 0]])
    np.testing.assert_allclose(keyed.offset_at(0.5), [0.5, 0, 0])
    with pytest.raises(ValueError, match=r"offsets: expected shape \(2, 3\), got \(3, 3\)"):
        flsh.ColliderPath([0.0, 1.0], np.zeros((3, 3)))
    with pytest.raises(ValueError, match="ColliderPath"):
        flsh.ColliderPath([1.0, 0.0], np.zeros((2, 3)))  # times not increasing
    with pytest.raises(ValueError, match="radius"):
        flsh.Collider.sphere([0, 0, 0], -1.0)


# --- Simulable: state ------------------------------------------------------------------------


def test_tracking_inertia_floor_reaches_the_toe_spring(avatar, walk):
    # Without gravity, rotating a toe (a leaf: only its own tracking spring sees its rotation) by
    # θ from its target at the first frame costs ½ ω_T² (I_toe + floor) θ²: the floor adds
    # ½ ω_T² Δ θ².
    assert flsh.SimulableOptions().tracking_inertia_floor == 0.01
    theta, delta = 0.1, 0.05
    costs = []
    for floor in (0.0, delta):
        options = flsh.SimulableOptions(tracking_inertia_floor=floor, gravity=[0.0, 0.0, 0.0])
        assert options.tracking_inertia_floor == floor
        sim = flsh.Simulable(avatar, walk, options)
        sim.initialize()
        e0 = sim.getPotentialEnergyScalar()
        dq = np.zeros(sim.numDofs())
        dq[6 * 10 + 3] = theta
        sim.updateState(dq)
        costs.append(sim.getPotentialEnergyScalar() - e0)
    assert costs[0] > 0.0
    expected = 0.5 * flsh.SimulableOptions().tracking_stiffness * delta * theta**2
    assert costs[1] - costs[0] == pytest.approx(expected, rel=1e-9)


def test_state_round_trips_through_set_state(avatar, walk, rng):
    sim = stepped(avatar, walk, rng)
    q = sim.getState()
    assert q.shape == (NUM_DOFS,) and q.dtype == np.float64
    vertices = sim.getVertices()
    sim.updateState(rng.normal(0.0, 0.1, NUM_DOFS))
    assert np.abs(sim.getState() - q).max() > 1e-3
    sim.setState(q)
    np.testing.assert_allclose(sim.getState(), q, atol=1e-12)
    np.testing.assert_allclose(sim.getVertices(), vertices, atol=1e-12)
    v = rng.normal(0.0, 0.3, NUM_DOFS)
    sim.setVelocity(v)
    np.testing.assert_allclose(sim.getVelocity(), v, atol=1e-9)


def test_push_pop_round_trip_exactly(avatar, walk, rng):
    sim = stepped(avatar, walk, rng)
    q, energy = sim.getState(), sim.getPotentialEnergyScalar()
    sim.pushState()
    sim.updateState(rng.normal(0.0, 0.2, NUM_DOFS))
    assert sim.getPotentialEnergyScalar() != energy
    sim.popState()
    np.testing.assert_array_equal(sim.getState(), q)
    assert sim.getPotentialEnergyScalar() == energy
    with pytest.raises(RuntimeError, match="popState"):
        sim.popState()


def test_outputs_shapes(avatar, walk, rng):
    sim = stepped(avatar, walk, rng)
    assert sim.num_dofs == sim.numDofs() == NUM_DOFS
    assert sim.getPose().shape == (72,) and sim.getTrans().shape == (3,)
    assert sim.getVertices().shape == (600, 3) and sim.getNodes().shape == (600, 3)
    assert sim.bone_rotations.shape == (24, 3, 3) and sim.bone_positions.shape == (24, 3)
    assert sim.time == pytest.approx(4 / 60)
    assert sim.avatar.total_mass == avatar.total_mass
    # snake_case aliases are the same functions
    assert flsh.Simulable.get_state is flsh.Simulable.getState
    assert flsh.Simulable.get_potential_hessian_triplet_vector is \
        flsh.Simulable.getPotentialHessianTripletVector


def shifted_energy(sim, energy, dq):
    sim.pushState()
    sim.updateState(dq)
    value = energy()
    sim.popState()
    return value


def directional_difference(sim, function, d, eps=1e-6):
    sim.pushState()
    sim.updateState(eps * d)
    plus = function()
    sim.popState()
    sim.pushState()
    sim.updateState(-eps * d)
    minus = function()
    sim.popState()
    return (plus - minus) / (2 * eps)


def test_state_jacobian_matches_finite_differences(avatar, walk, rng):
    sim = stepped(avatar, walk, rng)
    J = sim.getStateJacobian()
    assert J.shape == (75, NUM_DOFS)
    d = rng.normal(0.0, 1.0, NUM_DOFS)
    analytic = J @ d
    assert np.abs(analytic).max() > 0.1
    fd = directional_difference(sim, lambda: np.concatenate([sim.getPose(), sim.getTrans()]), d)
    np.testing.assert_allclose(analytic, fd, atol=1e-6 * np.abs(analytic).max())

    N = sim.getNodesStateJacobian()
    assert scipy.sparse.issparse(N) and N.shape == (3 * 600, NUM_DOFS)
    analytic = N @ d
    assert np.abs(analytic).max() > 0.1
    fd = directional_difference(sim, lambda: sim.getNodes().ravel(), d)
    np.testing.assert_allclose(analytic, fd, atol=1e-6 * np.abs(analytic).max())


# --- Simulable: energies ---------------------------------------------------------------------


@pytest.mark.parametrize("term", ["Dynamic", "Potential"])
def test_gradient_matches_finite_differences_of_the_energy(avatar, walk, rng, term):
    sim = stepped(avatar, walk, rng)
    energy = getattr(sim, f"get{term}EnergyScalar")
    g = getattr(sim, f"get{term}GradientVector")()
    sim.getPotentialEnergyScalar()
    assert sim.active_contacts > 0  # the ground pushes: contact terms are in the check
    assert g.shape == (NUM_DOFS,)
    assert np.abs(g).max() > 1e-3  # a zero gradient would pass any comparison
    q = sim.getState()
    fd = np.array([directional_difference(sim, energy, e) for e in np.eye(NUM_DOFS)])
    np.testing.assert_allclose(g, fd, rtol=0, atol=1e-5 * max(1.0, np.abs(g).max()))
    np.testing.assert_array_equal(sim.getState(), q)  # derivatives leave the state alone


@pytest.mark.parametrize("term", ["Dynamic", "Potential"])
def test_hessians_are_symmetric_and_match_second_differences(avatar, walk, rng, term):
    sim = stepped(avatar, walk, rng)
    q = sim.getState()
    hessian = getattr(sim, f"get{term}HessianTripletVector")
    for psd in (True, False):
        H = hessian(psd=psd)
        assert isinstance(H, scipy.sparse.csc_matrix) and H.shape == (NUM_DOFS, NUM_DOFS)
        assert abs(H).max() > 1.0
        assert abs(H - H.T).max() <= 1e-10 * abs(H).max()
    np.testing.assert_array_equal(sim.getState(), q)
    dense_psd = hessian(psd=True).toarray()
    assert np.linalg.eigvalsh(dense_psd).min() >= -1e-8 * np.abs(dense_psd).max()
    # The exact Hessian along a straight line of the increment chart: dᵀHd = d²E/dε².
    energy = getattr(sim, f"get{term}EnergyScalar")
    H = hessian(psd=False)
    for _ in range(3):
        d = rng.normal(0.0, 1.0, NUM_DOFS)
        eps = 1e-4
        plus, minus = (shifted_energy(sim, energy, s * eps * d) for s in (1, -1))
        second = (plus - 2 * energy() + minus) / eps**2
        assert d @ (H @ d) == pytest.approx(second, rel=1e-4, abs=1e-6 * abs(H).max())


def test_kinematic_dofs_are_fixed(avatar, walk, rng):
    sim = make_simulable(avatar, walk, kinematic_bones=[0, 3])
    sim.preUpdate()
    g = rng.normal(0.0, 1.0, NUM_DOFS)
    fixed = sim.fixVectorKinematic(g)
    kinematic = np.r_[0:6, 18:24]
    assert np.all(fixed[kinematic] == 0.0)
    np.testing.assert_array_equal(np.delete(fixed, kinematic), np.delete(g, kinematic))
    H = sim.getPotentialHessianTripletVector() + sim.getDynamicHessianTripletVector()
    F = sim.fixMatrixKinematic(H).toarray()
    np.testing.assert_array_equal(F[kinematic][:, kinematic], np.eye(len(kinematic)))
    assert np.all(F[kinematic][:, np.delete(np.arange(NUM_DOFS), kinematic)] == 0.0)
    free = np.delete(np.arange(NUM_DOFS), kinematic)
    np.testing.assert_allclose(F[np.ix_(free, free)], H.toarray()[np.ix_(free, free)])
    np.testing.assert_array_equal(sim.fixMatrixKinematic(H.toarray()).toarray(), F)  # dense in


def test_bad_arrays_raise_value_errors_naming_shapes(avatar, walk, rng):
    sim = make_simulable(avatar, walk)
    with pytest.raises(ValueError, match=r"q: expected shape \(144,\), got \(10,\)"):
        sim.setState(np.zeros(10))
    q = sim.getState()
    q[5] = np.nan
    with pytest.raises(ValueError, match="q: contains NaN or Inf"):
        sim.setState(q)
    with pytest.raises(ValueError, match=r"dq: expected shape \(144,\), got \(144, 1\)"):
        sim.updateState(np.zeros((144, 1)))
    with pytest.raises(ValueError, match="v: expected a float or integer array, got dtype"):
        sim.setVelocity(np.array(["a"] * 144))
    with pytest.raises(ValueError, match=r"H: expected shape \(144, 144\), got \(10, 10\)"):
        sim.fixMatrixKinematic(scipy.sparse.eye(10))
    with pytest.raises(ValueError, match=r"g: expected shape \(144,\)"):
        sim.fixVectorKinematic(np.zeros(3))
    with pytest.raises(ValueError, match="time_step"):
        flsh.SimulableOptions(time_step=0.0)
    with pytest.raises(ValueError, match="tracking_inertia_floor"):
        flsh.SimulableOptions(tracking_inertia_floor=-0.01)
    with pytest.raises(ValueError, match="not initialized"):
        flsh.Simulable(flsh.SoftAvatar(avatar.body))
    with pytest.raises(ValueError, match="body model passed is not the avatar's"):
        flsh.Simulable(avatar, flsh.make_synthetic_body(vertices=200), walk)


def test_absurd_finite_state_values_raise_value_errors(avatar, walk):
    # Issue 23: set_velocity(1e300) and a Scene step left the state NaN without an exception.
    sim = flsh.Simulable(avatar, walk)
    scene = flsh.Scene()
    scene.add_simulable(sim)
    scene.initialize()
    q0 = sim.getState()
    with pytest.raises(ValueError, match=r"setVelocity: v\[0\] = 1e\+300 m/s or rad/s, "
                                         r"expected within \[-10000, 10000\]"):
        sim.set_velocity(np.full(NUM_DOFS, 1e300))
    q = q0.copy()
    q[4] = 1e300
    with pytest.raises(ValueError, match="bone 0 has a rotation vector of angle 1e\\+300 rad"):
        sim.setState(q)
    q = q0.copy()
    q[1] = -1e300
    with pytest.raises(ValueError, match=r"q\[1\] = -1e\+300 m"):
        sim.setState(q)
    np.testing.assert_array_equal(sim.getState(), q0)  # untouched by the refused calls
    # The largest velocity accepted steps to a finite state.
    sim.set_velocity(np.full(NUM_DOFS, 1e4))
    scene.step()
    assert np.isfinite(sim.getState()).all()


# --- Scene and Newton -------------------------------------------------------------------------


def test_scene_matches_a_python_newton_loop(avatar, walk):
    # Solved tightly, the C++ Newton (exact Hessian first) and the Python loop of the example
    # (positive-semidefinite Hessian) must reach the same minimizer of each step.
    own_newton = load_example("own_newton")
    tight = flsh.NewtonOptions(max_iterations=100, gradient_tolerance=1e-11, step_tolerance=1e-13)
    scene = flsh.Scene(flsh.SceneOptions(newton=tight))
    in_scene = flsh.Simulable(avatar, walk)
    scene.add_simulable(in_scene)
    scene.add_collider(ground(avatar))
    scene.initialize()
    by_hand = make_simulable(avatar, walk)
    for _ in range(6):
        stats = scene.step()
        converged, _ = own_newton.newton_step(by_hand, max_iterations=300,
                                              gradient_tolerance=1e-11, step_tolerance=1e-13)
        assert stats.newton.converged and converged
    assert stats.active_contacts > 0 and in_scene.active_contacts > 0
    assert scene.time == pytest.approx(by_hand.time)
    moved = np.abs(in_scene.getState() - make_simulable(avatar, walk).getState()).max()
    assert moved > 1e-3
    np.testing.assert_allclose(by_hand.getState(), in_scene.getState(), atol=1e-7)


def test_scene_objective_and_newton_solve(avatar, walk):
    scene = flsh.Scene(flsh.SceneOptions(newton=flsh.NewtonOptions(max_iterations=40)))
    a, b = flsh.Simulable(avatar, walk), flsh.Simulable(avatar, walk)
    scene.add_simulable(a)
    scene.add_simulable(b)
    scene.add_collider(ground(avatar))
    scene.initialize()
    assert scene.num_dofs == 2 * NUM_DOFS and scene.offset(0) == 0 and scene.offset(1) == NUM_DOFS
    assert scene.simulables[1] is b
    with pytest.raises(IndexError):
        scene.offset(2)
    for s in (a, b):
        s.preUpdate()
    separate = sum(s.getDynamicEnergyScalar() + s.getPotentialEnergyScalar() for s in (a, b))
    # Both avatars stand in the same place: avatar–avatar contact adds to the sum.
    start_energy = scene.energy()
    assert start_energy > separate
    g = scene.gradient()
    H = scene.hessian()
    assert g.shape == (2 * NUM_DOFS,) and H.shape == (2 * NUM_DOFS, 2 * NUM_DOFS)
    assert abs(H - H.T).max() <= 1e-10 * abs(H).max()
    result = flsh.newton_solve(scene)
    assert result.converged, result.message
    assert result.energy < start_energy
    assert result.energy == pytest.approx(scene.energy())
    assert np.abs(scene.gradient()).max() <= 1e-5 * max(1.0, np.abs(g).max())
    with pytest.raises(ValueError, match="dq: expected shape"):
        scene.apply_increment(np.zeros(3))


def test_simulable_keeps_avatar_and_mocap_alive():
    def build():
        a = flsh.SoftAvatar(flsh.make_synthetic_body(vertices=400))
        a.init_volumetric_data()
        return flsh.Simulable(a, flsh.make_builtin_motion("walk", seconds=0.5))

    sim = build()
    gc.collect()
    scene = flsh.Scene()
    scene.add_simulable(sim)
    del sim
    gc.collect()
    scene.initialize()
    stats = scene.step()
    assert stats.newton.converged
    assert scene.simulables[0].avatar.rest_vertices.shape == (400, 3)


def test_scene_files():
    spec = flsh.load_scene_file(ROOT / "examples" / "scenes" / "default.json", duration=0.5)
    assert spec.duration == 0.5 and len(spec.avatars) == 1 and len(spec.colliders) == 2
    assert spec.avatars[0].motion == "builtin:walk"
    assert spec.colliders[1].shape == flsh.ColliderShape.Sphere
    default = flsh.default_scene(duration=1.0)
    assert default.duration == 1.0 and default.avatars[0].name
    with pytest.raises(FileNotFoundError):
        flsh.load_scene_file(ROOT / "no_such_scene.json")
    rom = flsh.load_scene_file(ROOT / "examples" / "scenes" / "soft_rom_jumping_jacks.json")
    assert rom.avatars[0].simulation == "rom"
    assert rom.avatars[0].basis == "modes" and rom.avatars[0].vibration_modes == 24
    assert rom.avatars[0].modal_columns == 72 and rom.avatars[0].elastic_cubature == 500
    assert rom.avatars[0].inertial_cubature == 500 and rom.avatars[0].resolution > 0
    assert rom.reduced_gradient_tolerance > 0
    realtime = flsh.load_scene_file(ROOT / "examples" / "scenes" / "rom_realtime_walk.json")
    assert realtime.preset == "realtime" and realtime.reduced_iteration_budget == 3
    assert (realtime.avatars[0].basis, realtime.avatars[0].modal_columns) == ("modes", 24)
    assert rom.preset == "none" and rom.reduced_iteration_budget == 0
    # Lagged-factor settings: each soft solver's defaults unless the file sets them.
    lagged = default.soft_tissue_lagged
    assert lagged.enabled and lagged.cg_relative_tolerance == 0.05
    assert default.reduced_lagged.cg_relative_tolerance == 0.01


# --- examples -------------------------------------------------------------------------------


@pytest.mark.parametrize("name,args", [
    ("track_motion", ["--seconds", "0.1", "--vertices", "600", "--sheet-frames", "2"]),
    ("own_newton", ["--seconds", "0.1", "--vertices", "600"]),
    ("ball_belly", ["--seconds", "0.25", "--speed", "4", "--vertices", "600",
                    "--sheet-frames", "2"]),
    ("ball_belly", ["--seconds", "0.25", "--speed", "4", "--vertices", "600",
                    "--sheet-frames", "2", "--soft", "--resolution", "0.3"]),
])
def test_examples_run(tmp_path, name, args):
    env = dict(os.environ)
    if "--soft" in args:
        args = [*args, "--cache", str(tmp_path / "cache")]
    result = subprocess.run([sys.executable, str(EXAMPLES / f"{name}.py"), "--out", str(tmp_path),
                             *args], env=env, capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert "wrote" in result.stdout and "did not converge" not in result.stdout
    image = flsh.read_png(tmp_path / "sheet.png")
    assert image.width > 0 and image.height > 0
    if name == "ball_belly":
        assert "pushed back" in result.stdout
    if "--soft" in args:
        # The ball dents the soft belly: a displacement of at least a millimetre.
        line = next(l for l in result.stdout.splitlines() if l.startswith("soft tissue"))
        assert float(line.split("|u|")[1].split("mm")[0]) > 1.0, line


def test_newton_options_and_discard_state(avatar, walk):
    options = flsh.NewtonOptions(exact_hessian=False, linear_solver=flsh.LinearSolverType.SparseLLT)
    assert options.exact_hessian is False and options.linear_solver == flsh.LinearSolverType.SparseLLT
    scene = flsh.Scene(flsh.SceneOptions(newton=options))
    sim = flsh.Simulable(avatar, walk)
    scene.add_simulable(sim)
    scene.add_collider(ground(avatar))
    scene.initialize()
    stats = scene.step()
    assert stats.newton.converged and stats.newton.psd_fallbacks == 0
    # Plain Newton on the PSD form: one assembly and one factorization per iteration, no CG.
    assert stats.newton.hessian_evaluations == stats.newton.iterations
    assert stats.newton.factorizations >= stats.newton.iterations
    assert stats.newton.cg_iterations == 0
    before = sim.getState()
    sim.pushState()
    sim.updateState(np.full(sim.num_dofs, 1e-3))
    sim.discardState()  # keeps the moved state
    assert np.abs(sim.getState() - before).max() > 5e-4
    with pytest.raises(RuntimeError):
        sim.discardState()
