"""Simulable's parameter calls from Python (SimParameter, parameter_size, get/set_parameter,
get_gradient_parameter_jacobian, get_gradient_previous_state_jacobian): values round trip, the
Jacobians match central differences of the total gradient, derivative calls leave the state
alone, and bad arguments raise ValueError naming sizes. A 600-vertex synthetic avatar walking
with ground and sphere contact."""
import numpy as np
import pytest

import flsh

P = flsh.SimParameter
GROUPS = [P.RestJoints, P.BoneInertia, P.PoseTargets, P.RootTranslationTarget, P.Stiffnesses,
          P.ColliderOffsets]


@pytest.fixture(scope="module")
def avatar():
    a = flsh.SoftAvatar(flsh.make_synthetic_body(vertices=600))
    a.init_volumetric_data()
    return a


def total_gradient(sim):
    return sim.get_dynamic_gradient_vector() + sim.get_potential_gradient_vector()


def set_history(sim, N, dN, M, dM, Q):
    """q_{n−1} = M ⊕ dM, q_n = N ⊕ dN (increments in the chart), current state Q."""
    sim.set_state(M)
    sim.update_state(dM)
    sim.post_update()
    sim.set_state(N)
    sim.update_state(dN)
    sim.post_update()
    sim.set_state(Q)


class Scenario:
    """One step into the walk with a distinct velocity history, moved off the prediction, a
    ground plane 1.5 cm above the lowest node and a sphere pressing into the frontmost one."""

    def __init__(self, avatar, walk):
        rng = np.random.default_rng(5)
        self.sim = sim = flsh.Simulable(avatar, walk)
        sim.initialize()
        sim.pre_update()
        predicted = sim.get_state()
        n = sim.num_dofs
        self.N = predicted + rng.uniform(-0.02, 0.02, n)
        self.M = self.N + rng.uniform(-0.02, 0.02, n)
        self.Q = predicted + rng.uniform(-0.03, 0.03, n)
        set_history(sim, self.N, np.zeros(n), self.M, np.zeros(n), self.Q)
        nodes = sim.get_nodes()
        lowest, front = nodes[:, 1].argmin(), nodes[:, 2].argmax()
        sim.set_colliders([
            flsh.Collider.plane(point=[0.0, nodes[lowest, 1] + 0.015, 0.0], normal=[0, 1, 0]),
            flsh.Collider.sphere(center=nodes[front] + [0.0, 0.0, 0.04], radius=0.05)])


@pytest.fixture
def scenario(avatar, walk):
    return Scenario(avatar, walk)


def central_difference(f, x0, eps=1e-6):
    columns = []
    for k in range(x0.size):
        d = np.zeros_like(x0)
        d[k] = eps
        columns.append((f(x0 + d) - f(x0 - d)) / (2 * eps))
    return np.stack(columns, axis=1)


def assert_matches(analytic, fd, tol=1e-5):
    assert np.abs(analytic).max() > 1e-6, "analytic Jacobian is zero"
    error = np.abs(analytic - fd).max()
    assert error <= tol * max(1.0, np.abs(fd).max()), error


def test_enum_and_sizes(scenario, avatar):
    sim = scenario.sim
    names = {p.name for p in P.__members__.values()}
    assert {"RestJoints", "BoneInertia", "PoseTargets", "RootTranslationTarget", "Stiffnesses",
            "ColliderOffsets", "Shape"} <= names
    sizes = {P.RestJoints: 72, P.BoneInertia: 240, P.PoseTargets: 72,
             P.RootTranslationTarget: 3, P.Stiffnesses: 4, P.ColliderOffsets: 6}
    for p, size in sizes.items():
        assert sim.parameter_size(p) == size, p
        assert sim.get_parameter(p).shape == (size,), p
        assert sim.parameterSize(p) == size  # the paper's name is the same function
    assert sim.get_parameter(P.Shape).shape == (sim.parameter_size(P.Shape),)


