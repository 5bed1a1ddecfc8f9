// The skeleton-aware basis (modal_basis.h): the soft tissue's rest operators against the energy
// they linearize and the skinning they couple to, the static-correction and vibration columns,
// mass-orthonormality, compression, the linear response the basis is for, and the errors.
#include "flsh/volume/modal_basis.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <Eigen/SparseCholesky>
#include <cmath>
#include <random>

#include "flsh/core/error.h"
#include "flsh/energy/fem_material.h"
#include "flsh/volume/elastic_tets.h"
#include "flsh/volume/soft_avatar.h"
#include "support/test_support.h"
#include "volume/lowest_eigenpairs.h"
#include "volume/sparse_cholesky.h"

namespace flsh {
namespace {

using test::messageOf;

// The 800-vertex synthetic body's soft avatar on a coarse interior, built once per binary.
const VolumetricData& volume() {
  static std::shared_ptr<const SoftAvatar> avatar = [] {
    auto a = std::make_shared<SoftAvatar>(
        test::smallScene(800).body, VecX(),
        test::smallSoftAvatarSettings(test::freshTempDir("modal_basis_volume_cache")));
    a->enableSoftTissue();
    a->initVolumetricData();
    return a;
  }();
  return avatar->volumetricData();
}

const SoftTissueRestOperators& operators() {
  static const SoftTissueRestOperators ops = softTissueRestOperators(volume());
  return ops;
}

ModalBasisSettings smallSettings() {
  ModalBasisSettings s;
  s.vibration_modes = 20;
  return s;
}

const ModalBasis& basis() {
  static const ModalBasis b = computeModalBasis(volume(), smallSettings());
  return b;
}

// Σ over the elastic tets of the elastic gradient at the soft displacements u (3S), on the soft
// DoFs: the function whose Jacobian at 0 is K_uu.
VecX elasticGradient(const VecX& u) {
  const VolumetricData& data = volume();
  const SoftTissueRestOperators& ops = operators();
  const ElasticTets elements = deformableTets(data);
  const MatX4i& tets = data.templ->mesh.tets;
  VecX g = VecX::Zero(u.size());
  for (int c = 0; c < elements.size(); ++c) {
    const int t = elements.tets[size_t(c)];
    Mat34 U = Mat34::Zero();
    for (int a = 0; a < 4; ++a) {
      const int d = ops.dof_of_node[tets(t, a)];
      if (d >= 0) U.col(a) = u.segment<3>(d);
    }
    Vec12 ge;
    tetElasticEnergy(elements.rest[size_t(c)], elements.materials[size_t(c)], U, &ge);
    for (int a = 0; a < 4; ++a) {
      const int d = ops.dof_of_node[tets(t, a)];
      if (d >= 0) g.segment<3>(d) += ge.segment<3>(3 * a);
    }
  }
  return g;
}

TEST(SoftTissueRestOperators, StiffnessIsTheElasticHessianAtRest) {
  const SoftTissueRestOperators& ops = operators();
  const Eigen::Index n = ops.stiffness.rows();
  ASSERT_EQ(n, 3 * ops.numSoftNodes());
  ASSERT_GT(ops.stiffness.norm(), 0.0);
  EXPECT_EQ((SpMat(ops.stiffness.transpose()) - ops.stiffness).norm(), 0.0);
  std::mt19937_64 rng(3);
  std::normal_distribution<double> normal;
  VecX v(n);
  for (Eigen::Index i = 0; i < n; ++i) v[i] = normal(rng);
  v *= 1e-3 / v.norm();
  const double eps = 1e-4;
  const VecX fd = (elasticGradient(eps * v) - elasticGradient(-eps * v)) / (2 * eps);
  const VecX Kv = ops.stiffness * v;
  ASSERT_GT(Kv.norm(), 0.0);
  EXPECT_LT((fd - Kv).norm(), 1e-5 * Kv.norm());
  // Positive definite (bone nodes hold the tissue): vᵀKv > 0.
  EXPECT_GT(v.dot(Kv), 0.0);
}

TEST(SoftTissueRestOperators, MassesAndCouplingFollowTheRigidMotionsOfTheSkeleton) {
  const VolumetricData& data = volume();
  const SoftTissueRestOperators& ops = operators();
  const int B = int(data.rest_joints.rows()), S = ops.numSoftNodes();
  ASSERT_EQ(ops.coupling.rows(), 3 * S);
  ASSERT_EQ(ops.coupling.cols(), 6 * B);
  ASSERT_GT(ops.masses.minCoeff(), 0.0);
  // Every bone translating by d: every node translates by d (weights sum to 1), so M_ub maps it
  // to the node masses times d.
  const Vec3 d(0.3, -0.2, 0.5);
  VecX translate = VecX::Zero(6 * B);
  for (int b = 0; b < B; ++b) translate.segment<3>(6 * b) = d;
  const VecX f = ops.coupling * translate;
  ASSERT_GT(f.norm(), 0.0);
  for (int i = 0; i < S; ++i)
    EXPECT_LT((f.segment<3>(3 * i) - ops.masses[3 * i] * d).norm(), 1e-12 * d.norm());
  // The whole body turning by ω about c: bone b moves its joint by ω × (J_b − c) and turns by ω;
  // node j then moves by ω × (X̄_j − c).
  const Vec3 omega(0.1, 0.7, -0.4), c(0.05, 0.9, 0.02);
  VecX turn = VecX::Zero(6 * B);
  for (int b = 0; b < B; ++b) {
    turn.segment<3>(6 * b) = omega.cross(Vec3(data.rest_joints.row(b).transpose()) - c);
    turn.segment<3>(6 * b + 3) = omega;
  }
  const VecX g = ops.coupling * turn;
  double worst = 0.0;
  for (int i = 0; i < S; ++i) {
    const Vec3 X = data.rest_nodes.row(ops.soft_nodes[i]).transpose();
    worst = std::max(worst, (g.segment<3>(3 * i) - ops.masses[3 * i] * omega.cross(X - c)).norm() /
                                ops.masses[3 * i]);
  }
  EXPECT_LT(worst, 1e-12);
  // Bone nodes have no DoF; soft nodes' DoFs are 3i in order.
  for (int j = 0; j < data.numNodes(); ++j)
    EXPECT_EQ(ops.dof_of_node[j] < 0, data.bone_of_node[j] >= 0) << "node " << j;
}

TEST(ModalBasis, IsMassOrthonormalAndZeroOnBoneNodes) {
  const VolumetricData& data = volume();
  const ModalBasis& b = basis();
  ASSERT_EQ(b.basis.rows(), 3 * data.numNodes());
  ASSERT_GT(b.columns(), 0);
  EXPECT_EQ(b.report.static_columns, 6 * int(data.rest_joints.rows()));
  EXPECT_EQ(b.report.vibration_columns, 20);
  EXPECT_EQ(b.columns() + b.report.dropped_columns, 6 * 24 + 20);
  const SoftTissueRestOperators& ops = operators();
  MatX soft(3 * ops.numSoftNodes(), b.columns());
  for (int i = 0; i < ops.numSoftNodes(); ++i)
    soft.middleRows<3>(3 * i) = b.basis.middleRows<3>(3 * ops.soft_nodes[i]);
  const MatX G = soft.transpose() * ops.masses.asDiagonal() * soft;
  EXPECT_LT((G - MatX::Identity(G.rows(), G.cols())).cwiseAbs().maxCoeff(), 1e-8);
  double on_bone_nodes = 0.0;
  for (int j = 0; j < data.numNodes(); ++j)
    if (data.bone_of_node[j] >= 0) on_bone_nodes += b.basis.middleRows<3>(3 * j).norm();
  EXPECT_EQ(on_bone_nodes, 0.0);
  // The vibration modes: ascending positive frequencies, converged.
  ASSERT_EQ(b.report.frequencies.size(), 20);
  EXPECT_GT(b.report.frequencies[0], 0.0);
  for (int k = 1; k < 20; ++k) EXPECT_GE(b.report.frequencies[k], b.report.frequencies[k - 1]);
  EXPECT_LE(b.report.max_eigen_residual, 1e-5);
}

// M-projection residual of the columns of X on the basis, relative to their M-norms.
double outOfSpan(const MatX& soft_basis, const VecX& m, const MatX& X) {
  const MatX P = soft_basis * (soft_basis.transpose() * (m.asDiagonal() * X));
  const MatX R = X - P;
  const VecX residual = (R.cwiseAbs2().transpose() * m).cwiseSqrt();
  const VecX size = (X.cwiseAbs2().transpose() * m).cwiseSqrt();
  return residual.maxCoeff() / size.minCoeff();
}

TEST(ModalBasis, SpansEveryStaticResponseToTheSkeleton) {
  // The static response to any bone acceleration a (K_uu u = −M_ub a) lies in the span: Galerkin
  // in the basis reproduces it.
  const SoftTissueRestOperators& ops = operators();
  const ModalBasis& b = basis();
  MatX soft(3 * ops.numSoftNodes(), b.columns());
  for (int i = 0; i < ops.numSoftNodes(); ++i)
    soft.middleRows<3>(3 * i) = b.basis.middleRows<3>(3 * ops.soft_nodes[i]);
  std::mt19937_64 rng(7);
  std::normal_distribution<double> normal;
  MatX a(ops.coupling.cols(), 3);
  for (Eigen::Index i = 0; i < a.size(); ++i) a.data()[i] = normal(rng);
  const MatX F = -(ops.coupling * a);
  const MatX Kr = soft.transpose() * (ops.stiffness * soft);
  const MatX reduced = soft * Kr.llt().solve(soft.transpose() * F);
  const MatX residual = ops.stiffness * reduced - F;
  ASSERT_GT(reduced.norm(), 0.0);
  EXPECT_LT(residual.norm(), 1e-7 * F.norm());
}

TEST(ModalBasis, BackwardEulerStepsStayCloseToTheFullSolution) {
  // The use the basis is built for (issue 26): the tissue linearized at rest, driven by bone
  // accelerations, stepped by backward Euler at 30 Hz; Galerkin in the basis against the full
  // solve, compared on the soft nodes (mass-weighted). The static modes alone already follow
  // the full solution closely; the vibration modes take the rest of the way.
  const SoftTissueRestOperators& ops = operators();
  const double h = 1.0 / 30.0;
  const SpMat A = SpMat(ops.masses.asDiagonal() * (1.0 / (h * h))) + ops.stiffness;
  const Eigen::SimplicialLLT<SpMat> full(A);
  ASSERT_EQ(full.info(), Eigen::Success);
  std::mt19937_64 rng(11);
  std::normal_distribution<double> normal;
  // A smooth push of every bone DoF (half a sine over 1/3 s, random amplitudes ~20 m/s² or
  // rad/s²), then 1/3 s of free motion.
  VecX amplitude(ops.coupling.cols());
  for (Eigen::Index i = 0; i < amplitude.size(); ++i) amplitude[i] = 20.0 * normal(rng);
  std::vector<VecX> accelerations;
  for (int n = 0; n < 20; ++n)
    accelerations.push_back((n < 10 ? std::sin(M_PI * n / 10.0) : 0.0) * amplitude);
  auto relativeError = [&](const ModalBasisSettings& settings) {
    const MatX V = modalColumns(ops, settings);
    const MatX Ar = V.transpose() * (A * V);
    const Eigen::LLT<MatX> reduced(Ar);
    const MatX Mr = V.transpose() * ops.masses.asDiagonal() * V;
    VecX u = VecX::Zero(A.rows()), u_prev = u, z = VecX::Zero(V.cols()), z_prev = z;
    double error = 0.0, size = 0.0;
    for (const VecX& a : accelerations) {
      const VecX rhs = ops.masses.cwiseProduct(2 * u - u_prev) / (h * h) - ops.coupling * a;
      u_prev = u;
      u = full.solve(rhs);
      const VecX zr = Mr * (2 * z - z_prev) / (h * h) - V.transpose() * (ops.coupling * a);
      z_prev = z;
      z = reduced.solve(zr);
      const VecX d = V * z - u;
      error += d.cwiseAbs2().dot(ops.masses);
      size += u.cwiseAbs2().dot(ops.masses);
    }
    EXPECT_GT(size, 0.0);
    return std::sqrt(error / size);
  };
  ModalBasisSettings statics;
  statics.vibration_modes = 0;
  const double static_error = relativeError(statics);
  const double modal_error = relativeError(smallSettings());
  // Measured: 1.5 % and 0.27 %.
  EXPECT_LT(static_error, 0.03);
  EXPECT_LT(modal_error, 0.3 * static_error);
}

TEST(ModalBasis, CompressionKeepsTheLeadingMassPrincipalColumns) {
  ModalBasisSettings s = smallSettings();
  s.columns = 40;
  ModalBasisReport report;
  const MatX V = modalColumns(operators(), s, &report);
  ASSERT_EQ(V.cols(), 40);
  EXPECT_EQ(report.dropped_columns, 6 * 24 + 20 - 40);
  const MatX G = V.transpose() * operators().masses.asDiagonal() * V;
  EXPECT_LT((G - MatX::Identity(40, 40)).cwiseAbs().maxCoeff(), 1e-8);
  // The compressed span is the leading part of the full one.
  const ModalBasis& full = basis();
  const SoftTissueRestOperators& ops = operators();
  MatX soft(3 * ops.numSoftNodes(), full.columns());
  for (int i = 0; i < ops.numSoftNodes(); ++i)
    soft.middleRows<3>(3 * i) = full.basis.middleRows<3>(3 * ops.soft_nodes[i]);
  EXPECT_LT(outOfSpan(soft, ops.masses, V), 1e-6);
}

// The static modes ψ_k = K⁻¹ M_ub e_k, the rotations' (k mod 6 ≥ 3) times `rotation_weight`.
MatX weightedStatics(const SoftTissueRestOperators& ops, double rotation_weight) {
  const detail::SparseCholesky factor(ops.stiffness, "test");
  MatX statics = factor.solve(ops.coupling);
  for (Eigen::Index k = 0; k < statics.cols(); ++k)
    if (k % 6 >= 3) statics.col(k) *= rotation_weight;
  return statics;
}

// Σ_k ‖x_k − P x_k‖²_M over the columns of X, P the M-projection on the (M-orthonormal) basis.
double squaredResidual(const SoftTissueRestOperators& ops, const MatX& basis, const MatX& X) {
  const MatX R = X - basis * (basis.transpose() * ops.masses.asDiagonal() * X);
  return (R.transpose() * ops.masses.asDiagonal() * R).trace();
}

// Compression weighs the static modes by the load they answer (their raw size, a rotation's
// times rotation_weight), so those responses are kept better than by a mass-PCA of the
// normalized columns: the weighted PCA is the best r-dimensional span for Σ_k w_k² ‖ψ_k −
// Pψ_k‖²_M (Eckart–Young), the normalized one is not.
TEST(ModalBasis, CompressionKeepsTheLargestStaticResponsesBest) {
  const SoftTissueRestOperators& ops = operators();
  ModalBasisSettings s = smallSettings();
  s.vibration_modes = 0;
  s.columns = 24;
  const MatX V = modalColumns(ops, s, nullptr);
  ASSERT_EQ(V.cols(), 24);
  const MatX statics = weightedStatics(ops, s.rotation_weight);
  ASSERT_GT(statics.norm(), 0.0);
  const MatX normalized = detail::massOrthonormalize(statics, ops.masses, 1e-10, 24);
  ASSERT_EQ(normalized.cols(), 24);
  EXPECT_LT(squaredResidual(ops, V, statics), 0.8 * squaredResidual(ops, normalized, statics));
  EXPECT_LT(squaredResidual(ops, V, statics), squaredResidual(ops, V.leftCols(23), statics));
  // Eckart–Young: no span of 24 columns keeps the weighted statics better, e.g. not the one
  // compressed with the rotations at full weight.
  ModalBasisSettings full_weight = s;
  full_weight.rotation_weight = 1.0;
  const MatX U = modalColumns(ops, full_weight, nullptr);
  EXPECT_LT(squaredResidual(ops, V, statics), squaredResidual(ops, U, statics));
}

// The rotation weight trades the rotations' static responses against the translations': a
// smaller weight keeps the translations better and the rotations worse, and without
// compression it changes nothing.
TEST(ModalBasis, RotationWeightTradesRotationsForTranslations) {
  const SoftTissueRestOperators& ops = operators();
  const MatX statics = weightedStatics(ops, 1.0);
  MatX translations(statics.rows(), statics.cols() / 2),
      rotations(statics.rows(), statics.cols() / 2);
  for (Eigen::Index b = 0; b < statics.cols() / 6; ++b) {
    translations.middleCols<3>(3 * b) = statics.middleCols<3>(6 * b);
    rotations.middleCols<3>(3 * b) = statics.middleCols<3>(6 * b + 3);
  }
  ASSERT_GT(rotations.norm(), 0.0);
  ModalBasisSettings s = smallSettings();
  s.vibration_modes = 0;
  s.columns = 24;
  s.rotation_weight = 0.1;
  const MatX light = modalColumns(ops, s, nullptr);
  s.rotation_weight = 10.0;
  const MatX heavy = modalColumns(ops, s, nullptr);
  EXPECT_LT(squaredResidual(ops, light, translations), squaredResidual(ops, heavy, translations));
  EXPECT_GT(squaredResidual(ops, light, rotations), squaredResidual(ops, heavy, rotations));
  s.columns = 0;
  s.rotation_weight = 0.1;
  const MatX all_light = modalColumns(ops, s, nullptr);
  s.rotation_weight = 1.0;
  const MatX all = modalColumns(ops, s, nullptr);
  ASSERT_EQ(all_light.cols(), all.cols());
  EXPECT_EQ((all_light - all).cwiseAbs().maxCoeff(), 0.0);
}

TEST(ModalBasis, SettingsOutOfRangeAreNamed) {
  const SoftTissueRestOperators& ops = operators();
  ModalBasisSettings s;
  s.vibration_modes = -1;
  EXPECT_NE(messageOf<InputError>([&] { modalColumns(ops, s); }).find("vibration_modes = -1"),
            std::string::npos);
  s = ModalBasisSettings();
  s.columns = -2;
  EXPECT_NE(messageOf<InputError>([&] { modalColumns(ops, s); }).find("columns = -2"),
            std::string::npos);
  s = ModalBasisSettings();
  s.static_modes = false;
  s.vibration_modes = 0;
  EXPECT_NE(messageOf<InputError>([&] { modalColumns(ops, s); }).find("no columns"),
            std::string::npos);
  for (double weight : {0.0, -1.0, std::nan("")}) {
    s = ModalBasisSettings();
    s.rotation_weight = weight;
    EXPECT_NE(messageOf<InputError>([&] { modalColumns(ops, s); }).find("rotation_weight"),
              std::string::npos);
  }
  s = ModalBasisSettings();
  s.eigen_tolerance = 0.0;
  EXPECT_NE(messageOf<InputError>([&] { modalColumns(ops, s); }).find("eigen_tolerance"),
            std::string::npos);
  VolumetricData empty;
  EXPECT_NE(messageOf<InputError>([&] { softTissueRestOperators(empty); }).find("no template"),
            std::string::npos);
}

}  // namespace
}  // namespace flsh
