"""The ROM soft skeleton from Python (docs/rom.md): SoftAvatar's reduced settings and data
(handles, bounded biharmonic basis as scipy.sparse, cubatures with held-out errors, the cache
level), the reduced state of Simulable (one z_h per handle, u_j = Σ_h φ_h(j) z_h read back by
node_displacement_basis and get_soft_tissue_displacements), a few steps in a Scene with the
reduced Newton, and the errors."""
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse

import flsh

NUM_BONE_DOFS = 6 * 24
HANDLES = 12
EXAMPLES = Path(__file__).resolve().parents[2] / "examples" / "python"


def _rom_avatar(body, cache_dir, elastic=True, inertial=True, handles=HANDLES, pou=False):
    """A ROM avatar on a coarse tet mesh with small cubatures (fast to build)."""
    avatar = flsh.SoftAvatar(body, resolution=0.3, cache_dir=str(cache_dir), handles=handles,
                             elastic_cubature_points=40, inertial_cubature_points=30,
                             cubature_training_samples=60, surface_partition_of_unity=pou)
    avatar.enable_soft_tissue()
    avatar.enable_reduced_model()
    avatar.enable_elastic_cubature(elastic)
    avatar.enable_inertial_cubature(inertial)
    avatar.init_volumetric_data()
    return avatar


@pytest.fixture(scope="module")
def small_body():
    return flsh.make_synthetic_body(vertices=600)


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("rom_cache")


@pytest.fixture(scope="module")
def avatar(small_body, cache_dir):
    return _rom_avatar(small_body, cache_dir)


@pytest.fixture
def rom(avatar):
    """A ROM simulable at rest (a fresh one per test: tests change its state)."""
    sim = flsh.Simulable(avatar, options=flsh.SimulableOptions(time_step=1.0 / 30.0))
    sim.initialize()
    return sim


def test_settings_are_keyword_arguments_with_the_documented_defaults(small_body):
    plain = flsh.SoftAvatar(small_body)
    assert plain.basis == "modes" and plain.vibration_modes == 24 and plain.modal_columns == 72
    assert plain.handles == 87  # of the handle basis
    assert plain.elastic_cubature_points == 500 and plain.inertial_cubature_points == 500
    assert not plain.reduced_model_enabled
    assert not plain.elastic_cubature_enabled and not plain.inertial_cubature_enabled
    custom = flsh.SoftAvatar(small_body, handles=5, elastic_cubature_points=7,
                             inertial_cubature_points=9)
    assert (custom.handles, custom.elastic_cubature_points, custom.inertial_cubature_points) == (
        5, 7, 9)
    assert custom.basis == "handles"  # handles without a basis choose the handle basis
    assert flsh.SoftAvatar(small_body, handles=5, basis="modes+handles").basis == "modes+handles"
    assert flsh.SoftAvatar(small_body, basis="handles").handles == 87
    with pytest.raises(TypeError, match="handles: expected an int or None, got <class 'float'>"):
        flsh.SoftAvatar(small_body, handles=5.0)
    # The realtime preset: the small modal ROM; the arguments given win.
    realtime = flsh.SoftAvatar(small_body, preset="realtime")
    assert (realtime.basis, realtime.vibration_modes, realtime.modal_columns) == ("modes", 12, 24)
    assert (realtime.elastic_cubature_points, realtime.inertial_cubature_points) == (100, 100)
    assert realtime.cubature_training_samples == 400  # the preset's, not the default 600
    assert flsh.SoftAvatar(small_body).cubature_training_samples == 600
    assert flsh.SoftAvatar(small_body, preset="realtime",
                           cubature_training_samples=50).cubature_training_samples == 50
    mixed = flsh.SoftAvatar(small_body, preset="realtime", modal_columns=36, handles=10,
                            inertial_cubature_points=50)
    assert (mixed.basis, mixed.handles, mixed.modal_columns) == ("handles", 10, 36)
    assert (mixed.elastic_cubature_points, mixed.inertial_cubature_points) == (100, 50)
    assert flsh.SoftAvatar(small_body, preset="none").modal_columns == 72
    with pytest.raises(ValueError, match="SoftAvatar: preset: unknown preset 'fast'"):
        flsh.SoftAvatar(small_body, preset="fast")
    with pytest.raises(TypeError, match="preset: expected 'none', 'realtime' or None"):
        flsh.SoftAvatar(small_body, preset=1)
    custom.enableReducedModel()
    custom.enableElasticCubature()
    custom.enable_inertial_cubature(True)
    assert custom.reduced_model_enabled and custom.elastic_cubature_enabled
    assert custom.inertial_cubature_enabled and "reduced=True" in repr(custom)
    custom.enable_inertial_cubature(False)
    assert not custom.inertial_cubature_enabled


