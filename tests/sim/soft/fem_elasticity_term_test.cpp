// The FEM soft skeleton's elastic energy alone against finite differences, and its Hessian on any
// number of threads.
#include <omp.h>

#include "flsh/volume/elastic_tets.h"
#include "sim/soft/soft_term_checks.h"

namespace flsh {
namespace {

using test::SoftModel;

TEST(FemElasticityTerm, DerivativesMatchFiniteDifferences) {
  auto sim = test::softTermScenario(SoftModel::Fem);
  ASSERT_FALSE(sim->hasReducedModel());
  // Reads u alone (the tissue's deformation in the unposed frame): no bone rows.
  test::expectSoftTermDerivatives(*sim, test::termNamed(*sim, "elasticity"), true, false);
}

// Zero energy and gradient at rest (u = 0) whatever the bones do.
TEST(FemElasticityTerm, RestIsStressFreeInAnyPose) {
  auto sim = test::softTermScenario(SoftModel::Fem);
  VecX q = sim->getState();
  q.tail(sim->numDofs() - sim->numBoneDofs()).setZero();
  sim->setState(q);
  const EnergyTerm& term = test::termNamed(*sim, "elasticity");
  const VecX g = test::termGradient(*sim, term);
  EXPECT_EQ(term.evaluate(sim->termContext(), nullptr, 0), 0.0);
  EXPECT_EQ(g.norm(), 0.0);
}

// The elements' Hessians are summed into the node-pair blocks by the threads' element ranges
// (FemElasticityTerm's ScatterPlan): every block gets the sums of one pass over the elements, so
// the Hessian is the same bit for bit on any number of threads, in both forms.
TEST(FemElasticityTerm, HessianIsTheSameOnAnyNumberOfThreads) {
  auto sim = test::softTermScenario(SoftModel::Fem);
  const VolumetricData& data = sim->avatar().volumetricData();
  int elastic = 0;
  for (int t = 0; t < data.numTets(); ++t) elastic += tetHasSoftNode(data, t) ? 1 : 0;
  ASSERT_GT(elastic, 2000);  // the threaded path runs
  const EnergyTerm& term = test::termNamed(*sim, "elasticity");
  const int threads = omp_get_max_threads();
  for (const bool psd : {false, true}) {
    std::vector<std::vector<Triplet>> runs;
    for (const int n : {1, 2, 3, 1}) {
      omp_set_num_threads(n);
      std::vector<Triplet> H;
      term.addHessian(sim->termContext(), H, 0, psd);
      runs.push_back(std::move(H));
    }
    omp_set_num_threads(threads);
    for (size_t r = 1; r < runs.size(); ++r) {
      ASSERT_EQ(runs[r].size(), runs[0].size());
      for (size_t k = 0; k < runs[0].size(); ++k) {
        ASSERT_EQ(runs[r][k].row(), runs[0][k].row());
        ASSERT_EQ(runs[r][k].col(), runs[0][k].col());
        ASSERT_EQ(runs[r][k].value(), runs[0][k].value()) << "run " << r << ", entry " << k;
      }
    }
  }
}

}  // namespace
}  // namespace flsh
