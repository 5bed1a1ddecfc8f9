"""flsh.modal_basis and flsh.soft_tissue_rest_operators (issue 26, docs/rom.md "A basis from the
physics"): the soft tissue's rest operators, the basis' layout (N, 3, r), mass-orthonormality,
every static response in its span, and the errors."""
import numpy as np
import pytest
import scipy.sparse
import scipy.sparse.linalg

import flsh


@pytest.fixture(scope="module")
def avatar(tmp_path_factory):
    body = flsh.make_synthetic_body(vertices=600)
    a = flsh.SoftAvatar(body, resolution=0.3, cache_dir=str(tmp_path_factory.mktemp("modal")))
    a.enable_soft_tissue()
    a.init_volumetric_data()
    return a


@pytest.fixture(scope="module")
def operators(avatar):
    return flsh.soft_tissue_rest_operators(avatar)


def test_rest_operators_have_the_documented_shapes(avatar, operators):
    soft = operators["soft_nodes"]
    n = 3 * len(soft)
    K = operators["stiffness"]
    assert scipy.sparse.issparse(K) and K.shape == (n, n)
    assert abs(K - K.T).max() == 0.0
    assert operators["masses"].shape == (n,) and operators["masses"].min() > 0
    assert operators["coupling"].shape == (n, 144)
    # Every bone translating by d moves every soft node by d (weights sum to 1).
    d = np.array([0.1, -0.3, 0.2])
    f = operators["coupling"] @ np.tile(np.concatenate([d, np.zeros(3)]), 24)
    np.testing.assert_allclose(f, operators["masses"] * np.tile(d, len(soft)), atol=1e-14)


def test_basis_is_mass_orthonormal_and_spans_the_static_responses(avatar, operators):
    basis, report = flsh.modal_basis(avatar, vibration_modes=10)
    N = avatar.volumetric_data.num_nodes
    r = basis.shape[2]
    assert basis.shape == (N, 3, r)
    assert report["static_columns"] == 144 and report["vibration_columns"] == 10
    assert r + report["dropped_columns"] == 154
    assert report["frequencies"].shape == (10,) and report["frequencies"][0] > 0
    assert report["max_eigen_residual"] <= 1e-5
    soft = operators["soft_nodes"]
    bone = np.setdiff1d(np.arange(N), soft)
    assert np.abs(basis[bone]).max() == 0.0
    V = basis[soft].reshape(3 * len(soft), r)
    m = operators["masses"]
    np.testing.assert_allclose(V.T @ (m[:, None] * V), np.eye(r), atol=1e-8)
    # The static response to a random bone acceleration: Galerkin in the basis reproduces it.
    K = operators["stiffness"].tocsc()
    a = np.random.default_rng(2).normal(size=144)
    F = -operators["coupling"] @ a
    u = scipy.sparse.linalg.spsolve(K, F)
    assert np.linalg.norm(u) > 0
    z = np.linalg.solve(V.T @ (K @ V), V.T @ F)
    assert np.linalg.norm(V @ z - u) <= 1e-6 * np.linalg.norm(u)


def test_compression_and_errors(avatar):
    basis, report = flsh.modal_basis(avatar, vibration_modes=0, columns=30)
    assert basis.shape[2] == 30 and report["dropped_columns"] == 144 - 30
    with pytest.raises(ValueError, match="vibration_modes = -1"):
        flsh.modal_basis(avatar, vibration_modes=-1)
    # The rotations' weight changes the compressed span, not the uncompressed one.
    light, _ = flsh.modal_basis(avatar, vibration_modes=0, columns=30, rotation_weight=0.1)
    assert np.abs(light - basis).max() > 1e-3 * np.abs(basis).max()
    with pytest.raises(ValueError, match="rotation_weight"):
        flsh.modal_basis(avatar, vibration_modes=0, columns=30, rotation_weight=0.0)
    with pytest.raises(ValueError, match="no columns"):
        flsh.modal_basis(avatar, static_modes=False, vibration_modes=0)
    plain = flsh.SoftAvatar(flsh.make_synthetic_body(vertices=600))
    with pytest.raises(ValueError, match="not initialized"):
        flsh.modal_basis(plain)