@pytest.mark.parametrize("kwargs, message", [
    ({"handles": 0}, "handles: expected an integer ≥ 1"),
    ({"handles": 5, "basis": "modes"}, "handles: not used by basis='modes'"),
    ({"elastic_cubature_points": 0}, "elastic_cubature_points: expected an integer ≥ 1"),
    ({"inertial_cubature_points": -3}, "inertial_cubature_points: expected an integer ≥ 1"),
    ({"cubature_training_samples": 0}, "cubature_training_samples: expected an integer ≥ 1"),
    ({"cubature_training_amplitude": 0.0}, "cubature_training_amplitude: expected a finite"),
    ({"cubature_training_amplitude": float("nan")}, "cubature_training_amplitude"),
    ({"basis_drop_below": 0.5}, r"basis_drop_below: expected a value in \[0, 0.01\]"),
    ({"basis_drop_below": float("nan")}, "basis_drop_below"),
])
def test_bad_reduced_settings_are_value_errors_naming_the_argument(small_body, kwargs, message):
    with pytest.raises(ValueError, match=message):
        flsh.SoftAvatar(small_body, **kwargs)


def test_reduced_data_shapes_and_bounds(avatar):
    assert avatar.has_reduced_data and avatar.has_volumetric_data
    data = avatar.volumetric_data
    rd = avatar.reduced_data
    N, V = data.num_nodes, data.num_surface_nodes
    assert isinstance(rd, flsh.ReducedData) and rd.num_handles == HANDLES

    handles = rd.handles
    assert isinstance(handles, np.ndarray) and np.issubdtype(handles.dtype, np.integer)
    assert handles.shape == (HANDLES,) and len(set(handles.tolist())) == HANDLES
    assert (handles >= 0).all() and (handles < V).all()  # surface vertices
    assert (data.bone_of_node[handles] < 0).all()  # soft-tissue nodes

    basis = rd.basis
    assert scipy.sparse.issparse(basis) and basis.format == "csc"
    assert basis.shape == (N, HANDLES) and basis.dtype == np.float64
    dense = basis.toarray()
    assert np.isfinite(dense).all()
    tolerance = 1e-6 + rd.basis_max_bound_violation
    assert dense.min() >= -tolerance and dense.max() <= 1 + tolerance
    # Handle rows are unit vectors, bone-node rows are empty.
    np.testing.assert_allclose(dense[handles], np.eye(HANDLES), atol=1e-9)
    assert not dense[data.bone_of_node >= 0].any()
    # φ spreads beyond the handles: the basis is more than the identity on them.
    assert basis.nnz > 2 * HANDLES
    assert rd.basis_converged and rd.basis_max_constraint_error < 1e-6

    T = data.num_tets
    for cubature, most, error in ((rd.elastic_cubature, 40, rd.elastic_test_error),
                                  (rd.inertial_cubature, 30, rd.inertial_test_error)):
        assert isinstance(cubature, flsh.Cubature)
        assert 1 <= len(cubature) <= most
        elements, weights = cubature.elements, cubature.weights
        assert elements.shape == weights.shape == (len(cubature),)
        assert np.issubdtype(elements.dtype, np.integer) and weights.dtype == np.float64
        assert (np.diff(elements) > 0).all() and elements[0] >= 0 and elements[-1] < T
        assert (weights > 0).all() and np.isfinite(weights).all()
        assert 0 <= cubature.training_error < 1 and cubature.rounds >= 1
        assert 0 < error < 1  # measured on held-out samples: nonzero, below 100 %
    # The skeleton's rigid motions are in the inertial training set; 30 tets are too few to fit
    # every bone's (0.83 here, 0.4 % on the full body with its 230), so only its wiring is checked.
    assert np.isfinite(rd.inertial_rigid_error) and rd.inertial_rigid_error > 0
    assert isinstance(rd.key, str) and len(rd.key) > 0


