// The FLSH paper's "solver example": a backward-Euler step solved by a Newton loop written
// only with the public Simulable calls (energies, gradients, Hessian triplets, kinematic fixes,
// state push/pop). flsh's own solver (flsh/solve/newton.h) does the same with more care.
//
//   ./build/bin/example_solver_example [frames]
#include <Eigen/SparseCholesky>
#include <cstdio>
#include <cstdlib>
#include <memory>

#include "flsh/body/motion.h"
#include "flsh/body/synthetic_body.h"
#include "flsh/contact/collider.h"
#include "flsh/sim/simulable.h"
#include "flsh/volume/soft_avatar.h"

using namespace flsh;

namespace {

// E(q) = dynamic + potential, at the simulable's current state.
double totalEnergy(const Simulable& sim) {
  return sim.getDynamicEnergyScalar() + sim.getPotentialEnergyScalar();
}

// One backward-Euler step: minimize E from the predicted state.
int newtonStep(Simulable& sim) {
  const int n = sim.numDofs();
  for (int iteration = 0; iteration < 30; ++iteration) {
    VecX g = VecX::Zero(n);
    sim.getDynamicGradientVector(g);
    sim.getPotentialGradientVector(g);
    sim.fixVectorKinematic(g);
    if (g.lpNorm<Eigen::Infinity>() < 1e-6) return iteration;

    std::vector<Triplet> triplets;
    sim.getDynamicHessianTripletVector(triplets);
    sim.getPotentialHessianTripletVector(triplets);  // positive-semidefinite form
    sim.fixMatrixKinematic(triplets);
    SpMat H(n, n);
    H.setFromTriplets(triplets.begin(), triplets.end());
    Eigen::SimplicialLDLT<SpMat> factor(H);
    if (factor.info() != Eigen::Success) {
      std::fprintf(stderr, "Hessian factorization failed\n");
      std::exit(1);
    }
    const VecX dq = factor.solve(-g);

    // Backtracking line search on E, restoring the state of each rejected trial.
    const double E0 = totalEnergy(sim);
    double alpha = 1.0;
    for (int trial = 0; trial < 20; ++trial, alpha *= 0.5) {
      sim.pushState();
      sim.updateState(alpha * dq);
      if (totalEnergy(sim) <= E0 + 1e-4 * alpha * g.dot(dq)) break;
      sim.popState();
    }
    if (dq.lpNorm<Eigen::Infinity>() * alpha < 1e-10) return iteration + 1;
  }
  return 30;
}

}  // namespace

int main(int argc, char** argv) {
  const int frames = argc > 1 ? std::atoi(argv[1]) : 60;
  SyntheticBodyOptions body_options;
  body_options.vertices = 2000;
  auto body = std::make_shared<BodyModel>(makeSyntheticBody(body_options));
  auto avatar = std::make_shared<SoftAvatar>(body, VecX::Zero(body->numBetas()));
  avatar->initVolumetricData();  // skeleton only: bone masses and inertias, no tet mesh
  auto walk = std::make_shared<Motion>(makeBuiltinMotion("walk", frames / 60.0, 60.0));

  Simulable sim(avatar, walk);
  const double sole = avatar->restVertices().col(1).minCoeff();
  sim.setColliders({Collider::plane(Vec3(0, sole, 0), Vec3::UnitY())});
  sim.initialize();
  int total_iterations = 0;
  for (int frame = 0; frame < frames; ++frame) {
    sim.preUpdate();  // advance time, mocap targets, inertial prediction
    total_iterations += newtonStep(sim);
    sim.postUpdate();  // accept the step
  }
  const Vec3 trans = sim.getTrans();
  std::printf("solver example: %d steps, %.2f Newton iterations per step; root at (%.3f, %.3f, %.3f) m, "
              "%d contacts\n",
              frames, double(total_iterations) / frames, trans.x(), trans.y(), trans.z(),
              sim.stats().active_contacts);
  return 0;
}
