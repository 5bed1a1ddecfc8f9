// Shared helpers of the C++ tests: one finite-difference checker for every derivative,
// temporary directories, and a small random SMPL-format model.
#pragma once

#include <gtest/gtest.h>

#include <functional>
#include <string>
#include <vector>

#include "flsh/body/body_model.h"
#include "flsh/body/motion.h"
#include "flsh/core/types.h"
#include "flsh/sim/simulable.h"
#include "flsh/solve/scene.h"
#include "flsh/volume/soft_avatar.h"

namespace flsh::test {

/// Central-difference Jacobian of f at x (columns = dx directions).
MatX finiteDifferenceJacobian(const std::function<VecX(const VecX&)>& f, const VecX& x,
                              double eps = 1e-6);

/// Asserts that `analytic` is not (near) zero, then that it matches the central-difference
/// Jacobian of f at x: max |A − FD| ≤ tol · max(1, max |FD|). Returns the error found.
::testing::AssertionResult jacobianMatchesFiniteDifferences(
    const std::function<VecX(const VecX&)>& f, const VecX& x, const MatX& analytic,
    double tol = 1e-6, double eps = 1e-6);

/// Uniform random vector in [−scale, scale]^n, deterministic in `seed`.
VecX randomVector(int n, double scale, unsigned seed);

/// The dense n × n sum of Hessian triplets.
MatX denseFromTriplets(const std::vector<Triplet>& H, int n);

/// The triplets of fixed Hessian block lists (3 × 3 each, at their positions plus the list's
/// offset).
std::vector<Triplet> expanded(const std::vector<FixedHessianBlocks>& blocks);

/// f() evaluated at the state of `sim` (a Simulable) moved by increments d; the state is
/// restored exactly afterwards (pushState / updateState / popState).
template <class Sim, class F>
auto atMovedState(Sim& sim, const VecX& d, F&& f) {
  sim.pushState();
  sim.updateState(d);
  auto result = f();
  sim.popState();
  return result;
}

/// Moves every bone of `sim` by `shift` (m), at rest there: the previous states move too
/// (preUpdate then starts from the prediction of q_n and q_{n−1}).
void translateBones(Simulable& sim, const Vec3& shift);

/// Simulable `moving` of `scene` moved along z (5 cm back first) until the scene's avatars just
/// stop touching (avatar–avatar contact, at most 2 m), then `overlap` metres back into them.
void touchAlongZ(Scene& scene, int moving, double overlap);

/// A fresh empty directory under $FLSH_TEST_TMP (or the system temp dir), unique to the running
/// test and `name`.
std::string freshTempDir(const std::string& name);

/// Runs `call` and returns the message of the exception of type E it throws ("" and a test
/// failure if it throws nothing or another type). For checking what error messages name.
template <class E, class F>
std::string messageOf(F&& call) {
  try {
    call();
  } catch (const E& e) {
    return e.what();
  } catch (const std::exception& e) {
    ADD_FAILURE() << "threw the wrong exception type: " << e.what();
    return "";
  }
  ADD_FAILURE() << "did not throw";
  return "";
}

/// A small synthetic body, its skeleton avatar (2 cm voxels) and the built-in walk, built once
/// per (vertices, walk_seconds) per test binary: the fixture of the simulation tests.
struct SmallScene {
  std::shared_ptr<const BodyModel> body;
  std::shared_ptr<const SoftAvatar> avatar;
  std::shared_ptr<const Motion> walk;  ///< built-in "walk" at 30 fps
};
const SmallScene& smallScene(int vertices, double walk_seconds = 1.0);

/// Settings of the small soft avatars of the simulation tests (on smallScene(800).body): 2 cm
/// voxels, a coarse interior (resolution 0.5), cache in `cache_dir`, and a small ROM (16
/// handles, 60 tets per cubature, 80 training samples) for avatars that enable it.
SoftAvatarSettings smallSoftAvatarSettings(const std::string& cache_dir);

/// Increment-chart helper for finite differences of gradients: the gradient g at the state
/// moved by increments d (6 per bone, [δt, δω]) pulled back to the chart at d = 0, i.e. the
/// rotation entries multiplied by J_l(δω)ᵀ. Its finite-difference Jacobian at d = 0 is the
/// symmetric Hessian the simulables return.
VecX pullBackRotationGradient(const VecX& g, const VecX& d);

/// A small random SMPL-format model (`vertices` vertices, `betas` shape components) with a
/// valid skeleton (SMPL parents), smooth positive weights (rows sum to 1), a regressor whose
/// rows sum to 1, and random dense shape and pose blend shapes. Finalized. Deterministic in
/// `seed`. For unit tests of the forward pass that must not depend on the synthetic body.
BodyModel makeRandomModel(int vertices = 300, int betas = 10, unsigned seed = 1);

/// An SMPL-H model built from an SMPL one: the same body joints; each hand's SMPL weight split
/// over three finger joints; the middle fingers' first joints at SMPL's hand joints, the other
/// finger joints there too; random finger pose blend shapes; 6 more shape components (random).
BodyModel smplhFrom(const BodyModel& smpl);

}  // namespace flsh::test
