"""The soft-tissue calls of Simulable from Python (FEM soft skeleton, docs/fem.md): the skeleton
model has no soft DoFs (empty soft_nodes, zero displacements, the rest surface), and a soft
avatar (enable_soft_tissue) has one displacement per soft-tissue node after the 144 bone
values, read back consistently by node_soft_dof, get_soft_tissue_displacements and
get_unposed_surface."""
import numpy as np
import pytest

import flsh

NUM_BONE_DOFS = 6 * 24


@pytest.fixture(scope="module")
def small_body():
    return flsh.make_synthetic_body(vertices=600)


@pytest.fixture(scope="module")
def skeleton(small_body):
    avatar = flsh.SoftAvatar(small_body)
    avatar.init_volumetric_data()
    sim = flsh.Simulable(avatar)
    sim.initialize()
    return sim


@pytest.fixture(scope="module")
def soft(small_body, tmp_path_factory):
    """A soft avatar on a coarse tet mesh (cache in a temporary folder), at rest."""
    avatar = flsh.SoftAvatar(small_body, resolution=0.3,
                             cache_dir=str(tmp_path_factory.mktemp("fem_cache")))
    avatar.enable_soft_tissue()
    avatar.init_volumetric_data()
    sim = flsh.Simulable(avatar)
    sim.initialize()
    return sim


def test_skeleton_has_no_soft_tissue(skeleton, small_body):
    V = small_body.v_template.shape[0]
    assert skeleton.hasSoftTissue() is False and skeleton.has_soft_tissue() is False
    assert skeleton.numBoneDofs() == NUM_BONE_DOFS == skeleton.num_bone_dofs == skeleton.num_dofs

    nodes = skeleton.soft_nodes()
    assert isinstance(nodes, np.ndarray) and nodes.shape == (0,)
    assert np.issubdtype(nodes.dtype, np.integer)
    assert skeleton.node_soft_dof(0) == -1 and skeleton.nodeSoftDof(V - 1) == -1
    for bad in (-1, V):
        with pytest.raises(ValueError, match=f"node {bad} outside \\[0, {V}\\)"):
            skeleton.node_soft_dof(bad)

    u = skeleton.get_soft_tissue_displacements()
    assert u.dtype == np.float64 and u.shape == (V, 3)
    assert not u.any()
    Y = skeleton.get_unposed_surface()
    assert Y.dtype == np.float64 and Y.shape == (V, 3)
    np.testing.assert_array_equal(Y, skeleton.avatar.rest_vertices)
    X = skeleton.get_volume_nodes()
    assert X.dtype == np.float64 and X.shape == (V, 3)
    np.testing.assert_allclose(X, skeleton.get_nodes(), rtol=0, atol=1e-12)


def test_the_camel_case_names_are_the_snake_case_ones(skeleton):
    cls = type(skeleton)
    for camel, snake in [("hasSoftTissue", "has_soft_tissue"), ("softNodes", "soft_nodes"),
                         ("nodeSoftDof", "node_soft_dof"),
                         ("getSoftTissueDisplacements", "get_soft_tissue_displacements"),
                         ("getUnposedSurface", "get_unposed_surface"),
                         ("getVolumeNodes", "get_volume_nodes")]:
        assert getattr(cls, camel) is getattr(cls, snake), camel
    for name in ("get_soft_tissue_displacements", "get_unposed_surface", "get_volume_nodes"):
        doc = getattr(cls, name).__doc__
        assert "float64" in doc and ", m" in doc, (name, doc)  # shape, dtype and unit documented


def test_soft_avatar_state_holds_one_displacement_per_soft_tissue_node(soft, small_body):
    V = small_body.v_template.shape[0]
    data = soft.avatar.volumetric_data
    N = data.num_nodes
    assert soft.has_soft_tissue() is True
    assert soft.num_bone_dofs == NUM_BONE_DOFS

    nodes = soft.soft_nodes()
    S = nodes.shape[0]
    assert S > 0 and soft.num_dofs == NUM_BONE_DOFS + 3 * S
    # The soft-tissue nodes are exactly the nodes not attached to a bone, each once.
    assert sorted(nodes.tolist()) == np.flatnonzero(data.bone_of_node < 0).tolist()
    for k in (0, S // 2, S - 1):
        assert soft.node_soft_dof(int(nodes[k])) == NUM_BONE_DOFS + 3 * k
    bone_nodes = np.flatnonzero(data.bone_of_node >= 0)
    assert bone_nodes.size > 0 and soft.node_soft_dof(int(bone_nodes[0])) == -1
    with pytest.raises(ValueError, match="outside"):
        soft.node_soft_dof(N)

    X = soft.get_volume_nodes()
    assert X.dtype == np.float64 and X.shape == (N, 3) and np.isfinite(X).all()
    np.testing.assert_allclose(X[:V], soft.get_nodes(), rtol=0, atol=1e-12)

    # Displacements written into the state come back on the surface vertices (unposed space);
    # at the rest pose the unposed surface is the rest surface plus u.
    rest = soft.get_unposed_surface()
    np.testing.assert_allclose(rest, soft.avatar.rest_vertices, rtol=0, atol=1e-12)
    rng = np.random.default_rng(5)
    q = soft.get_state()
    q[NUM_BONE_DOFS:] = rng.normal(0.0, 0.003, 3 * S)  # m
    soft.push_state()
    try:
        soft.set_state(q)
        u = soft.get_soft_tissue_displacements()
        assert u.dtype == np.float64 and u.shape == (V, 3)
        expected = np.zeros((V, 3))
        on_surface = nodes < V
        assert on_surface.any()
        expected[nodes[on_surface]] = q[NUM_BONE_DOFS:].reshape(S, 3)[on_surface]
        np.testing.assert_allclose(u, expected, rtol=0, atol=1e-15)
        np.testing.assert_allclose(soft.get_unposed_surface(), rest + u, rtol=0, atol=1e-12)
    finally:
        soft.pop_state()
    assert not soft.get_soft_tissue_displacements().any()
