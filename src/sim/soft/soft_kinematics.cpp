// The soft skeletons' kinematics: skinning of the tet nodes, the soft state's layout (FEM nodes
// or ROM basis) and the chain rule to the state; see soft_kinematics.h for the formulas. The
// ROM's Hessian value lists (their pattern, soft–soft blocks, zeroing, mirroring and hand-over)
// are in soft_kinematics_value_lists.cpp.
#include "sim/soft/soft_kinematics.h"

#include <algorithm>
#include <string>

#include "flsh/body/smpl_skeleton.h"
#include "flsh/core/error.h"
#include "flsh/core/rotation.h"
#include "flsh/volume/reduced_data.h"
#include "flsh/volume/volumetric_data.h"
#include "sim/soft/on_two_threads.h"
#include "sim/terms/term_blocks.h"

namespace flsh::detail {

namespace {

// Interior nodes get their skinning weights by harmonic extension, which leaves every weight
// slightly positive almost everywhere; like SMPL's own weights they are cut to a few
// influences (weights below kMinInteriorWeight dropped, at most kMaxInteriorInfluences kept,
// renormalized), so a node couples to ≤ 4 bones. Surface nodes keep SMPL's weights exactly: at
// u = 0 the simulated surface is the SMPL mesh.
constexpr double kMinInteriorWeight = 0.01;
constexpr int kMaxInteriorInfluences = 4;

}  // namespace

SoftKinematics::SoftKinematics(const SoftAvatar& avatar, const MatX3& joints,
                               const std::vector<int>& parents)
    : num_bones_(int(joints.rows())),
      bone_dofs_(6 * int(joints.rows())),
      parents_(parents),
      joints_(joints) {
  const VolumetricData& data = avatar.volumetricData();
  const VolumetricTemplate& templ = *data.templ;
  const int n = data.numNodes();
  rest_ = data.rest_nodes;
  num_surface_ = templ.mesh.num_surface_nodes;
  posedirs_ = &templ.fields.posedirs;
  if (posedirs_->rows() != 3 * n || posedirs_->cols() != 9 * (num_bones_ - 1))
    throw InputError("Simulable: the avatar's volumetric pose blend shapes are " +
                     std::to_string(posedirs_->rows()) + " × " + std::to_string(posedirs_->cols()) +
                     ", expected " + std::to_string(3 * n) + " × " +
                     std::to_string(9 * (num_bones_ - 1)));
  blend_ = MatX3::Zero(n, 3);
  // ROM: every node's offsets from posedirs until setMassNodes gives some a contiguous slot.
  blend_stamp_.assign(n, 0);
  blend_slot_.assign(n, -1);

  // Soft-tissue nodes and their DoF offsets.
  node_dof_.assign(n, -1);
  std::vector<int> soft;
  for (int j = 0; j < n; ++j)
    if (data.bone_of_node[j] < 0) {
      node_dof_[j] = 3 * int(soft.size());
      soft.push_back(j);
    }
  reduced_ = avatar.reducedModelEnabled();
  if (!reduced_) {
    state_nodes_ = Eigen::Map<const VecXi>(soft.data(), Eigen::Index(soft.size()));
  } else {
    const ReducedData& rom = avatar.reducedData();
    num_handles_ = rom.numHandles();
    if (rom.basis.rows() != n || rom.basis.cols() != num_handles_)
      throw InputError("Simulable: the avatar's reduced basis is " +
                       std::to_string(rom.basis.rows()) + " × " + std::to_string(rom.basis.cols()) +
                       ", expected #nodes × #handles = " + std::to_string(n) + " × " +
                       std::to_string(num_handles_));
    num_modes_ = rom.numModes();
    if (num_modes_ > 0) {
      if (rom.modes.rows() != 3 * n || num_modes_ % 3 != 0)
        throw InputError("Simulable: the avatar's modes are " + std::to_string(rom.modes.rows()) +
                         " × " + std::to_string(num_modes_) + ", expected 3·#nodes (" +
                         std::to_string(3 * n) + ") × a multiple of 3");
      modes_ = rom.modes;
    }
    num_groups_ = num_handles_ + num_modes_ / 3;
    state_nodes_ = rom.handles;
    state_dof_.assign(n, -1);
    for (int h = 0; h < num_handles_; ++h) state_dof_[rom.handles[h]] = 3 * h;
    // Rows of φ (the basis is stored by columns); bone nodes never move (u = 0).
    const SpMat rows = rom.basis.transpose();
    phi_start_.assign(n + 1, 0);
    for (int j = 0; j < n; ++j) {
      if (node_dof_[j] >= 0)
        for (SpMat::InnerIterator it(rows, j); it; ++it)
          phi_.emplace_back(int(it.row()), it.value());
      phi_start_[j + 1] = int(phi_.size());
    }
  }
  u = u_n = u_nm1 = VecX::Zero(numSoftDofs());

  // Skinning influences.
  const MatX& surface_weights = avatar.body().weights;
  const MatX& node_weights = templ.fields.weights;
  influence_start_.assign(n + 1, 0);
  std::vector<std::pair<double, int>> ranked;
  for (int j = 0; j < n; ++j) {
    if (j < num_surface_) {
      for (int b = 0; b < num_bones_; ++b)
        if (surface_weights(j, b) != 0.0) influences_.push_back({b, surface_weights(j, b)});
    } else {
      ranked.clear();
      for (int b = 0; b < num_bones_; ++b)
        if (node_weights(j, b) >= kMinInteriorWeight) ranked.emplace_back(node_weights(j, b), b);
      if (ranked.empty()) {  // no weight reaches the threshold: keep the largest one
        int best = 0;
        node_weights.row(j).maxCoeff(&best);
        ranked.emplace_back(1.0, best);
      }
      std::sort(ranked.begin(), ranked.end(), [](const auto& a, const auto& b) {
        return a.first > b.first || (a.first == b.first && a.second < b.second);
      });
      if (int(ranked.size()) > kMaxInteriorInfluences) ranked.resize(kMaxInteriorInfluences);
      double sum = 0.0;
      for (const auto& r : ranked) sum += r.first;
      for (const auto& r : ranked) influences_.push_back({r.second, r.first / sum});
    }
    influence_start_[j + 1] = int(influences_.size());
  }

  for (BonePairBlocks& blocks : pair_blocks_) blocks.resize(num_bones_);
  for (auto& moments : pair_moments_)
    moments.resize(size_t(num_bones_) * num_bones_, PairMoments{});
  pair_moments_second_.resize(size_t(num_bones_) * num_bones_, PairMoments{});
  all_nodes_.resize(n);
  for (int j = 0; j < n; ++j) all_nodes_[j] = j;
  surface_nodes_.assign(all_nodes_.begin(), all_nodes_.begin() + num_surface_);

  // Pose blend and the broad-phase bounds.
  feature_ = VecX::Zero(posedirs_->cols());
  blend_bound_.resize(num_surface_);
  for (int i = 0; i < num_surface_; ++i) blend_bound_[i] = posedirs_->middleRows(3 * i, 3).norm();
  if (reduced_) {
    phi_sum_ = VecX::Zero(num_surface_);
    for (int i = 0; i < num_surface_; ++i)
      for (int k = phi_start_[i]; k < phi_start_[i + 1]; ++k) phi_sum_[i] += phi_[k].second;
    mode_norm_ = VecX::Zero(num_surface_);
    for (int i = 0; i < num_surface_ && num_modes_ > 0; ++i)
      if (node_dof_[i] >= 0) mode_norm_[i] = modeRows(i).norm();
  }
}

void SoftKinematics::setMassNodes(const std::vector<int>& mass_nodes) {
  const int n = numNodes();
  mass_nodes_ = mass_nodes;
  mass_mu_skinning_ = -1;
  if (!reduced_) {
    // prepare() skins every node; the fixed coupling positions of inertia's and gravity's
    // Hessians.
    eval_nodes_ = all_nodes_;
    coupling_start_.assign(mass_nodes.size() + 1, 0);
    coupling_dofs_.clear();
    for (size_t idx = 0; idx < mass_nodes.size(); ++idx) {
      const int j = mass_nodes[idx];
      coupling_start_[idx + 1] = coupling_start_[idx];
      if (node_dof_[j] < 0) continue;
      const int u = bone_dofs_ + node_dof_[j];
      for (int k = influence_start_[j]; k < influence_start_[j + 1]; ++k) {
        const int b = 6 * influences_[k].bone;
        coupling_dofs_.insert(coupling_dofs_.end(), {{b, u}, {b + 3, u}, {u, b}, {u, b + 3}});
      }
      coupling_dofs_.emplace_back(u, u);
      coupling_start_[idx + 1] = int(coupling_dofs_.size());
    }
    return;
  }
  // ROM: prepare() skins the mass nodes (the elastic energy reads u only; contact and output
  // skin the surface nodes they need); the surface and mass nodes keep their posedirs rows
  // contiguous for blendOf.
  eval_nodes_ = mass_nodes;
  blend_stamp_.assign(n, 0);  // pose_stamp_ 0: the zero feature, whose offsets are zero
  held_R_.assign(size_t(num_bones_), Mat3::Identity());  // the rest pose's: the zero feature
  std::vector<int> blend_slot(n, -1);
  int slots = 0;
  for (int j = 0; j < num_surface_; ++j) blend_slot[j] = slots++;
  for (int j : mass_nodes)
    if (blend_slot[j] < 0) blend_slot[j] = slots++;
  blend_slot_ = std::move(blend_slot);
  posedirs_T_.resize(posedirs_->cols(), 3 * slots);
  for (int j = 0; j < n; ++j)
    if (blend_slot_[j] >= 0)
      posedirs_T_.middleCols(3 * blend_slot_[j], 3) = posedirs_->middleRows(3 * j, 3).transpose();
}

// ---- broad-phase bounds and positions (the pose blend: soft_kinematics_pose_blend.cpp) --

double SoftKinematics::displacementWeight(int i) const {
  if (!reduced_) return node_dof_[i] >= 0 ? 1.0 : 0.0;
  return phi_sum_[i];
}

double SoftKinematics::modeNorm(int i) const {
  return reduced_ && num_modes_ > 0 ? mode_norm_[i] : 0.0;
}

double SoftKinematics::largestSoftState() const {
  double largest = 0.0;
  const Eigen::Index end = reduced_ ? 3 * num_handles_ : u.size();
  for (Eigen::Index k = 0; k + 2 < end; k += 3) largest = std::max(largest, u.segment<3>(k).norm());
  return largest;
}

void SoftKinematics::setContactBones(const std::vector<std::vector<int>>& dominated) {
  bone_blend_bound_.assign(size_t(num_bones_), 0.0);
  bone_weight_bound_.assign(size_t(num_bones_), 0.0);
  bone_mode_bound_.assign(size_t(num_bones_), 0.0);
  for (int b = 0; b < num_bones_ && b < int(dominated.size()); ++b)
    for (int i : dominated[size_t(b)]) {
      bone_blend_bound_[size_t(b)] = std::max(bone_blend_bound_[size_t(b)], blendBound(i));
      bone_weight_bound_[size_t(b)] =
          std::max(bone_weight_bound_[size_t(b)], displacementWeight(i));
      bone_mode_bound_[size_t(b)] = std::max(bone_mode_bound_[size_t(b)], modeNorm(i));
    }
}

void SoftKinematics::contactMargins(double* margin) const {
  const double feature = poseFeatureNorm(), largest = largestSoftState();
  const double modes = num_modes_ > 0 ? u.tail(num_modes_).norm() : 0.0;
  for (int b = 0; b < num_bones_; ++b)
    margin[b] = bone_blend_bound_[size_t(b)] * feature + bone_weight_bound_[size_t(b)] * largest +
                bone_mode_bound_[size_t(b)] * modes;
}

void SoftKinematics::pruneCandidates(const std::function<double(const Vec3&)>& distance,
                                     std::vector<int>& candidates) const {
  if (!reduced_ || num_modes_ == 0) return;
  const double modes = u.tail(num_modes_).norm(), feature = poseFeatureNorm();
  const std::vector<Mat3>& R = *cur_R_;
  Vec3 shift[kNumJoints];
  boneShifts(R, *cur_t_, shift);
  size_t kept = 0;
  for (const int j : candidates) {
    double weights = 0.0;  // ‖M_j‖₂ ≤ Σ |w|
    for (int k = influence_start_[j]; k < influence_start_[j + 1]; ++k)
      weights += std::abs(influences_[k].weight);
    // First without the pose blend (‖P_j‖ ≤ blendBound(j) ‖feature‖), whose first evaluation in
    // a step reads 3 × 207 values; then with it.
    const Vec3 Y = rest_.row(j).transpose() + handleDisplacement(u, j);
    const double modal = mode_norm_[j] * modes;
    if (distance(skin(j, R, shift, Y)) >= weights * (modal + blend_bound_[j] * feature)) continue;
    if (distance(skin(j, R, shift, Y + blendOf(j))) < weights * modal) candidates[kept++] = j;
  }
  candidates.resize(kept);
}

Vec3 SoftKinematics::skin(int j, const std::vector<Mat3>& R, const Vec3* shift, const Vec3& Y,
                          Mat3* M) const {
  Vec3 x = Vec3::Zero();
  if (M) M->setZero();
  for (int k = influence_start_[j]; k < influence_start_[j + 1]; ++k) {
    const Influence& inf = influences_[k];
    x += inf.weight * (R[inf.bone] * Y + shift[inf.bone]);
    if (M) *M += inf.weight * R[inf.bone];
  }
  return x;
}

void SoftKinematics::boneShifts(const std::vector<Mat3>& R, const MatX3& t, Vec3* shift) const {
  for (int b = 0; b < num_bones_; ++b)
    shift[b] = t.row(b).transpose() - R[b] * joints_.row(b).transpose();
}

void SoftKinematics::positionsOf(const std::vector<int>& nodes, const BoneFrames& bones,
                                 const VecX& state, MatX3& x) const {
  Vec3 shift[kNumJoints];
  boneShifts(bones.R, bones.t, shift);
  if (x.rows() != numNodes()) x.resize(numNodes(), 3);
  // Distinct nodes: each writes its own row (and blendOf its own row and stamp).
  const long count = long(nodes.size());
#pragma omp parallel for schedule(static) if (count >= 512)
  for (long idx = 0; idx < count; ++idx) {
    const int j = nodes[size_t(idx)];
    const Vec3 Y = rest_.row(j).transpose() + blendOf(j) + nodeDisplacement(state, j);
    x.row(j) = skin(j, bones.R, shift, Y).transpose();
  }
}

void SoftKinematics::positions(const BoneFrames& bones, const VecX& displacement, MatX3& x) const {
  positionsOf(all_nodes_, bones, displacement, x);
}

void SoftKinematics::prepare(long version, const BoneFrames& bones) const {
  cur_R_ = &bones.R;
  cur_t_ = &bones.t;
  pending_version_ = version;
  if (version == version_) return;
  version_ = version;
  skinNodes(eval_nodes_);
}

void SoftKinematics::prepareFrames(long version, const BoneFrames& bones) const {
  if (!reduced_) return prepare(version, bones);
  cur_R_ = &bones.R;
  cur_t_ = &bones.t;
  pending_version_ = version;
}

void SoftKinematics::ensurePrepared() const {
  if (pending_version_ == version_) return;
  version_ = pending_version_;
  skinNodes(eval_nodes_);
}

void SoftKinematics::refreshUnposed() const {
  if (y_epoch_ != blend_epoch_ || y_state_.size() != u.size() || y_state_ != u) {
    ++y_current_;
    y_epoch_ = blend_epoch_;
    y_state_ = u;
  }
}

void SoftKinematics::skinNodes(const std::vector<int>& nodes) const {
  const int n = numNodes();
  if (Y_.rows() != n) {
    Y_.setZero(n, 3);
    y_stamp_.assign(size_t(n), 0);  // y_current_ is ≥ 1 from the first skinning on
  }
  if (x_.rows() != n) x_.setZero(n, 3);
  node_M_.resize(n);
  ++skinnings_;
  // Y_j = X̄_j + P_j + u_j reads neither the bones nor the joints: its rows stay current while
  // the soft state and the held pose blend do (the bones' presolve, a line search along the
  // bones, the first evaluation after the presolve).
  refreshUnposed();
  const std::vector<Mat3>& R = *cur_R_;
  const MatX3& t = *cur_t_;
  Vec3 shift[kNumJoints];
  boneShifts(R, t, shift);
  // Nodes are distinct: each writes its own rows and stamp (and blendOf its own row and stamp).
  const long count = long(nodes.size());
#pragma omp parallel for schedule(static) if (count >= 512)
  for (long idx = 0; idx < count; ++idx) {
    const int j = nodes[size_t(idx)];
    if (y_stamp_[size_t(j)] != y_current_) {
      Y_.row(j) = (rest_.row(j).transpose() + blendOf(j) + nodeDisplacement(u, j)).transpose();
      y_stamp_[size_t(j)] = y_current_;
    }
    x_.row(j) = skin(j, R, shift, Y_.row(j).transpose(), &node_M_[j]).transpose();
  }
}

void SoftKinematics::surface(MatX3* x, MatX3* Y) const {
  if (reduced_) skinNodes(surface_nodes_);
  if (x) *x = x_.topRows(num_surface_);
  if (Y) *Y = Y_.topRows(num_surface_);
}

// ---- the chain rule to the soft state -----------------------------------------------------------

void SoftKinematics::tetHandles(const Eigen::Vector4i& nodes, std::vector<int>& handles) const {
  handles.clear();
  for (int a = 0; a < 4; ++a)
    for (auto* phi = basisBegin(nodes[a]); phi != basisEnd(nodes[a]); ++phi)
      handles.push_back(phi->first);
  std::sort(handles.begin(), handles.end());
  handles.erase(std::unique(handles.begin(), handles.end()), handles.end());
}

void SoftKinematics::displacementBasis(int j, std::vector<std::pair<int, Mat3>>& out) const {
  out.clear();
  if (!reduced_) {
    if (node_dof_[j] >= 0) out.emplace_back(node_dof_[j], Mat3::Identity());
    return;
  }
  for (int k = phi_start_[j]; k < phi_start_[j + 1]; ++k)
    out.emplace_back(3 * phi_[k].first, phi_[k].second * Mat3::Identity());
  if (num_modes_ > 0 && node_dof_[j] >= 0)
    for (int g = 0; g < num_modes_ / 3; ++g)
      out.emplace_back(3 * num_handles_ + 3 * g, modeRows(j).middleCols<3>(3 * g));
}

void SoftKinematics::addSoftGradient(VecX& g, int offset, int j, const Vec3& v) const {
  const int base = offset + bone_dofs_;
  if (!reduced_) {
    if (node_dof_[j] >= 0) g.segment<3>(base + node_dof_[j]) += v;
    return;
  }
  for (int k = phi_start_[j]; k < phi_start_[j + 1]; ++k)
    g.segment<3>(base + 3 * phi_[k].first) += phi_[k].second * v;
  if (num_modes_ > 0 && node_dof_[j] >= 0) {
    // Ψ_jᵀ v as three axpys of Ψ_j's contiguous rows.
    const double* row = modes_.data() + size_t(3) * size_t(num_modes_) * size_t(j);
    Eigen::Map<VecX> out(g.data() + base + 3 * num_handles_, num_modes_);
    for (int c = 0; c < 3; ++c)
      out += v[c] * Eigen::Map<const VecX>(row + c * num_modes_, num_modes_);
  }
}

template <int Rows>
void SoftKinematics::addBoneSoft(std::vector<Triplet>& H, int offset, int row, int j,
                                 const Eigen::Matrix<double, Rows, 3>& B, int list) const {
  if (!reduced_) {
    if (node_dof_[j] < 0) return;
    const int u_index = offset + bone_dofs_ + node_dof_[j];
    addBlock(H, offset + row, u_index, B);
    addBlock(H, u_index, offset + row, B.transpose());
    return;
  }
  Mat3* values = reduced_values_[size_t(list)].data();
  const size_t groups = size_t(num_groups_);
  for (int k = phi_start_[j]; k < phi_start_[j + 1]; ++k)
    for (int r = 0; r < Rows; r += 3)
      values[bz_slot_[size_t((row + r) / 3) * groups + size_t(phi_[k].first)]] +=
          phi_[k].second * B.template middleRows<3>(r);
  if (num_modes_ == 0 || node_dof_[j] < 0) return;
  // B Ψ_j into the bone's dense rows (rows of r contiguous values; mirrorReduced folds them into
  // the bone–z slots).
  bone_modes_[size_t(list)].middleRows<Rows>(row).noalias() += B * modeRows(j);
  bone_modes_touched_[size_t(list)][size_t(row / 6)] = 1;
}

// ---- mapping node derivatives to the state ----------------------------------------------------

void SoftKinematics::point(int j, SkinnedPoint& p) const {
  fillPoint(j, *cur_R_, Y_.row(j).transpose(), node_M_[j], p);
}

const std::vector<Vec3>& SoftKinematics::massCotangents(const VecX& lambda) const {
  if (mass_mu_skinning_ == skinnings_ && mass_mu_lambda_.size() == lambda.size() &&
      mass_mu_lambda_ == lambda)
    return mass_mu_;
  mass_mu_.resize(mass_nodes_.size());
  const long count = long(mass_nodes_.size());
#pragma omp parallel if (count >= 512)
  {
    SkinnedPoint p;
#pragma omp for schedule(static)
    for (long idx = 0; idx < count; ++idx) {
      point(mass_nodes_[size_t(idx)], p);
      mass_mu_[size_t(idx)] = p.cotangent(lambda);
    }
  }
  mass_mu_lambda_ = lambda;
  mass_mu_skinning_ = skinnings_;
  return mass_mu_;
}

void SoftKinematics::pointAt(int j, const std::vector<Mat3>& R, const VecX& state,
                             SkinnedPoint& p) const {
  const Vec3 Y = rest_.row(j).transpose() + blendOf(j) + nodeDisplacement(state, j);
  fillPoint(j, R, Y, blendMatrix(j, R), p);
}

void SoftKinematics::fillPoint(int j, const std::vector<Mat3>& R, const Vec3& Y, const Mat3& M,
                               SkinnedPoint& p, bool soft_blocks) const {
  p.count = influence_start_[j + 1] - influence_start_[j];
  for (int a = 0; a < p.count; ++a) {
    const Influence& inf = influences_[influence_start_[j] + a];
    p.bone[a] = inf.bone;
    p.weight[a] = inf.weight;
    p.lever[a] = R[inf.bone] * (Y - joints_.row(inf.bone).transpose());
  }
  p.soft.clear();
  p.modes = nullptr;
  if (node_dof_[j] < 0 || !soft_blocks) return;
  if (!reduced_) {
    p.soft.emplace_back(bone_dofs_ + node_dof_[j], M);
    return;
  }
  for (int k = phi_start_[j]; k < phi_start_[j + 1]; ++k)
    p.soft.emplace_back(bone_dofs_ + 3 * phi_[k].first, phi_[k].second * M);
  if (num_modes_ == 0) return;
  p.modes = modes_.data() + size_t(3) * size_t(num_modes_) * size_t(j);
  p.num_modes = num_modes_;
  p.modal_dof = bone_dofs_ + 3 * num_handles_;
  p.blend = M;
}

void SoftKinematics::mapForces(const std::vector<int>& nodes, const std::vector<Vec3>& forces,
                               VecX& g, int offset) const {
  const std::vector<Mat3>& R = *cur_R_;
  for (size_t idx = 0; idx < nodes.size(); ++idx) {
    const Vec3& f = forces[idx];
    if (f.isZero(0.0)) continue;
    const int j = nodes[idx];
    const Vec3 Y = Y_.row(j).transpose();
    for (int k = influence_start_[j]; k < influence_start_[j + 1]; ++k) {
      const int b = influences_[k].bone;
      const double w = influences_[k].weight;
      const Vec3 r = R[b] * (Y - joints_.row(b).transpose());
      g.segment<3>(offset + 6 * b) += w * f;
      g.segment<3>(offset + 6 * b + 3) += w * r.cross(f);
    }
    if (node_dof_[j] >= 0) addSoftGradient(g, offset, j, node_M_[j].transpose() * f);
  }
}

void SoftKinematics::surfaceForces(const MatX3& forces, VecX& g) const {
  std::vector<Vec3> f(static_cast<size_t>(num_surface_));
  for (int i = 0; i < num_surface_; ++i) f[size_t(i)] = forces.row(i).transpose();
  mapForces(surface_nodes_, f, g, 0);
}

void SoftKinematics::mapHessian(const std::vector<int>& nodes, const std::vector<Mat3>* K,
                                const std::vector<Vec3>* forces, std::vector<Triplet>& H,
                                int offset, bool psd, int list, std::vector<Mat3>* fixed,
                                const std::vector<double>* K_scalar, bool soft_soft) const {
  if (fixed) fixed->assign(coupling_dofs_.size(), Mat3::Zero());
  const std::vector<Mat3>& R = *cur_R_;
  BonePairBlocks& pair_blocks = pair_blocks_[size_t(list)];
  auto block = [&](int b, int c) -> Mat6& { return pair_blocks.block(b, c); };
  // K_j = κ_j I: J_aᵀ J_c = w_a w_c [I, −[r_c]×; [r_a]×, (r_a·r_c) I − r_c r_aᵀ] is summed over
  // the nodes as moments per bone pair (κ w w, its r_c- and r_a-weighted sums and Σ κ w w r_c
  // r_aᵀ), 16 products per pair and node instead of a 6 × 3 × 6 product; blocks at the end.
  // Per-bone sums of the rotation curvature against the forces.
  struct Sums {
    explicit Sums(TouchedValues<PairMoments>& m) : moments(&m) {
      for (Mat3& c : curvature) c.setZero();
    }
    TouchedValues<PairMoments>* moments;
    Mat3 curvature[kNumJoints];
    bool has_curvature[kNumJoints] = {};
  };
  // The nodes [begin, end) into `sums`; the blocks of a node go to its own fixed slots, or
  // (without `fixed`) into H, the pair blocks or the value lists.
  const auto mapNodes = [&](size_t begin, size_t end, Sums& sums) {
    TouchedValues<PairMoments>& moments = *sums.moments;
    Eigen::Matrix<double, 3, 6> Jb[kNumJoints];
    Vec3 lever[kNumJoints];
    int bones[kNumJoints];
    for (size_t idx = begin; idx < end; ++idx) {
      const int j = nodes[idx];
      const int dof = node_dof_[j];
      const Vec3 Y = Y_.row(j).transpose();
      const int count = influence_start_[j + 1] - influence_start_[j];
      for (int a = 0; a < count; ++a) {
        const Influence& inf = influences_[influence_start_[j] + a];
        bones[a] = inf.bone;
        lever[a] = R[inf.bone] * (Y - joints_.row(inf.bone).transpose());
        Jb[a].leftCols<3>() = inf.weight * Mat3::Identity();
        Jb[a].rightCols<3>() = -inf.weight * skew(lever[a]);
      }
      // Bone–soft coupling per influence, one 6 × 3 block: Jbᵀ K M from K and, in the exact
      // form, ∂²(f·x)/∂δω_b∂δu_j = −w [f]× R_b from the force (rows 3..5).
      const bool force = forces && !(*forces)[idx].isZero(0.0);
      const bool k_coupling = (K || K_scalar) && dof >= 0;
      const bool f_coupling = force && !psd && dof >= 0;
      Eigen::Matrix<double, 6, 3> coupling[kNumJoints];
      for (int a = 0; a < count && (k_coupling || f_coupling); ++a) coupling[a].setZero();
      if (K_scalar) {
        const double kappa = (*K_scalar)[idx];
        for (int a = 0; a < count; ++a) {
          const double ka = kappa * influences_[influence_start_[j] + a].weight;
          for (int c = 0; c < count; ++c) {
            const double s = ka * influences_[influence_start_[j] + c].weight;
            PairMoments& m = moments.at(bones[a] * num_bones_ + bones[c]);
            m.s += s;
            m.p += s * lever[c];
            m.q += s * lever[a];
            m.W.noalias() += (s * lever[c]) * lever[a].transpose();
          }
        }
        if (dof >= 0) {
          const Mat3& M = node_M_[j];
          for (int a = 0; a < count; ++a) {
            const double ka = kappa * influences_[influence_start_[j] + a].weight;
            coupling[a].topRows<3>() += ka * M;
            coupling[a].bottomRows<3>().noalias() += ka * (skew(lever[a]) * M);
          }
          if (soft_soft) {
            const Mat3 MtKM = kappa * (M.transpose() * M);
            if (fixed)
              (*fixed)[size_t(coupling_start_[idx + 1]) - 1] = MtKM;
            else
              addSoftSoft(H, offset, j, MtKM, list);
          }
        }
      } else if (K) {
        const Mat3& Kj = (*K)[idx];
        for (int a = 0; a < count; ++a) {
          const Eigen::Matrix<double, 6, 3> JaT_K = Jb[a].transpose() * Kj;
          for (int c = 0; c < count; ++c) block(bones[a], bones[c]).noalias() += JaT_K * Jb[c];
        }
        if (k_coupling) {
          const Mat3 KM = Kj * node_M_[j];
          for (int a = 0; a < count; ++a) coupling[a].noalias() += Jb[a].transpose() * KM;
          if (fixed)
            (*fixed)[size_t(coupling_start_[idx + 1]) - 1].noalias() = node_M_[j].transpose() * KM;
          else if (soft_soft)
            addSoftSoft(H, offset, j, node_M_[j].transpose() * KM, list);
        }
      }
      if (force) {
        const Vec3& f = (*forces)[idx];
        for (int a = 0; a < count; ++a) {
          const int b = bones[a];
          const double w = influences_[influence_start_[j] + a].weight;
          sums.has_curvature[b] = true;
          sums.curvature[b] += w * rotationCurvature(f, lever[a]);
          if (f_coupling) coupling[a].bottomRows<3>() -= w * skew(f) * R[b];
        }
      }
      if (fixed && (k_coupling || f_coupling)) {
        Mat3* out = fixed->data() + coupling_start_[idx];
        for (int a = 0; a < count; ++a, out += 4) {
          out[0] = coupling[a].topRows<3>();
          out[1] = coupling[a].bottomRows<3>();
          out[2] = out[0].transpose();
          out[3] = out[1].transpose();
        }
        continue;
      }
      for (int a = 0; a < count; ++a) {  // without K only the rotation rows are nonzero
        if (k_coupling)
          addBoneSoft<6>(H, offset, 6 * bones[a], j, coupling[a], list);
        else if (f_coupling)
          addBoneSoft<3>(H, offset, 6 * bones[a] + 3, j, coupling[a].bottomRows<3>().eval(), list);
      }
    }
  };
  Sums sums(pair_moments_[size_t(list)]);
  // FEM (the blocks of each node into its own fixed slots, no pair blocks from K): two halves of
  // the nodes on two threads, the second's sums added to the first's after; always two halves,
  // so the sums are the same on any number of threads (the inertia of ~9 k nodes: ~8 → ~4 ms).
  const bool halves = fixed && !K;
  if (halves) {
    Sums second(pair_moments_second_);
    const size_t mid = nodes.size() / 2;
    onTwoThreads([&](int part) {
      if (part == 0)
        mapNodes(0, mid, sums);
      else
        mapNodes(mid, nodes.size(), second);
    });
    for (int key : second.moments->touched()) sums.moments->at(key) += second.moments->at(key);
    second.moments->forget();
    for (int b = 0; b < num_bones_; ++b) {
      sums.has_curvature[b] = sums.has_curvature[b] || second.has_curvature[b];
      sums.curvature[b] += second.curvature[b];
    }
  } else {
    mapNodes(0, nodes.size(), sums);
  }
  TouchedValues<PairMoments>& moments = *sums.moments;
  for (int key : moments.touched()) {
    const PairMoments& m = moments.at(key);
    Mat6& B = block(key / num_bones_, key % num_bones_);
    B.topLeftCorner<3, 3>().diagonal().array() += m.s;
    B.topRightCorner<3, 3>() -= skew(m.p);
    B.bottomLeftCorner<3, 3>() += skew(m.q);
    B.bottomRightCorner<3, 3>() += m.W.trace() * Mat3::Identity() - m.W;
  }
  moments.forget();
  for (int b = 0; b < num_bones_; ++b)
    if (sums.has_curvature[b])
      block(b, b).bottomRightCorner<3, 3>() +=
          psd ? projectToPSD<3>(sums.curvature[b]) : sums.curvature[b];
  pair_blocks.emit(H, offset);
}

void SoftKinematics::surfaceJacobian(std::vector<Triplet>& triplets) const {
  if (reduced_) skinNodes(surface_nodes_);
  const std::vector<Mat3>& R = *cur_R_;
  std::vector<std::pair<int, Mat3>> basis;
  for (int i = 0; i < num_surface_; ++i) {
    const Vec3 Y = Y_.row(i).transpose();
    for (int k = influence_start_[i]; k < influence_start_[i + 1]; ++k) {
      const int b = influences_[k].bone;
      const double w = influences_[k].weight;
      const Mat3 dx_dw = -w * skew(R[b] * (Y - joints_.row(b).transpose()));
      for (int r = 0; r < 3; ++r) {
        triplets.emplace_back(3 * i + r, 6 * b + r, w);
        for (int c = 0; c < 3; ++c) triplets.emplace_back(3 * i + r, 6 * b + 3 + c, dx_dw(r, c));
      }
    }
    displacementBasis(i, basis);
    for (const auto& [dof, block] : basis) {
      const Mat3 MB = node_M_[i] * block;
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c)
          triplets.emplace_back(3 * i + r, bone_dofs_ + dof + c, MB(r, c));
    }
  }
}

}  // namespace flsh::detail