def test_elastic_rest_stiffness_is_symmetric_positive_definite(avatar):
    K = avatar.reduced_data.elastic_rest_stiffness
    assert K.shape == (3 * HANDLES, 3 * HANDLES) and K.dtype == np.float64
    np.testing.assert_array_equal(K, K.T)
    assert np.linalg.eigvalsh(K).min() > 0


def test_surface_partition_of_unity_basis(small_body, avatar, cache_dir):
    """The keyword rescales the basis so that it sums to 1 on the soft surface (where any handle
    reaches), keeping the constraints (1 at its handle, 0 at the others and on bone nodes) and
    the bounds."""
    pou = _rom_avatar(small_body, cache_dir, pou=True)
    data = pou.volumetric_data
    V = data.num_surface_nodes
    soft_surface = np.flatnonzero(data.bone_of_node[:V] < 0)
    plain = avatar.reduced_data.basis.toarray()
    dense = pou.reduced_data.basis.toarray()
    assert pou.reduced_data.key != avatar.reduced_data.key
    sums, plain_sums = dense[soft_surface].sum(axis=1), plain[soft_surface].sum(axis=1)
    reached = plain_sums > 1e-9  # soft patches no handle reaches (12 handles) stay 0
    assert reached.mean() > 0.5
    assert plain_sums[reached].min() < 0.9  # the prescribed weights fade between handles …
    np.testing.assert_allclose(sums[reached], 1.0, atol=1e-9)  # … these do not
    assert not sums[~reached].any()
    handles = pou.reduced_data.handles
    np.testing.assert_allclose(dense[handles], np.eye(HANDLES), atol=1e-9)
    assert not dense[data.bone_of_node >= 0].any()
    assert dense.min() >= 0 and dense.max() <= 1 + 1e-12


def test_the_reduced_level_is_cached_and_its_flags_are_part_of_the_key(avatar, small_body,
                                                                         cache_dir):
    first = avatar.reduced_build_report
    assert not first["from_cache"] and first["seconds_total"] > 0 and first["warnings"] == ""
    again = _rom_avatar(small_body, cache_dir)
    assert again.reduced_build_report["from_cache"]
    np.testing.assert_array_equal(again.reduced_data.handles, avatar.reduced_data.handles)
    assert (again.reduced_data.basis != avatar.reduced_data.basis).nnz == 0
    np.testing.assert_array_equal(again.reduced_data.elastic_cubature.weights,
                                  avatar.reduced_data.elastic_cubature.weights)
    assert again.reduced_data.key == avatar.reduced_data.key

    # Without the elastic cubature: another cache entry, no elastic cubature, error 0.
    exact = _rom_avatar(small_body, cache_dir, elastic=False)
    assert not exact.reduced_build_report["from_cache"]
    assert exact.reduced_data.key != avatar.reduced_data.key
    assert len(exact.reduced_data.elastic_cubature) == 0
    assert exact.reduced_data.elastic_test_error == 0
    assert len(exact.reduced_data.inertial_cubature) > 0


