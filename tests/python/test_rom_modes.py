"""The ROM on a basis with modes from Python (docs/rom.md, issue 26): SoftAvatar's basis /
vibration_modes / modal_columns, ReducedData's modes (N, 3, r), the reduced state (z: 3 per
handle, then one per mode; u_j = Ψ_j z_modes read back by node_displacement_basis's 3 × 3
blocks), a few converged steps in a Scene, and the errors."""
import numpy as np
import pytest

import flsh

NUM_BONE_DOFS = 6 * 24


def _modal_avatar(body, cache_dir, basis, handles=6):
    avatar = flsh.SoftAvatar(body, resolution=0.3, cache_dir=str(cache_dir),
                             handles=handles if "handles" in basis else None, basis=basis,
                             vibration_modes=3, modal_columns=13,
                             elastic_cubature_points=40, inertial_cubature_points=30,
                             cubature_training_samples=60)
    avatar.enable_soft_tissue()
    avatar.enable_reduced_model()
    avatar.enable_elastic_cubature()
    avatar.enable_inertial_cubature()
    avatar.init_volumetric_data()
    return avatar


@pytest.fixture(scope="module")
def small_body():
    return flsh.make_synthetic_body(vertices=600)


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("rom_modes_cache")


@pytest.fixture(scope="module")
def modes(small_body, cache_dir):
    return _modal_avatar(small_body, cache_dir, "modes")


def test_modal_data_and_the_state_layout(small_body, cache_dir, modes):
    rd = modes.reduced_data
    N = modes.volumetric_data.num_nodes
    assert rd.basis_kind == "modes" and rd.num_handles == 0
    assert rd.num_modes == 12  # 13 columns cut to a multiple of 3
    psi = rd.modes
    assert psi.shape == (N, 3, 12) and psi.dtype == np.float64
    bone = modes.volumetric_data.bone_of_node >= 0
    assert not psi[bone].any() and np.abs(psi[~bone]).max() > 0
    assert "basis='modes'" in repr(rd) and "modes=12" in repr(rd)
    assert rd.elastic_rest_stiffness.shape == (12, 12)
    np.testing.assert_allclose(rd.elastic_rest_stiffness, rd.elastic_rest_stiffness.T)

    sim = flsh.Simulable(modes, options=flsh.SimulableOptions(time_step=1.0 / 30.0))
    sim.initialize()
    assert sim.num_dofs == NUM_BONE_DOFS + 12 and len(sim.soft_nodes()) == 0
    q = sim.get_state()
    z = np.random.default_rng(3).normal(0.0, 0.01, 12)
    q[NUM_BONE_DOFS:] = z
    sim.set_state(q)
    V = modes.volumetric_data.num_surface_nodes
    expected = psi[:V] @ z  # (V, 3)
    u = sim.get_soft_tissue_displacements()
    assert np.abs(u).max() > 1e-5
    np.testing.assert_allclose(u, expected, rtol=0, atol=1e-12)
    j = int(np.flatnonzero(~bone[:V])[0])
    pairs = sim.node_displacement_basis(j)
    assert len(pairs) == 4 and all(B.shape == (3, 3) for _, B in pairs)
    np.testing.assert_allclose(sum(B @ q[i:i + 3] for i, B in pairs), expected[j], atol=1e-12)
    assert sim.node_displacement_basis(int(np.flatnonzero(bone)[0])) == []

    both = _modal_avatar(small_body, cache_dir, "modes+handles")
    assert both.reduced_data.basis_kind == "modes+handles"
    assert both.reduced_data.num_handles == 6 and both.reduced_data.num_modes == 12
    sim_both = flsh.Simulable(both)
    sim_both.initialize()
    assert sim_both.num_dofs == NUM_BONE_DOFS + 3 * 6 + 12


def _jumping(avatar, approximate):
    motion = flsh.make_builtin_motion("jumping_jacks", seconds=0.5, fps=30.0)
    sim = flsh.Simulable(avatar, motion, flsh.SimulableOptions(time_step=1.0 / 30.0))
    ground = avatar.rest_vertices[:, 1].min()
    newton = flsh.NewtonOptions(gradient_tolerance=1e-9, approximate_hessian=approximate)
    scene = flsh.Scene(flsh.SceneOptions(reduced_newton=newton))
    scene.add_simulable(sim)
    scene.add_collider(flsh.Collider.plane(point=[0.0, ground, 0.0], normal=[0, 1, 0]))
    scene.initialize()
    return scene, sim


def test_a_few_steps_move_the_soft_tissue(modes):
    assert flsh.SceneOptions().reduced_newton.approximate_hessian
    assert not flsh.NewtonOptions().approximate_hessian
    scene, sim = _jumping(modes, True)
    exact_scene, exact_sim = _jumping(modes, False)
    approximate = 0
    for _ in range(4):
        stats, exact_stats = scene.step(), exact_scene.step()
        assert stats.newton.converged, stats.newton.message
        assert exact_stats.newton.approximate_directions == 0
        approximate += stats.newton.approximate_directions
        # The constant soft–soft block's directions end where the exact ones end.
        assert np.abs(sim.get_state() - exact_sim.get_state()).max() < 1e-7
    assert approximate > 0
    u = sim.get_soft_tissue_displacements()
    assert np.isfinite(u).all() and 1e-4 < np.linalg.norm(u, axis=1).max() < 0.1


@pytest.mark.parametrize("kwargs, message", [
    ({"basis": "mode"}, "basis kind 'mode', expected one of 'handles', 'modes', 'modes\\+handles'"),
    ({"basis": "modes", "vibration_modes": -1}, "vibration_modes: expected ≥ 0"),
    ({"basis": "modes", "modal_columns": -2}, "modal_columns: expected ≥ 0"),
])
def test_bad_basis_settings_are_value_errors(small_body, kwargs, message):
    with pytest.raises(ValueError, match=message):
        flsh.SoftAvatar(small_body, **kwargs)