@pytest.mark.parametrize("p", GROUPS, ids=lambda p: p.name)
def test_values_round_trip(scenario, p):
    sim = scenario.sim
    original = sim.get_parameter(p)
    changed = original * 1.01 + 1e-3  # stays valid: masses and stiffnesses remain positive
    if p == P.BoneInertia:
        changed = original * 1.01  # scaling keeps every inertia tensor physical
    sim.set_parameter(p, changed)
    np.testing.assert_allclose(sim.get_parameter(p), changed, rtol=1e-14, atol=0)
    sim.setParameter(p, original)
    # Pose targets are kept as rotation matrices: their rotation vectors come back to round-off.
    np.testing.assert_allclose(sim.get_parameter(p), original, rtol=0, atol=1e-14)


@pytest.mark.parametrize("p", GROUPS, ids=lambda p: p.name)
def test_gradient_parameter_jacobian_matches_finite_differences(scenario, p):
    sim = scenario.sim
    total_gradient(sim)
    assert sim.active_contacts > 1
    p0 = sim.get_parameter(p)
    # Stiffnesses span 1e2..1e5 in their units: differentiate with respect to relative changes.
    scale = np.abs(p0) if p == P.Stiffnesses else np.ones_like(p0)
    analytic = sim.get_gradient_parameter_jacobian(p) * scale[None, :]
    assert analytic.shape == (sim.num_dofs, p0.size)

    def gradient(d):
        sim.set_parameter(p, p0 + scale * d)
        g = total_gradient(sim)
        sim.set_parameter(p, p0)
        return g

    assert_matches(analytic, central_difference(gradient, np.zeros(p0.size)))


@pytest.mark.parametrize("which", [1, 2])
def test_previous_state_jacobian_matches_finite_differences(scenario, which):
    s = scenario
    n = s.sim.num_dofs
    zero = np.zeros(n)
    analytic = s.sim.get_gradient_previous_state_jacobian(which)
    assert analytic.shape == (n, n)

    def gradient(d):
        set_history(s.sim, s.N, d if which == 1 else zero, s.M, d if which == 2 else zero, s.Q)
        g = total_gradient(s.sim)
        set_history(s.sim, s.N, zero, s.M, zero, s.Q)
        return g

    assert_matches(analytic, central_difference(gradient, zero))


def test_derivative_calls_do_not_change_the_state(scenario):
    sim = scenario.sim
    q, v, g = sim.get_state(), sim.get_velocity(), total_gradient(sim)
    for p in GROUPS + [P.Shape]:
        sim.get_gradient_parameter_jacobian(p)
    sim.get_gradient_previous_state_jacobian(1)
    sim.get_gradient_previous_state_jacobian(2)
    np.testing.assert_array_equal(sim.get_state(), q)
    np.testing.assert_array_equal(sim.get_velocity(), v)
    np.testing.assert_array_equal(total_gradient(sim), g)


def test_bad_arguments_raise_value_errors(scenario):
    sim = scenario.sim
    with pytest.raises(ValueError, match=r"value: expected shape \(72,\), got \(5,\)"):
        sim.set_parameter(P.RestJoints, np.zeros(5))
    inertia = sim.get_parameter(P.BoneInertia)
    bad = inertia.copy()
    bad[30] = -1.0  # bone 3's mass
    with pytest.raises(ValueError):
        sim.set_parameter(P.BoneInertia, bad)
    np.testing.assert_array_equal(sim.get_parameter(P.BoneInertia), inertia)  # nothing written
    nan = sim.get_parameter(P.Stiffnesses)
    nan[0] = np.nan
    with pytest.raises(ValueError, match="value"):
        sim.set_parameter(P.Stiffnesses, nan)
    with pytest.raises(ValueError):
        sim.set_parameter(P.Shape, sim.get_parameter(P.Shape))
    with pytest.raises(ValueError):
        sim.get_gradient_previous_state_jacobian(3)
    with pytest.raises(TypeError):
        sim.get_parameter("RestJoints")