def test_rom_state_is_one_z_per_handle_and_u_follows_the_basis(rom, avatar):
    V = avatar.body.v_template.shape[0]
    rd = avatar.reduced_data
    handles = rd.handles
    assert rom.has_reduced_model() and rom.hasReducedModel() and rom.has_soft_tissue()
    assert rom.num_dofs == NUM_BONE_DOFS + 3 * HANDLES
    np.testing.assert_array_equal(rom.soft_nodes(), handles)
    for k, h in enumerate(handles):
        assert rom.node_soft_dof(int(h)) == NUM_BONE_DOFS + 3 * k
    basis = rd.basis.tocsr()
    shared = next(j for j in range(V) if basis[j].nnz >= 2)  # a node between handles
    assert rom.node_soft_dof(shared) == -1

    # u_j = Σ_h φ_h(j) z_h for a random z, read three ways.
    rng = np.random.default_rng(11)
    q = rom.get_state()
    z = rng.normal(0.0, 0.004, (HANDLES, 3))  # m
    q[NUM_BONE_DOFS:] = z.ravel()
    rom.set_state(q)
    expected = basis[:V] @ z  # (V, 3)
    u = rom.get_soft_tissue_displacements()
    assert u.dtype == np.float64 and u.shape == (V, 3) and np.abs(u).max() > 1e-4
    np.testing.assert_allclose(u, expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose(u[handles], z, rtol=0, atol=1e-12)
    pairs = rom.node_displacement_basis(shared)
    assert len(pairs) == basis[shared].nnz >= 2
    assert all(B.shape == (3, 3) for _, B in pairs)
    from_pairs = sum(B @ q[i:i + 3] for i, B in pairs)
    np.testing.assert_allclose(from_pairs, expected[shared], rtol=0, atol=1e-12)
    np.testing.assert_allclose(rom.get_unposed_surface(), avatar.rest_vertices + u, atol=1e-12)
    bone_node = int(np.flatnonzero(avatar.volumetric_data.bone_of_node >= 0)[0])
    assert rom.node_displacement_basis(bone_node) == []
    with pytest.raises(ValueError, match="outside"):
        rom.node_displacement_basis(avatar.volumetric_data.num_nodes)
    cls = type(rom)
    for camel, snake in [("hasReducedModel", "has_reduced_model"),
                         ("nodeDisplacementBasis", "node_displacement_basis")]:
        assert getattr(cls, camel) is getattr(cls, snake), camel


@pytest.mark.parametrize("psd", [True, False])
def test_both_hessian_parts_in_one_call_are_their_sum(rom, psd):
    rng = np.random.default_rng(7)
    rom.updateState(rng.normal(scale=0.01, size=rom.numDofs()))
    total = rom.getHessianTripletVector(psd=psd)
    parts = rom.getDynamicHessianTripletVector(psd) + rom.getPotentialHessianTripletVector(psd)
    assert total.shape == (rom.numDofs(), rom.numDofs())
    scale = abs(parts).max()
    assert scale > 0.0
    assert abs(total - parts).max() <= 1e-10 * scale
    # The handle blocks (the fixed-position lists of the C++ call) are in it.
    assert abs(total[NUM_BONE_DOFS:, NUM_BONE_DOFS:]).max() > 0.0
    assert rom.get_hessian_triplet_vector(psd=psd).shape == total.shape


def test_both_gradients_in_one_call_are_their_sum(rom):
    rng = np.random.default_rng(8)
    rom.updateState(rng.normal(scale=0.01, size=rom.numDofs()))
    total = rom.getGradientVector()
    parts = rom.getDynamicGradientVector() + rom.getPotentialGradientVector()
    assert total.shape == (rom.numDofs(),)
    scale = np.abs(parts).max()
    assert scale > 0.0 and np.abs(parts[NUM_BONE_DOFS:]).max() > 0.0
    assert np.abs(total - parts).max() <= 1e-12 * scale
    assert np.array_equal(rom.get_gradient_vector(), total)


def test_energy_and_gradient_in_one_call(rom):
    rng = np.random.default_rng(9)
    rom.updateState(rng.normal(scale=0.01, size=rom.numDofs()))
    energy, gradient = rom.getEnergyAndGradientVector()
    parts = rom.getDynamicGradientVector() + rom.getPotentialGradientVector()
    expected = rom.getDynamicEnergyScalar() + rom.getPotentialEnergyScalar()
    assert gradient.shape == (rom.numDofs(),)
    scale = np.abs(parts).max()
    assert scale > 0.0 and expected != 0.0
    assert np.abs(gradient - parts).max() <= 1e-12 * scale
    assert abs(energy - expected) <= 1e-12 * (abs(rom.getDynamicEnergyScalar())
                                             + abs(rom.getPotentialEnergyScalar()))
    energy_again, gradient_again = rom.get_energy_and_gradient_vector()
    assert energy_again == energy and np.array_equal(gradient_again, gradient)


def test_a_few_steps_move_the_soft_tissue(avatar):
    motion = flsh.make_builtin_motion("jumping_jacks", seconds=0.5, fps=30.0)
    sim = flsh.Simulable(avatar, motion, flsh.SimulableOptions(time_step=1.0 / 30.0))
    ground = avatar.rest_vertices[:, 1].min()
    scene = flsh.Scene(flsh.SceneOptions(reduced_newton=flsh.NewtonOptions(gradient_tolerance=1e-7)))
    scene.add_simulable(sim)
    scene.add_collider(flsh.Collider.plane(point=[0.0, ground, 0.0], normal=[0, 1, 0]))
    scene.initialize()
    assert scene.has_soft_tissue() and not scene.has_fem_soft_tissue()
    assert scene.newton_options.gradient_tolerance == 1e-7  # reduced_newton, not the others
    assert scene.num_dofs == NUM_BONE_DOFS + 3 * HANDLES
    assert not sim.get_soft_tissue_displacements().any()
    for _ in range(4):
        stats = scene.step()
        assert stats.newton.converged, stats.newton.message
    q = sim.get_state()
    assert np.isfinite(q).all() and np.abs(q[NUM_BONE_DOFS:]).max() > 1e-5
    u = sim.get_soft_tissue_displacements()
    assert np.isfinite(u).all() and np.linalg.norm(u, axis=1).max() > 1e-4  # > 0.1 mm
    assert np.linalg.norm(u, axis=1).max() < 0.1  # and not absurd
    assert np.isfinite(sim.get_vertices()).all()


def test_scene_options_carry_the_reduced_newton():
    defaults = flsh.SceneOptions()
    assert defaults.reduced_newton.max_iterations > 0
    assert 0 < defaults.reduced_newton.gradient_tolerance < 1e-3
    assert defaults.reduced_newton.linear_solver == flsh.LinearSolverType.Auto
    options = flsh.SceneOptions(reduced_newton=flsh.NewtonOptions(max_iterations=7),
                                soft_tissue_newton=flsh.NewtonOptions(max_iterations=9))
    assert options.reduced_newton.max_iterations == 7
    assert options.soft_tissue_newton.max_iterations == 9
    options.reduced_newton = flsh.NewtonOptions(gradient_tolerance=2e-6)
    assert options.reduced_newton.gradient_tolerance == 2e-6


def test_lagged_factor_options_reach_the_solver(avatar):
    defaults = flsh.SceneOptions().reduced_newton.lagged
    assert defaults.enabled and 0 < defaults.cg_relative_tolerance < 1
    assert defaults.fast_preconditioner and defaults.max_cg_iterations >= 1
    assert flsh.NewtonOptions().lagged.enabled is False  # plain Newton unless asked

    def run(lagged):
        motion = flsh.make_builtin_motion("jumping_jacks", seconds=0.5, fps=30.0)
        sim = flsh.Simulable(avatar, motion, flsh.SimulableOptions(time_step=1.0 / 30.0))
        options = flsh.SceneOptions()
        options.reduced_newton.lagged = lagged
        scene = flsh.Scene(options)
        scene.add_simulable(sim)
        scene.initialize()
        totals = [0, 0, 0]
        for _ in range(3):
            n = scene.step().newton
            assert n.converged, n.message
            totals = [totals[0] + n.iterations, totals[1] + n.factorizations,
                      totals[2] + n.cg_iterations]
        return totals, sim.get_state()

    (iterations, factorizations, cg), q_lag = run(flsh.LaggedFactorOptions(enabled=True))
    assert cg > 0 and factorizations < iterations  # PCG on an earlier factor
    cg_lag = cg
    off = flsh.NewtonOptions().lagged
    off.enabled = False  # edited in place
    assert off.enabled is False
    (iterations, factorizations, cg), q_plain = run(off)
    assert cg == 0 and factorizations >= iterations  # every iteration factors
    assert np.abs(q_lag - q_plain).max() < 1e-4  # both converged to the same states
    exact = flsh.LaggedFactorOptions(enabled=True, fast_preconditioner=False,
                                     cg_relative_tolerance=1e-3)
    assert not exact.fast_preconditioner and exact.cg_relative_tolerance == 1e-3
    (_, _, cg_exact), _ = run(exact)
    assert cg_exact > 0
    with pytest.raises(ValueError, match="cg_relative_tolerance"):
        run(flsh.LaggedFactorOptions(enabled=True, cg_relative_tolerance=2.0))
    assert "LaggedFactorOptions(enabled=True" in repr(flsh.LaggedFactorOptions(enabled=True))
    # Chord steps near convergence: the scene default, and the reuses reported per step.
    assert defaults.reuse_hessian_below > 0.0
    assert flsh.LaggedFactorOptions().reuse_hessian_below == 0.0
    with pytest.raises(ValueError, match="reuse_hessian_below"):
        run(flsh.LaggedFactorOptions(enabled=True, reuse_hessian_below=-1.0))
    # The bones as PCG's coarse level: on in the scene defaults, the same states with fewer
    # PCG iterations.
    assert defaults.coarse_correction and flsh.SceneOptions().soft_tissue_newton.lagged.coarse_correction
    assert flsh.LaggedFactorOptions().coarse_correction is False
    (_, _, cg_coarse), q_coarse = run(flsh.LaggedFactorOptions(enabled=True, coarse_correction=True))
    assert 0 < cg_coarse < cg_lag
    assert np.abs(q_coarse - q_lag).max() < 1e-4
    motion = flsh.make_builtin_motion("jumping_jacks", seconds=0.5, fps=30.0)
    sim = flsh.Simulable(avatar, motion, flsh.SimulableOptions(time_step=1.0 / 30.0))
    scene = flsh.Scene()
    scene.add_simulable(sim)
    scene.initialize()
    steps = [scene.step().newton for _ in range(3)]
    assert all(n.converged for n in steps)
    assert sum(n.hessian_reuses for n in steps) > 0
    assert sum(n.hessian_evaluations + n.hessian_reuses for n in steps) >= sum(
        n.iterations for n in steps)


def test_bones_first_options_reach_the_solver(avatar):
    # Newton's iterations on the bones alone before those on every DoF: on in both soft solvers'
    # defaults, off in plain Newton; the same states with fewer iterations on every DoF.
    defaults = flsh.SceneOptions()
    for newton in (defaults.reduced_newton, defaults.soft_tissue_newton):
        assert newton.coarse_presolve.max_iterations == 8
        assert 0 < newton.coarse_presolve.relative_tolerance < 1e-3
    assert flsh.NewtonOptions().coarse_presolve.max_iterations == 0

    def run(presolve):
        motion = flsh.make_builtin_motion("jumping_jacks", seconds=0.5, fps=30.0)
        sim = flsh.Simulable(avatar, motion, flsh.SimulableOptions(time_step=1.0 / 30.0))
        options = flsh.SceneOptions()
        options.reduced_newton.coarse_presolve = presolve
        options.reduced_newton.gradient_tolerance = 1e-9
        scene = flsh.Scene(options)
        scene.add_simulable(sim)
        scene.initialize()
        whole = coarse = 0
        for _ in range(4):
            n = scene.step().newton
            assert n.converged, n.message
            whole += n.iterations
            coarse += n.coarse_iterations
        return whole, coarse, sim.get_state()

    whole_on, coarse_on, q_on = run(flsh.CoarsePresolveOptions(max_iterations=8))
    off = flsh.SceneOptions().reduced_newton.coarse_presolve
    off.max_iterations = 0  # edited in place
    whole_off, coarse_off, q_off = run(off)
    assert coarse_on > 0 and coarse_off == 0
    assert whole_on < whole_off
    assert np.abs(q_on - q_off).max() < 1e-6
    with pytest.raises(ValueError, match="coarse_presolve.relative_tolerance"):
        run(flsh.CoarsePresolveOptions(max_iterations=2, relative_tolerance=0.0))
    assert "CoarsePresolveOptions(max_iterations=3" in repr(
        flsh.CoarsePresolveOptions(max_iterations=3))


def test_errors(small_body, avatar, rom, tmp_path):
    # The reduced model is a soft-tissue model.
    alone = flsh.SoftAvatar(small_body, use_cache=False)
    alone.enable_reduced_model()
    with pytest.raises(ValueError, match="soft tissue is off"):
        alone.init_volumetric_data()
    # More handles than soft-tissue surface vertices.
    with pytest.raises(ValueError, match="num_handles = 5000, expected at most"):
        _rom_avatar(small_body, tmp_path, handles=5000)
    # Reduced data of the other models.
    fem = flsh.SoftAvatar(small_body, resolution=0.3, cache_dir=str(tmp_path))
    fem.enable_soft_tissue()
    fem.init_volumetric_data()
    assert not fem.has_reduced_data
    assert fem.reduced_build_report["seconds_total"] == 0
    with pytest.raises(RuntimeError, match="no reduced data"):
        fem.reduced_data
    # A soft avatar's parameter derivatives cover every group, β included.
    shape = rom.get_gradient_parameter_jacobian(flsh.SimParameter.Shape)
    assert shape.shape == (rom.num_dofs, rom.parameter_size(flsh.SimParameter.Shape))
    assert np.abs(shape).max() > 0
    stiffness = rom.get_gradient_parameter_jacobian(flsh.SimParameter.Stiffnesses)
    assert stiffness.shape == (rom.num_dofs, rom.parameter_size(flsh.SimParameter.Stiffnesses))
    with pytest.raises(ValueError, match="expected shape"):
        rom.set_state(np.zeros(NUM_BONE_DOFS))


def test_ball_belly_example_with_rom(tmp_path):
    result = subprocess.run(
        [sys.executable, str(EXAMPLES / "ball_belly.py"), "--out", str(tmp_path), "--seconds",
         "0.25", "--speed", "4", "--vertices", "600", "--sheet-frames", "2", "--rom",
         "--resolution", "0.3", "--handles", "20", "--cache", str(tmp_path / "cache")],
        env=dict(os.environ), capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert "did not converge" not in result.stdout
    assert "ROM: 20 handles; elastic cubature" in result.stdout, result.stdout
    assert flsh.read_png(tmp_path / "sheet.png").width > 0
    # The ball dents the reduced belly: a displacement of at least a millimetre.
    line = next(l for l in result.stdout.splitlines() if l.startswith("soft tissue"))
    assert float(line.split("|u|")[1].split("mm")[0]) > 1.0, line
