// Reduced bases for the soft tissue, ranked by the linear test of issue 26: the FEM soft tissue
// linearized at rest (K_uu, M_uu, M_ub of volume/modal_basis.h), bones prescribed from skeleton
// runs of built-in motions on the ground, backward Euler at h = 1/30 s; the full solve against
// Galerkin in each basis and against the basis' best fit (the M-orthogonal projection of the full
// solution). Error: RMS over the surface vertices' soft-tissue displacement of all steps,
// relative to the full solution's. Also the time to build each modal basis (cold, no cache).
//
// The bones' accelerations: per step the second difference of each bone's position and the
// first difference of its angular velocity (log R_{n+1} R_nᵀ / h), expressed in the bone's frame
// (the tissue is linearized in its rest frame).
//
// Usage: modal_basis_benchmark [--motions walk,jumping_jacks] [--seconds 2] [--vertices 6890]
//                              [--resolution 1] [--handles 87] [--modes 0,50,150]
//                              [--columns 24,48,96]
// --vertices 6890 (the default) is the full-size synthetic body; every figure is a relative error
// or a build time.
#include <Eigen/Cholesky>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "flsh/body/motion.h"
#include "flsh/body/synthetic_body.h"
#include "flsh/core/error.h"
#include "flsh/core/rotation.h"
#include "flsh/solve/linear_solver.h"
#include "flsh/solve/scene.h"
#include "flsh/volume/modal_basis.h"
#include "flsh/volume/reduced_data.h"

