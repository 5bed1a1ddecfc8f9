#include "sim/soft/nodal_inertia_term.h"

#include "flsh/body/smpl_skeleton.h"
#include "flsh/core/rotation.h"
#include "sim/soft/node_offset_blocks.h"
#include "sim/soft/on_two_threads.h"
#include "sim/tangent_columns.h"
#include "sim/terms/term_blocks.h"

namespace flsh::detail {

NodalInertiaTerm::NodalInertiaTerm(const SoftKinematics& kinematics, const NodeMasses& masses,
                                   const HeldMassMoments& moments, const MaterialChain& chain,
                                   const ShapeChain& shape, double time_step)
    : NodeTerm(kinematics),
      masses_(masses),
      moments_(moments),
      chain_(chain),
      shape_(shape),
      h_(time_step),
      x_hat_(kinematics.restNodes()) {
  const std::vector<int>& nodes = masses_.nodes;
  const size_t first = size_t((1.0 - kShareBesidePotential) * double(nodes.size()));
  parts_[0].assign(nodes.begin(), nodes.begin() + long(first));
  parts_[1].assign(nodes.begin() + long(first), nodes.end());
}

void NodalInertiaTerm::setPrediction(const BoneFrames& bones_n, const BoneFrames& bones_nm1) {
  MatX3 x_n, x_nm1;
  kin_.positionsOf(masses_.nodes, bones_n, kin_.u_n, x_n);
  kin_.positionsOf(masses_.nodes, bones_nm1, kin_.u_nm1, x_nm1);
  for (int j : masses_.nodes) x_hat_.row(j) = 2.0 * x_n.row(j) - x_nm1.row(j);
  ++prediction_stamp_;
}

void NodalInertiaTerm::updateHeldReference() const {
  const long id = moments_.update();
  if (held_.moments == id && held_.prediction == prediction_stamp_) return;
  kin_.ensurePrepared();  // x at the reference frames (the presolve defers the skinning)
  const int bones = kin_.numBones();
  const MatX3& x = kin_.x();
  const MatX3& Y = kin_.Y();
  const MatX3& J = kin_.joints();
  held_.R0 = kin_.R();
  held_.t0 = kin_.t();
  held_.P.assign(size_t(bones), Vec3::Zero());
  held_.Q.assign(size_t(bones), Mat3::Zero());
  held_.E0 = 0.0;
  for (int j : masses_.nodes) {
    const double m = masses_.mass[j];
    const Vec3 e = (x.row(j) - x_hat_.row(j)).transpose();
    held_.E0 += m * e.squaredNorm();
    for (auto* inf = kin_.influencesBegin(j); inf != kin_.influencesEnd(j); ++inf) {
      const double mw = m * inf->weight;
      held_.P[size_t(inf->bone)] += mw * e;
      held_.Q[size_t(inf->bone)].noalias() +=
          (mw * (Y.row(j) - J.row(inf->bone)).transpose()) * e.transpose();
    }
  }
  held_.moments = id;
  held_.prediction = prediction_stamp_;
}

// With f_j = κ m_j (x_j − x̂_j) = κ m_j (e⁰_j + Σ_c w_jc d_jc), per bone b:
//   F_b = Σ_j w_jb f_j / κ = P_b + Σ_c (ΔR_c U_cb + S_cb Δt_c)          (the translation rows)
//   O_b = Σ_j w_jb f_j Ỹ_jbᵀ / κ = Q_bᵀ + Σ_c (ΔR_c V_cb + Δt_c U_bcᵀ)  (body-frame levers)
// so the rotation rows are κ Σ_j w_jb r_jb × f_j = κ vee(Mᵀ − M), M = R_b O_bᵀ (r_jb = R_b Ỹ_jb)
// and the rotation curvature Σ_j w_jb C(f_j, r_jb) is C of the outer sum κ O_b R_bᵀ (C
// bilinear: ½(M + Mᵀ) − tr(M) I). The Hessian's Jᵀ K J blocks per pair (a, c), as mapHessian
// forms them from the nodes: s = κ S_ac, p = Σ s r_c = κ R_c U_ca, q = κ R_a U_ac and
// W = Σ s r_c r_aᵀ = κ R_c V_acᵀ R_aᵀ.
double NodalInertiaTerm::boneOnly(VecX* g, std::vector<Triplet>* H, int offset, bool psd) const {
  updateHeldReference();
  const double k = 1.0 / (h_ * h_);
  const int bones = kin_.numBones();
  const std::vector<Mat3>& R = kin_.R();
  const MatX3& t = kin_.t();
  Mat3 dR[kNumJoints];
  Vec3 dt[kNumJoints], F[kNumJoints];
  Mat3 O[kNumJoints];
  double E = held_.E0;
  for (int b = 0; b < bones; ++b) {
    dR[b] = R[size_t(b)] - held_.R0[size_t(b)];
    dt[b] = (t.row(b) - held_.t0.row(b)).transpose();
    F[b] = held_.P[size_t(b)];
    O[b] = held_.Q[size_t(b)].transpose();
    E += 2.0 * ((dR[b] * held_.Q[size_t(b)]).trace() + dt[b].dot(held_.P[size_t(b)]));
  }
  for (const HeldMassMoments::Pair& p : moments_.pairs()) {
    // The pair (b, c): Σ_j m w_b w_c d_jb · d_jc, and its share of bone c's F and O.
    const int b = p.b, c = p.c;
    const Vec3 dRU = dR[b] * p.Ub;  // Σ s ΔR_b Ỹ_jb
    E += (dR[b] * p.V * dR[c].transpose()).trace() + dt[c].dot(dRU) + dt[b].dot(dR[c] * p.Uc) +
         p.S * dt[b].dot(dt[c]);
    F[c] += dRU + p.S * dt[b];
    O[c].noalias() += dR[b] * p.V + dt[b] * p.Uc.transpose();
  }
  if (g)
    for (int b = 0; b < bones; ++b) {
      g->segment<3>(offset + 6 * b) += k * F[b];
      const Mat3 M = R[size_t(b)] * O[b].transpose();  // Σ_j w_jb r_jb f_jᵀ / κ
      g->segment<3>(offset + 6 * b + 3) += k * vee(M.transpose() - M);
    }
  if (H) {
    for (const HeldMassMoments::Pair& p : moments_.pairs()) {
      const int a = p.b, c = p.c;
      const Vec3 pc = k * (R[size_t(c)] * p.Uc), qa = k * (R[size_t(a)] * p.Ub);
      const Mat3 W = k * (R[size_t(c)] * p.V.transpose() * R[size_t(a)].transpose());
      Mat6 B = Mat6::Zero();
      B.topLeftCorner<3, 3>().diagonal().setConstant(k * p.S);
      B.topRightCorner<3, 3>() = -skew(pc);
      B.bottomLeftCorner<3, 3>() = skew(qa);
      B.bottomRightCorner<3, 3>() = W.trace() * Mat3::Identity() - W;
      if (a == c && !psd) {
        const Mat3 M = k * (O[a] * R[size_t(a)].transpose());
        B.bottomRightCorner<3, 3>() += 0.5 * (M + M.transpose()) - M.trace() * Mat3::Identity();
      }
      addBlock(*H, offset + 6 * a, offset + 6 * c, B);
    }
  }
  return 0.5 * k * E;
}

void NodalInertiaTerm::addHessianBlocks(const TermContext& c, std::vector<Triplet>& H,
                                        std::vector<FixedHessianBlocks>* blocks, int offset,
                                        bool psd) const {
  if (c.bone_block_only) {
    boneOnly(nullptr, &H, offset, psd);
    return;
  }
  collectFixedBlocks(blocks,
                     [&](FixedHessianBlocks* fixed) { evaluate(nullptr, &H, offset, psd, fixed); });
}

double NodalInertiaTerm::evaluate(VecX* g, std::vector<Triplet>* H, int offset, bool psd,
                                  FixedHessianBlocks* blocks) const {
  const double k = 1.0 / (h_ * h_);
  const std::vector<int>& nodes = masses_.nodes;
  const MatX3& x = kin_.x();
  const size_t count = nodes.size();
  double E = 0.0;
  forces_.resize(count);
  for (size_t idx = 0; idx < count; ++idx) {
    const int j = nodes[idx];
    const Vec3 d = (x.row(j) - x_hat_.row(j)).transpose();
    E += 0.5 * k * masses_.mass[j] * d.squaredNorm();
    forces_[idx] = k * masses_.mass[j] * d;
  }
  if (g) kin_.mapForces(nodes, forces_, *g, offset);
  if (H) {
    scalars_.resize(count);
    for (size_t idx = 0; idx < count; ++idx) scalars_[idx] = k * masses_.mass[nodes[idx]];
    // psd: Gauss–Newton Σ m JᵀJ; exact: plus the curvature of the rotating nodes.
    const bool fixed = blocks && !kin_.reduced();
    kin_.mapHessian(nodes, nullptr, psd ? nullptr : &forces_, *H, offset, psd, 0,
                    fixed ? &fixed_ : nullptr, &scalars_);
    if (fixed) *blocks = {&kin_.couplingPositions(), &fixed_, offset};
  }
  return E;
}

void NodalInertiaTerm::hessianPart(int part, std::vector<Triplet>& H, int offset, bool psd,
                                   bool approximate) const {
  const double k = 1.0 / (h_ * h_);
  const std::vector<int>& nodes = parts_[part];
  const MatX3& x = kin_.x();
  std::vector<double>& kappa = part_scalars_[part];
  std::vector<Vec3>& forces = part_forces_[part];
  kappa.resize(nodes.size());
  if (!psd) forces.resize(nodes.size());
  for (size_t idx = 0; idx < nodes.size(); ++idx) {
    const int j = nodes[idx];
    kappa[idx] = k * masses_.mass[j];
    if (!psd) forces[idx] = kappa[idx] * (x.row(j) - x_hat_.row(j)).transpose();
  }
  kin_.mapHessian(nodes, nullptr, psd ? nullptr : &forces, H, offset, psd, part, nullptr, &kappa,
                  !approximate);
}

const MatX& NodalInertiaTerm::constantSoftBlock() const {
  const std::vector<int>& nodes = masses_.nodes;
  bool current = constant_of_.size() == nodes.size();
  for (size_t idx = 0; current && idx < nodes.size(); ++idx)
    current = constant_of_[idx] == masses_.mass[nodes[idx]];
  if (current) return constant_soft_;
  const int m = kin_.numSoftDofs();
  const double k = 1.0 / (h_ * h_);
  constant_soft_.setZero(m, m);
  constant_of_.resize(nodes.size());
  std::vector<std::pair<int, Mat3>> basis;
  Eigen::Matrix<double, Eigen::Dynamic, 3> B_t(m, 3);  // B_jᵀ
  for (size_t idx = 0; idx < nodes.size(); ++idx) {
    const int j = nodes[idx];
    constant_of_[idx] = masses_.mass[j];
    kin_.displacementBasis(j, basis);
    if (basis.empty()) continue;
    B_t.setZero();
    for (const auto& [offset, block] : basis) B_t.middleRows<3>(offset) += block.transpose();
    constant_soft_.selfadjointView<Eigen::Upper>().rankUpdate(B_t, k * masses_.mass[j]);
  }
  constant_soft_.triangularView<Eigen::StrictlyLower>() = constant_soft_.transpose();
  return constant_soft_;
}

// g = Σ_j J_jᵀ f_j, f_j = κ_j (x_j − x̂_j), κ_j = m_j / h². The rest joint J_b moves x_j by
// −w_jb R_b, the prediction x̂_j = 2 x_j(q_n) − x_j(q_{n−1}) by −w_jb (2 R_b,n − R_b,n−1), and
// turns the lever arm of J_jᵀ's rotation rows (∂(r × f)/∂J_b = w [f]× R_b): per node and bone,
// a rotation-row block w [f]× R_b and a node block κ · (−w (R_b − 2 R_b,n + R_b,n−1)).
template <class Visit>
void NodalInertiaTerm::forEachMassNode(const VecX* lambda, Visit&& visit) const {
  const double k = 1.0 / (h_ * h_);
  const std::vector<int>& nodes = masses_.nodes;
  const MatX3& x = kin_.x();
  const std::vector<Vec3>* mu =
      lambda && kin_.massNodes() == nodes ? &kin_.massCotangents(*lambda) : nullptr;
  SkinnedPoint point;
  for (size_t idx = 0; idx < nodes.size(); ++idx) {
    const int j = nodes[idx];
    const double kappa = k * masses_.mass[j];
    kin_.point(j, point);
    point.id = int(idx);
    point.known_cotangent = mu ? &(*mu)[idx] : nullptr;
    visit(j, kappa, Vec3(kappa * (x.row(j) - x_hat_.row(j)).transpose()), point);
  }
}

// The masses (Material, in coefficient values; Shape): ∂g/∂m_j = J_jᵀ f_j / m_j, through each
// mass coefficient k as ∂m_j/∂c_k and through β as ∂m_j/∂β (the rest nodes' share of β goes
// through Y, nodeOffsetBlocks).
template <class Sink>
void NodalInertiaTerm::parameterBlocks(const TermContext& c, Sink& sink) const {
  const bool joints = sink.wants(SimParameter::RestJoints);
  const bool material = sink.wants(SimParameter::Material);
  const bool shape = sink.wants(SimParameter::Shape);
  if (c.is_static || (!joints && !material && !shape)) return;
  const MatX3* dm = material ? &chain_.massDerivatives() : nullptr;
  const MatX* dm_dbeta = shape ? &shape_.massJacobian() : nullptr;
  forEachMassNode(
      sink.lambda(), [&](int j, double kappa, const Vec3& f, const SkinnedPoint& point) {
        if (shape)
          sink.add(SimParameter::Shape, point, 0, Vec3(f / masses_.mass[j]), dm_dbeta->row(j));
        if (material)
          for (int k = 0; k < 3; ++k)
            if ((*dm)(j, k) != 0.0)
              sink.add(SimParameter::Material, point, chain_.massCoefficients()[size_t(k)],
                       Vec3(f / masses_.mass[j]), Eigen::Matrix<double, 1, 1>((*dm)(j, k)));
        if (!joints) return;
        const Mat3 turn = skew(f);
        for (int a = 0; a < point.count; ++a) {
          const int b = point.bone[a];
          const double w = point.weight[a];
          sink.add(SimParameter::RestJoints, rotationRow(b), 3 * b, w * turn * c.R[b]);
          sink.add(SimParameter::RestJoints, point, 3 * b, kappa * Mat3::Identity(),
                   -w * (c.R[b] - 2.0 * c.R_n[b] + c.R_nm1[b]));
        }
      });
}

// An offset d_j of Y_j (in q, q_n and q_{n−1} alike) moves x_j by M_j d_j and x̂_j by
// (2 M_j(R_n) − M_j(R_{n−1})) d_j, so the node block is κ_j (M_j − 2 M_j(R_n) + M_j(R_{n−1})),
// and turns the lever arms of J_jᵀ's rotation rows: −w_jb [f_j]× R_b.
template <class Sink>
void NodalInertiaTerm::nodeOffsetBlocks(const TermContext& c, Sink& sink) const {
  if (c.is_static) return;
  forEachMassNode(sink.lambda(), [&](int j, double kappa, const Vec3& f,
                                     const SkinnedPoint& point) {
    sink.add(point, j,
             kappa * (kin_.M(j) - 2.0 * kin_.blendMatrix(j, c.R_n) + kin_.blendMatrix(j, c.R_nm1)));
    const Mat3 turn = skew(f);
    for (int a = 0; a < point.count; ++a)
      sink.addRotation(point.bone[a], j, -point.weight[a] * turn * c.R[point.bone[a]]);
  });
}

// g = Σ_j J_jᵀ κ_j (x_j − x̂_j) with x̂_j = 2 x_j(q_n) − x_j(q_{n−1}): (∂g/∂q_n)ᵀ λ =
// −2 Σ_j κ_j J_j(q_n)ᵀ J_j λ and (∂g/∂q_{n−1})ᵀ λ = Σ_j κ_j J_j(q_{n−1})ᵀ J_j λ.
void NodalInertiaTerm::addPreviousStatesProducts(const TermContext& c, const VecX& lambda,
                                                 VecX* a_n, VecX* a_nm1) const {
  if (c.is_static) return;
  const double k = 1.0 / (h_ * h_);
  const std::vector<int>& nodes = masses_.nodes;
  const std::vector<Vec3>* mus = kin_.massNodes() == nodes ? &kin_.massCotangents(lambda) : nullptr;
  const auto addRange = [&](size_t begin, size_t end, VecX* out_n, VecX* out_nm1) {
    SkinnedPoint point, previous;
    for (size_t idx = begin; idx < end; ++idx) {
      const int j = nodes[idx];
      const double kappa = k * masses_.mass[j];
      Vec3 mu;  // J_j λ
      if (mus) {
        mu = (*mus)[idx];
      } else {
        kin_.point(j, point);
        mu = point.cotangent(lambda);
      }
      if (out_n) {
        kin_.pointAt(j, c.R_n, kin_.u_n, previous);
        previous.addForce(-2.0 * kappa * mu, *out_n);
      }
      if (out_nm1) {
        kin_.pointAt(j, c.R_nm1, kin_.u_nm1, previous);
        previous.addForce(kappa * mu, *out_nm1);
      }
    }
  };
  // From kSplitNodes nodes, half on each thread (pointAt evaluates each node's own pose blend row),
  // each into its own products, added in a fixed order.
  const size_t count = nodes.size();
  if (count < kSplitNodes) return addRange(0, count, a_n, a_nm1);
  VecX part_n[2], part_nm1[2];
  onTwoThreads([&](int p) {
    if (a_n) part_n[p] = VecX::Zero(a_n->size());
    if (a_nm1) part_nm1[p] = VecX::Zero(a_nm1->size());
    addRange(p == 0 ? 0 : count / 2, p == 0 ? count / 2 : count, a_n ? &part_n[p] : nullptr,
             a_nm1 ? &part_nm1[p] : nullptr);
  });
  if (a_n) *a_n += part_n[0] + part_n[1];
  if (a_nm1) *a_nm1 += part_nm1[0] + part_nm1[1];
}

void NodalInertiaTerm::addPreviousStatesTangent(const TermContext& c, const VecX& dq_n,
                                                const VecX& dq_nm1, VecX& out) const {
  if (c.is_static) return;
  const double k = 1.0 / (h_ * h_);
  SkinnedPoint point, previous;
  for (int j : masses_.nodes) {
    const double kappa = k * masses_.mass[j];
    kin_.pointAt(j, c.R_n, kin_.u_n, previous);
    Vec3 dx_hat = 2.0 * previous.cotangent(dq_n);  // J_j(q_n) dq_n
    kin_.pointAt(j, c.R_nm1, kin_.u_nm1, previous);
    dx_hat -= previous.cotangent(dq_nm1);
    kin_.point(j, point);
    point.addForce(-kappa * dx_hat, out);
  }
}

void NodalInertiaTerm::addPreviousStateJacobian(const TermContext& c, int which, MatX& D) const {
  const VecX zero = VecX::Zero(D.cols());
  addTangentColumns(D, [&](const VecX& unit, VecX& column) {
    addPreviousStatesTangent(c, which == 1 ? unit : zero, which == 2 ? unit : zero, column);
  });
}

}  // namespace flsh::detail

template class flsh::TermWithParameterBlocks<flsh::detail::NodalInertiaTerm>;
template class flsh::detail::WithNodeOffsetBlocks<flsh::detail::NodalInertiaTerm>;
