#include "sim/soft/nodal_gravity_term.h"

#include "flsh/body/smpl_skeleton.h"
#include "flsh/core/rotation.h"
#include "sim/soft/node_offset_blocks.h"
#include "sim/terms/term_blocks.h"

namespace flsh::detail {

NodalGravityTerm::NodalGravityTerm(const SoftKinematics& kinematics, const NodeMasses& masses,
                                   const HeldMassMoments& moments, const MaterialChain& chain,
                                   const ShapeChain& shape)
    : NodeTerm(kinematics), masses_(masses), moments_(moments), chain_(chain), shape_(shape) {
  bone_mass_.assign(size_t(kin_.numBones()), 0.0);
  for (int j : masses_.nodes)
    for (auto* inf = kin_.influencesBegin(j); inf != kin_.influencesEnd(j); ++inf)
      bone_mass_[size_t(inf->bone)] += masses_.mass[j] * inf->weight;
  if (!kin_.reduced()) {
    for (int j : masses_.nodes) {
      if (!kin_.isSoftNode(j)) continue;
      const int u = kin_.boneDofs() + kin_.nodeDof(j);
      for (auto* inf = kin_.influencesBegin(j); inf != kin_.influencesEnd(j); ++inf) {
        coupling_positions_.emplace_back(6 * inf->bone + 3, u);
        coupling_positions_.emplace_back(u, 6 * inf->bone + 3);
      }
    }
    return;
  }
  const int bones = kin_.numBones(), H = kin_.numHandles();
  std::vector<double> D(size_t(bones) * H, 0.0);
  for (int j : masses_.nodes)
    for (auto* inf = kin_.influencesBegin(j); inf != kin_.influencesEnd(j); ++inf)
      for (auto* phi = kin_.basisBegin(j); phi != kin_.basisEnd(j); ++phi)
        D[size_t(inf->bone) * H + phi->first] += masses_.mass[j] * inf->weight * phi->second;
  for (int b = 0; b < bones; ++b)
    for (int h = 0; h < H; ++h)
      if (D[size_t(b) * H + h] != 0.0)
        handle_blocks_.push_back({kin_.bzSlot(2 * b + 1, h), b, D[size_t(b) * H + h]});
  const int r = kin_.numModes();
  if (r == 0) return;
  MatX D_modes = MatX::Zero(3 * bones, r);  // rows 3b..3b+2: Σ_j m_j w_jb Ψ_j
  for (int j : masses_.nodes) {
    if (!kin_.isSoftNode(j)) continue;
    for (auto* inf = kin_.influencesBegin(j); inf != kin_.influencesEnd(j); ++inf)
      D_modes.middleRows<3>(3 * inf->bone) += (masses_.mass[j] * inf->weight) * kin_.modeRows(j);
  }
  for (int b = 0; b < bones; ++b)
    for (int g = 0; g < r / 3; ++g) {
      const Mat3 block = D_modes.block<3, 3>(3 * b, 3 * g);
      if (!block.isZero(0.0))
        mode_blocks_.push_back({kin_.bzSlot(2 * b + 1, kin_.numHandles() + g), b, block});
    }
}

void NodalGravityTerm::addHessianBlocks(const TermContext& c, std::vector<Triplet>& H,
                                        std::vector<FixedHessianBlocks>* blocks, int offset,
                                        bool psd) const {
  // Neither model needs the node forces' pass for the Hessian alone. The bones' block alone:
  // their rotation curvature.
  if (c.bone_block_only) {
    boneOnly(c.options.gravity, nullptr, &H, offset, psd);
    return;
  }
  if (kin_.reduced()) return reducedHessian(c.options.gravity, H, offset, psd);
  femHessian(c.options.gravity, H, blocks, offset, psd);
}

void NodalGravityTerm::femHessian(const Vec3& gravity, std::vector<Triplet>& H,
                                  std::vector<FixedHessianBlocks>* blocks, int offset,
                                  bool psd) const {
  boneCurvature(gravity, H, offset, psd);
  if (psd) {
    if (blocks) blocks->push_back({&no_positions_, &no_values_, offset});
    return;
  }
  const std::vector<Mat3>& R = kin_.R();
  Mat3 G[kNumJoints];  // [g]× R_b
  for (int b = 0; b < kin_.numBones(); ++b) G[b] = skew(gravity) * R[size_t(b)];
  fixed_.resize(coupling_positions_.size());
  size_t k = 0;
  for (int j : masses_.nodes) {
    if (!kin_.isSoftNode(j)) continue;
    for (auto* inf = kin_.influencesBegin(j); inf != kin_.influencesEnd(j); ++inf, k += 2) {
      fixed_[k] = (masses_.mass[j] * inf->weight) * G[inf->bone];
      fixed_[k + 1] = fixed_[k].transpose();
    }
  }
  if (blocks) {
    blocks->push_back({&coupling_positions_, &fixed_, offset});
    return;
  }
  for (size_t b = 0; b < coupling_positions_.size(); ++b)
    addBlock(H, offset + coupling_positions_[b].first, offset + coupling_positions_[b].second,
             fixed_[b]);
}

double NodalGravityTerm::evaluate(const Vec3& gravity, VecX* g, std::vector<Triplet>* H, int offset,
                                  bool psd, FixedHessianBlocks* blocks) const {
  const std::vector<int>& nodes = masses_.nodes;
  const MatX3& x = kin_.x();
  double E = 0.0;
  forces_.resize(nodes.size());
  for (size_t idx = 0; idx < nodes.size(); ++idx) {
    const int j = nodes[idx];
    E -= masses_.mass[j] * gravity.dot(x.row(j).transpose());
    forces_[idx] = -masses_.mass[j] * gravity;
  }
  if (g) kin_.mapForces(nodes, forces_, *g, offset);
  if (H && kin_.reduced()) {
    reducedHessian(gravity, *H, offset, psd);
  } else if (H) {
    std::vector<FixedHessianBlocks> lists;
    femHessian(gravity, *H, blocks ? &lists : nullptr, offset, psd);
    if (blocks) *blocks = lists.front();
  }
  return E;
}

double NodalGravityTerm::boneOnly(const Vec3& gravity, VecX* g, std::vector<Triplet>* H, int offset,
                                  bool psd) const {
  moments_.update();
  const std::vector<Mat3>& R = kin_.R();
  const MatX3& t = kin_.t();
  double E = 0.0;
  for (int b = 0; b < kin_.numBones(); ++b) {
    const double G = bone_mass_[size_t(b)];
    if (G == 0.0) continue;
    const Vec3 lever = R[size_t(b)] * moments_.boneLever(b);  // Σ_j m_j w_jb r_jb
    E -= gravity.dot(lever + G * t.row(b).transpose());
    if (g) {
      g->segment<3>(offset + 6 * b) -= G * gravity;
      g->segment<3>(offset + 6 * b + 3) -= lever.cross(gravity);
    }
    if (H) {
      const Mat3 C = rotationCurvature(-gravity, lever);
      addBlock(*H, offset + 6 * b + 3, offset + 6 * b + 3, psd ? projectToPSD<3>(C) : C);
    }
  }
  return E;
}

void NodalGravityTerm::reducedHessian(const Vec3& gravity, std::vector<Triplet>& H, int offset,
                                      bool psd) const {
  // The rotation–handle blocks Σ_j −w_jb φ_jh [f_j]× R_b = D_bh [g]× R_b (D_bh constant).
  boneCurvature(gravity, H, offset, psd);
  if (psd) return;
  const std::vector<Mat3>& R = kin_.R();
  Mat3* values = kin_.reducedValues(1);
  const Mat3 G = skew(gravity);
  for (const HandleBlock& hb : handle_blocks_) values[hb.slot] += hb.weight * (G * R[hb.bone]);
  for (const ModeBlock& mb : mode_blocks_) values[mb.slot] += (G * R[mb.bone]) * mb.D;
}

void NodalGravityTerm::boneCurvature(const Vec3& gravity, std::vector<Triplet>& H, int offset,
                                     bool psd) const {
  // The node forces f_j = −m_j g are constant, so mapHessian's per-node sums collapse to per-bone
  // ones: the rotation curvature Σ_j w_jb C(f_j, R_b (Y_j − J_b)) = C(−g, R_b v_b) with v_b =
  // Σ_j m_j w_jb (Y_j − J_b) (C is bilinear).
  const std::vector<Mat3>& R = kin_.R();
  const MatX3& Y = kin_.Y();
  const int bones = kin_.numBones();
  Vec3 v[kNumJoints];
  double mass[kNumJoints];
  for (int b = 0; b < bones; ++b) {
    v[b].setZero();
    mass[b] = 0.0;
  }
  for (int j : masses_.nodes) {
    const Vec3 Yj = Y.row(j).transpose();
    for (auto* inf = kin_.influencesBegin(j); inf != kin_.influencesEnd(j); ++inf) {
      const double mw = masses_.mass[j] * inf->weight;
      v[inf->bone] += mw * Yj;
      mass[inf->bone] += mw;
    }
  }
  for (int b = 0; b < bones; ++b) {
    if (mass[b] == 0.0) continue;
    const Vec3 lever = R[b] * (v[b] - mass[b] * kin_.joints().row(b).transpose());
    const Mat3 C = rotationCurvature(-gravity, lever);
    addBlock(H, offset + 6 * b + 3, offset + 6 * b + 3, psd ? projectToPSD<3>(C) : C);
  }
}

// g = Σ_j J_jᵀ f_j with the constant f_j = −m_j g: the rest joint J_b turns only the lever
// arms of bone b's rotation rows, Σ_j w_jb [f_j]× R_b = [−g]× R_b Σ_j m_j w_jb.
// The masses (Material, in coefficient values; Shape): ∂g/∂m_j = J_jᵀ (−g), through each mass
// coefficient k as ∂m_j/∂c_k and through β as ∂m_j/∂β.
template <class Sink>
void NodalGravityTerm::parameterBlocks(const TermContext& c, Sink& sink) const {
  const bool shape = sink.wants(SimParameter::Shape);
  const bool material = sink.wants(SimParameter::Material);
  if (shape || material) {
    const MatX* dm_dbeta = shape ? &shape_.massJacobian() : nullptr;
    const MatX3* dm = material ? &chain_.massDerivatives() : nullptr;
    const std::vector<Vec3>* mu = sink.lambda() && kin_.massNodes() == masses_.nodes
                                      ? &kin_.massCotangents(*sink.lambda())
                                      : nullptr;
    SkinnedPoint point;
    const Vec3 force = -c.options.gravity;
    for (size_t idx = 0; idx < masses_.nodes.size(); ++idx) {
      const int j = masses_.nodes[idx];
      kin_.point(j, point);
      point.id = int(idx);
      point.known_cotangent = mu ? &(*mu)[idx] : nullptr;
      if (shape) sink.add(SimParameter::Shape, point, 0, force, dm_dbeta->row(j));
      for (int k = 0; material && k < 3; ++k)
        if ((*dm)(j, k) != 0.0)
          sink.add(SimParameter::Material, point, chain_.massCoefficients()[size_t(k)], force,
                   Eigen::Matrix<double, 1, 1>((*dm)(j, k)));
    }
  }
  if (!sink.wants(SimParameter::RestJoints)) return;
  const Mat3 turn = skew(Vec3(-c.options.gravity));
  for (int b = 0; b < kin_.numBones(); ++b)
    if (bone_mass_[size_t(b)] != 0.0)
      sink.add(SimParameter::RestJoints, rotationRow(b), 3 * b,
               bone_mass_[size_t(b)] * turn * c.R[b]);
}

// The constant forces f_j = −m_j g do not move with Y_j; the lever arms do: −w_jb [f_j]× R_b
// per influence (the rest joints' blocks with the opposite sign, node by node).
template <class Sink>
void NodalGravityTerm::nodeOffsetBlocks(const TermContext& c, Sink& sink) const {
  const Mat3 turn = skew(Vec3(c.options.gravity));  // −[f_j]× / m_j
  for (int j : masses_.nodes)
    for (auto* inf = kin_.influencesBegin(j); inf != kin_.influencesEnd(j); ++inf)
      sink.addRotation(inf->bone, j, (masses_.mass[j] * inf->weight) * turn * c.R[inf->bone]);
}

}  // namespace flsh::detail

template class flsh::TermWithParameterBlocks<flsh::detail::NodalGravityTerm>;
template class flsh::detail::WithNodeOffsetBlocks<flsh::detail::NodalGravityTerm>;