namespace {

using namespace flsh;
using Clock = std::chrono::steady_clock;

double secondsSince(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

std::vector<std::string> split(const std::string& text) {
  std::vector<std::string> out;
  std::stringstream in(text);
  for (std::string item; std::getline(in, item, ',');)
    if (!item.empty()) out.push_back(item);
  return out;
}

// Per step: the 6B bone accelerations (each bone's δt and δω in its own frame) of a skeleton run.
std::vector<VecX> boneAccelerations(const std::shared_ptr<BodyModel>& body,
                                    const std::string& motion_name, double seconds, double h) {
  auto avatar = std::make_shared<SoftAvatar>(body, VecX(), SoftAvatarSettings());
  avatar->initVolumetricData();
  auto motion = std::make_shared<Motion>(makeBuiltinMotion(motion_name, seconds, 1.0 / h));
  SimulableOptions options;
  options.time_step = h;
  auto sim = std::make_shared<Simulable>(avatar, motion, options);
  Scene scene;
  scene.addSimulable(sim);
  scene.initialize();
  scene.addCollider(
      Collider::plane(Vec3(0, sim->getNodes().col(1).minCoeff() - 0.002, 0), Vec3::UnitY()));
  std::vector<VecX> states{sim->getState()};
  const int steps = int(std::lround(seconds / h));
  for (int k = 0; k < steps; ++k) {
    scene.step();
    states.push_back(sim->getState());
  }
  const int B = int(states[0].size() / 6);
  auto velocity = [&](int k) {  // between states k and k + 1
    VecX v(6 * B);
    for (int b = 0; b < B; ++b) {
      v.segment<3>(6 * b) = (states[k + 1].segment<3>(6 * b) - states[k].segment<3>(6 * b)) / h;
      const Mat3 R1 = rodrigues(states[k + 1].segment<3>(6 * b + 3));
      const Mat3 R0 = rodrigues(states[k].segment<3>(6 * b + 3));
      v.segment<3>(6 * b + 3) = logSO3(R1 * R0.transpose()) / h;
    }
    return v;
  };
  std::vector<VecX> out;
  for (int k = 0; k + 2 < int(states.size()); ++k) {
    const VecX a = (velocity(k + 1) - velocity(k)) / h;
    VecX local(6 * B);
    for (int b = 0; b < B; ++b) {
      const Mat3 R = rodrigues(states[k + 1].segment<3>(6 * b + 3));
      local.segment<3>(6 * b) = R.transpose() * a.segment<3>(6 * b);
      local.segment<3>(6 * b + 3) = R.transpose() * a.segment<3>(6 * b + 3);
    }
    out.push_back(local);
  }
  return out;
}

struct Errors {
  double galerkin = 0, best = 0;
};

}  // namespace

int main(int argc, char** argv) {
  std::vector<std::string> motions{"walk", "jumping_jacks"};
  std::vector<int> mode_counts{0, 50, 150};
  std::vector<int> column_counts;  // mass-PCA compressions of the last --modes basis
  double seconds = 2.0, resolution = 1.0;
  int vertices = 6890, handles = 87;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto value = [&]() -> std::string {
      if (i + 1 >= argc) {
        std::fprintf(stderr, "modal_basis_benchmark: %s needs a value\n", a.c_str());
        std::exit(2);
      }
      return argv[++i];
    };
    if (a == "--motions")
      motions = split(value());
    else if (a == "--seconds")
      seconds = std::atof(value().c_str());
    else if (a == "--vertices")
      vertices = std::atoi(value().c_str());
    else if (a == "--resolution")
      resolution = std::atof(value().c_str());
    else if (a == "--handles")
      handles = std::atoi(value().c_str());
    else if (a == "--modes") {
      mode_counts.clear();
      for (const std::string& m : split(value())) mode_counts.push_back(std::atoi(m.c_str()));
    } else if (a == "--columns") {
      for (const std::string& c : split(value())) column_counts.push_back(std::atoi(c.c_str()));
    } else {
      std::fprintf(stderr,
                   "usage: modal_basis_benchmark [--motions walk,jumping_jacks] [--seconds 2] "
                   "[--vertices 6890] [--resolution 1] [--handles 87] [--modes 0,50,150] "
                   "[--columns 24,48,96]\n");
      return 2;
    }
  }
  try {
    SyntheticBodyOptions body_options;
    body_options.vertices = vertices;
    auto body = std::make_shared<BodyModel>(makeSyntheticBody(body_options));
    SoftAvatarSettings settings;
    settings.volumetric.tet_mesh.resolution = resolution;
    settings.reduced.basis_kind = ReducedBasisKind::Handles;
    settings.reduced.num_handles = handles;
    auto avatar = std::make_shared<SoftAvatar>(body, VecX(), settings);
    avatar->enableSoftTissue();
    avatar->enableReducedModel();
    avatar->enableElasticCubature(false);
    avatar->enableInertialCubature(false);
    avatar->initVolumetricData();
    const VolumetricData& data = avatar->volumetricData();
    const auto t_ops = Clock::now();
    const SoftTissueRestOperators ops = softTissueRestOperators(data);
    const double seconds_operators = secondsSince(t_ops);
    const int n = int(ops.stiffness.rows()), V = body->numVertices();
    std::printf(
        "%d vertices, resolution %g: %d nodes (%d soft, %d soft DoFs), %d tets; "
        "operators K_uu, M_uu, M_ub in %.2f s\n",
        V, resolution, data.numNodes(), ops.numSoftNodes(), n, data.numTets(), seconds_operators);

    // The bases, each as soft-DoF columns (n × r).
    std::vector<std::pair<std::string, MatX>> bases;
    {
      const SpMat& phi = avatar->reducedData().basis;  // #N × H scalar weights
      MatX kron = MatX::Zero(n, 3 * phi.cols());
      for (int h = 0; h < phi.cols(); ++h)
        for (SpMat::InnerIterator it(phi, h); it; ++it) {
          const int d = ops.dof_of_node[it.row()];
          if (d < 0) continue;
          for (int a = 0; a < 3; ++a) kron(d + a, 3 * h + a) = it.value();
        }
      bases.emplace_back(std::to_string(phi.cols()) + " handles (bounded biharmonic)", kron);
    }
    std::printf(
        "\nmodal bases from the operators (cold), s: factor / static / vibration = total; "
        "frequencies\n");
    auto build = [&](const std::string& name, const ModalBasisSettings& s) {
      const auto t0 = Clock::now();
      ModalBasisReport r;
      MatX columns = modalColumns(ops, s, &r);
      const double total = secondsSince(t0);
      std::printf("  %-34s %4d columns: %.2f / %.2f / %.2f = %.2f s", name.c_str(),
                  int(columns.cols()), r.seconds_factor, r.seconds_static, r.seconds_vibration,
                  total);
      if (r.frequencies.size() > 0)
        std::printf("; %.2f–%.2f Hz, residual %.1e, %d Lanczos steps, %d solves", r.frequencies[0],
                    r.frequencies[r.frequencies.size() - 1], r.max_eigen_residual,
                    r.eigen_iterations, r.factor_solves);
      std::printf("\n");
      bases.emplace_back(name, std::move(columns));
    };
    for (int m : mode_counts) {
      ModalBasisSettings s;
      s.vibration_modes = m;
      build(m == 0 ? "static modes" : "static + " + std::to_string(m) + " vibration modes", s);
    }
    for (int c : column_counts) {
      ModalBasisSettings s;
      s.vibration_modes = mode_counts.empty() ? 0 : mode_counts.back();
      s.columns = c;
      build("the last, compressed to " + std::to_string(c), s);
    }
    {
      ModalBasisSettings s;
      s.static_modes = false;
      s.vibration_modes = mode_counts.empty() ? 150 : std::max(1, mode_counts.back());
      build(std::to_string(s.vibration_modes) + " vibration modes alone", s);
    }

    // Full linear dynamics.
    const double h = 1.0 / 30.0;
    const SpMat A = SpMat(ops.masses.asDiagonal() * (1.0 / (h * h))) + ops.stiffness;
    auto full = makeLinearSolver(LinearSolverType::Cholmod, n);
    if (!full->factorize(A)) throw Error("the linearized tissue is not positive definite");
    std::vector<int> surface;  // soft DoFs of surface vertices
    for (int j = 0; j < V; ++j)
      if (ops.dof_of_node[j] >= 0)
        for (int a = 0; a < 3; ++a) surface.push_back(ops.dof_of_node[j] + a);
    auto surfaceSquares = [&](const VecX& x) {
      double s = 0;
      for (int i : surface) s += x[i] * x[i];
      return s;
    };

    std::printf(
        "\nsurface RMS error of the soft-tissue displacement, relative to the full solve "
        "(Galerkin / best fit), %.1f s per motion at h = 1/30 s\n",
        seconds);
    std::printf("%-40s %7s", "basis", "columns");
    for (const std::string& m : motions) std::printf("  %22s", m.c_str());
    std::printf("\n");
    std::map<std::string, std::vector<Errors>> table;
    std::vector<double> full_rms;
    for (const std::string& motion : motions) {
      const std::vector<VecX> acc = boneAccelerations(body, motion, seconds, h);
      std::vector<VecX> U;
      VecX u = VecX::Zero(n), u_prev = u;
      double full_squares = 0;
      for (const VecX& a : acc) {
        VecX rhs = ops.masses.cwiseProduct(2 * u - u_prev) / (h * h) - ops.coupling * a;
        u_prev = u;
        u = full->solve(rhs);
        U.push_back(u);
        full_squares += surfaceSquares(u);
      }
      full_rms.push_back(std::sqrt(full_squares / (double(surface.size()) * U.size())));
      for (const auto& [name, Vb] : bases) {
        const MatX Mr = Vb.transpose() * ops.masses.asDiagonal() * Vb;
        const MatX Ar = Vb.transpose() * (A * Vb);
        const MatX Br = Vb.transpose() * ops.coupling;
        const Eigen::LLT<MatX> reduced(Ar), mass(Mr);
        VecX z = VecX::Zero(Vb.cols()), z_prev = z;
        double galerkin = 0, best = 0;
        for (size_t k = 0; k < acc.size(); ++k) {
          const VecX rhs = Mr * (2 * z - z_prev) / (h * h) - Br * acc[k];
          z_prev = z;
          z = reduced.solve(rhs);
          galerkin += surfaceSquares(Vb * z - U[k]);
          const VecX fit = Vb * mass.solve(Vb.transpose() * ops.masses.cwiseProduct(U[k]));
          best += surfaceSquares(fit - U[k]);
        }
        table[name].push_back({std::sqrt(galerkin / full_squares), std::sqrt(best / full_squares)});
      }
    }
    for (const auto& [name, Vb] : bases) {
      std::printf("%-40s %7d", name.c_str(), int(Vb.cols()));
      for (const Errors& e : table[name])
        std::printf("  %9.2f %% / %7.2f %%", 100 * e.galerkin, 100 * e.best);
      std::printf("\n");
    }
    std::printf("full solution's surface RMS displacement:");
    for (size_t m = 0; m < motions.size(); ++m)
      std::printf(" %s %.3f mm", motions[m].c_str(), 1e3 * full_rms[m]);
    std::printf("\n");
  } catch (const std::exception& e) {
    std::fprintf(stderr, "modal_basis_benchmark: %s\n", e.what());
    return 2;
  }
  return 0;
}
