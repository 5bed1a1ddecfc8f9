// The skeleton-aware basis of the soft tissue: static-correction and fixed-interface vibration
// modes of the tissue linearized at rest (see modal_basis.h).
#include "flsh/volume/modal_basis.h"

#include <omp.h>

#include <chrono>
#include <cmath>
#include <string>
#include <vector>

#include "core/seconds_since.h"
#include "flsh/core/error.h"
#include "flsh/core/rotation.h"
#include "flsh/energy/fem_material.h"
#include "flsh/volume/elastic_tets.h"
#include "flsh/volume/reduced_data.h"
#include "volume/lowest_eigenpairs.h"
#include "volume/sparse_cholesky.h"

namespace flsh {

namespace {

using Clock = std::chrono::steady_clock;
using detail::secondsSince;

}  // namespace

SoftTissueRestOperators softTissueRestOperators(const VolumetricData& data) {
  const std::string fn = "softTissueRestOperators: ";
  if (!data.templ) throw InputError(fn + "the volumetric data has no template mesh");
  const int N = data.numNodes();
  const MatX& W = data.templ->fields.weights;
  if (data.bone_of_node.size() != N || W.rows() != N || data.rest_joints.rows() != W.cols())
    throw InputError(fn + "bone_of_node has " + std::to_string(data.bone_of_node.size()) +
                     " entries and the skinning weights " + std::to_string(W.rows()) + " × " +
                     std::to_string(W.cols()) + " for " + std::to_string(N) + " nodes and " +
                     std::to_string(data.rest_joints.rows()) + " joints, expected #N rows and " +
                     "one weight column per joint");
  SoftTissueRestOperators ops;
  ops.dof_of_node = VecXi::Constant(N, -1);
  std::vector<int> soft;
  for (int j = 0; j < N; ++j)
    if (data.bone_of_node[j] < 0) {
      ops.dof_of_node[j] = 3 * int(soft.size());
      soft.push_back(j);
    }
  if (soft.empty()) throw InputError(fn + "the avatar has no soft-tissue nodes");
  ops.soft_nodes = Eigen::Map<const VecXi>(soft.data(), Eigen::Index(soft.size()));
  const int S = int(soft.size()), B = int(W.cols());

  // K_uu: the elastic tets' Hessians at rest, on their soft nodes' DoFs.
  const ElasticTets elements = deformableTets(data);
  const MatX4i& tets = data.templ->mesh.tets;
  std::vector<std::vector<Triplet>> per_thread(1);
#pragma omp parallel
  {
#pragma omp single
    per_thread.resize(size_t(omp_get_num_threads()));
    std::vector<Triplet>& out = per_thread[size_t(omp_get_thread_num())];
#pragma omp for schedule(static)
    for (int c = 0; c < elements.size(); ++c) {
      const int t = elements.tets[size_t(c)];
      Mat12 K;
      tetElasticEnergy(elements.rest[size_t(c)], elements.materials[size_t(c)], Mat34::Zero(),
                       nullptr, &K, false);
      for (int a = 0; a < 4; ++a) {
        const int da = ops.dof_of_node[tets(t, a)];
        if (da < 0) continue;
        for (int b = 0; b < 4; ++b) {
          const int db = ops.dof_of_node[tets(t, b)];
          if (db < 0) continue;
          for (int r = 0; r < 3; ++r)
            for (int s = 0; s < 3; ++s) out.emplace_back(da + r, db + s, K(3 * a + r, 3 * b + s));
        }
      }
    }
  }
  std::vector<Triplet> triplets;
  for (const auto& part : per_thread) triplets.insert(triplets.end(), part.begin(), part.end());
  ops.stiffness.resize(3 * S, 3 * S);
  ops.stiffness.setFromTriplets(triplets.begin(), triplets.end());
  const SpMat transposed = ops.stiffness.transpose();
  ops.stiffness = 0.5 * (ops.stiffness + transposed);  // exactly symmetric

  // M_uu (lumped) and M_ub at rest: x_j = Σ_b w_jb (δt_b + δω_b × (X̄_j − J_b)) + u_j.
  const VecX node_mass = inertialNodeMasses(data, exactCubature(data.numTets()));
  ops.masses.resize(3 * S);
  ops.coupling = MatX::Zero(3 * S, 6 * B);
  for (int i = 0; i < S; ++i) {
    const int j = soft[size_t(i)];
    const double mass = node_mass[j];
    if (!(mass > 0.0))
      throw InputError(fn + "soft node " + std::to_string(j) +
                       " has no mass (it belongs to no tet with a positive density)");
    ops.masses.segment<3>(3 * i).setConstant(mass);
    for (int b = 0; b < B; ++b) {
      const double w = W(j, b);
      if (w == 0.0) continue;
      const Vec3 r = (data.rest_nodes.row(j) - data.rest_joints.row(b)).transpose();
      ops.coupling.block<3, 3>(3 * i, 6 * b) = (mass * w) * Mat3::Identity();
      ops.coupling.block<3, 3>(3 * i, 6 * b + 3) = -(mass * w) * skew(r);
    }
  }
  return ops;
}

MatX modalColumns(const SoftTissueRestOperators& ops, const ModalBasisSettings& settings,
                  ModalBasisReport* report) {
  const std::string fn = "modalColumns: ";
  const Eigen::Index n = ops.stiffness.rows();
  if (settings.vibration_modes < 0 || settings.vibration_modes > n)
    throw InputError(fn + "vibration_modes = " + std::to_string(settings.vibration_modes) +
                     ", expected an integer in [0, " + std::to_string(n) +
                     "] (the soft tissue's DoFs)");
  if (settings.columns < 0)
    throw InputError(fn + "columns = " + std::to_string(settings.columns) +
                     ", expected 0 (keep all) or a positive integer");
  if (!(settings.rotation_weight > 0.0 && std::isfinite(settings.rotation_weight)))
    throw InputError(fn + "rotation_weight = " + std::to_string(settings.rotation_weight) +
                     ", expected a positive finite number (m/s² per rad/s²)");
  if (!(settings.eigen_tolerance > 0.0 && settings.eigen_tolerance < 1.0))
    throw InputError(fn + "eigen_tolerance = " + std::to_string(settings.eigen_tolerance) +
                     ", expected in (0, 1)");
  if (!(settings.dependence_tolerance >= 0.0 && settings.dependence_tolerance < 1.0))
    throw InputError(fn + "dependence_tolerance = " +
                     std::to_string(settings.dependence_tolerance) + ", expected in [0, 1)");
  if (!settings.static_modes && settings.vibration_modes == 0)
    throw InputError(fn + "no columns: static_modes is off and vibration_modes = 0");
  if (ops.masses.size() != n || ops.coupling.rows() != n)
    throw InputError(fn + "the operators' sizes do not match (stiffness " + std::to_string(n) +
                     " rows, masses " + std::to_string(ops.masses.size()) + ", coupling " +
                     std::to_string(ops.coupling.rows()) + ")");
  ModalBasisReport local;
  ModalBasisReport& r = report ? *report : local;
  auto t0 = Clock::now();
  const detail::SparseCholesky factor(ops.stiffness, "modalColumns (K_uu)");
  r.seconds_factor = secondsSince(t0);

  MatX statics;
  if (settings.static_modes) {
    t0 = Clock::now();
    statics = factor.solve(ops.coupling);
    r.factor_solves += int(ops.coupling.cols());
    r.static_columns = int(statics.cols());
    r.seconds_static = secondsSince(t0);
  }
  detail::LowestEigenpairs modes;
  if (settings.vibration_modes > 0) {
    t0 = Clock::now();
    detail::LowestEigenpairsOptions eig;
    eig.tolerance = settings.eigen_tolerance;
    eig.seed = settings.seed;
    modes =
        detail::lowestEigenpairs(ops.stiffness, factor, ops.masses, settings.vibration_modes, eig);
    if (!modes.converged)
      throw Error(fn + "the vibration modes did not converge: relative residual " +
                  std::to_string(modes.max_residual) + " after " +
                  std::to_string(modes.iterations) + " Lanczos steps, expected ≤ " +
                  std::to_string(settings.eigen_tolerance));
    r.vibration_columns = int(modes.values.size());
    r.frequencies = modes.values.cwiseSqrt() / (2.0 * M_PI);
    r.max_eigen_residual = modes.max_residual;
    r.eigen_iterations = modes.iterations;
    r.factor_solves += modes.solves;
    r.seconds_vibration = secondsSince(t0);
  }
  t0 = Clock::now();
  MatX columns(n, statics.cols() + modes.vectors.cols());
  columns << statics, modes.vectors;
  // Compression weighs each column by the load it answers: a static mode by the acceleration
  // it answers (1 m/s² for a translation, rotation_weight for a rotation), each vibration mode
  // by its static participation ‖φᵀ M_ub W‖ / λ (its share of those responses). Normalized
  // columns would count a mode that barely moves as much as the main ones (docs/benchmarks.md:
  // 2–3× the error).
  const bool weighted = settings.columns > 0;
  if (weighted) {
    VecX dof_weight = VecX::Ones(ops.coupling.cols());  // W: column 6b + a, a ≥ 3 a rotation
    for (Eigen::Index k = 0; k < dof_weight.size(); ++k)
      if (k % 6 >= 3) dof_weight[k] = settings.rotation_weight;
    for (Eigen::Index k = 0; k < statics.cols(); ++k) columns.col(k) *= dof_weight[k];
    const MatX weighted_coupling = ops.coupling * dof_weight.asDiagonal();
    for (Eigen::Index i = 0; i < modes.values.size(); ++i)
      columns.col(statics.cols() + i) *=
          (modes.vectors.col(i).transpose() * weighted_coupling).norm() / modes.values[i];
  }
  MatX basis = detail::massOrthonormalize(columns, ops.masses, settings.dependence_tolerance,
                                          settings.columns, !weighted);
  r.dropped_columns = int(columns.cols() - basis.cols());
  r.seconds_orthonormalize = secondsSince(t0);
  return basis;
}

ModalBasis computeModalBasis(const VolumetricData& data, const ModalBasisSettings& settings) {
  const auto start = Clock::now();
  ModalBasis out;
  const SoftTissueRestOperators ops = softTissueRestOperators(data);
  out.report.seconds_operators = secondsSince(start);
  const MatX columns = modalColumns(ops, settings, &out.report);
  out.basis = MatX::Zero(3 * data.numNodes(), columns.cols());
  for (int i = 0; i < ops.numSoftNodes(); ++i)
    out.basis.middleRows<3>(3 * ops.soft_nodes[i]) = columns.middleRows<3>(3 * i);
  out.report.seconds_total = secondsSince(start);
  return out;
}

}  // namespace flsh
