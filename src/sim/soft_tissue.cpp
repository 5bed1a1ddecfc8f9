// Soft-tissue terms of the FEM soft skeleton; see soft_tissue.h for the formulas.
#include "soft_tissue.h"

#include "hessian_blocks.h"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <string>

#include "core/first_failure.h"
#include "flsh/body/smpl_skeleton.h"
#include "flsh/core/error.h"
#include "flsh/core/rotation.h"
#include "flsh/sim/simulable.h"
#include "flsh/volume/reduced_data.h"
#include "flsh/volume/volumetric_data.h"

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

SoftTissue::SoftTissue(const SoftAvatar& avatar, const MatX3& joints,
                       const std::vector<int>& parents, double time_step)
    : num_bones_(int(joints.rows())), bone_dofs_(6 * int(joints.rows())), h_(time_step),
      parents_(parents), joints_(joints) {
  const VolumetricData& data = avatar.volumetricData();
  const VolumetricTemplate& templ = *data.templ;
  const int n = data.numNodes();
  rest_ = data.rest_nodes;
  num_surface_ = templ.mesh.num_surface_nodes;
  posedirs_ = &templ.fields.posedirs;
  if (posedirs_->rows() != 3 * n || posedirs_->cols() != 9 * (num_bones_ - 1))
    throw InputError("Simulable: the avatar's volumetric pose blend shapes are " +
                     std::to_string(posedirs_->rows()) + " × " +
                     std::to_string(posedirs_->cols()) + ", expected " + std::to_string(3 * n) +
                     " × " + std::to_string(9 * (num_bones_ - 1)));
  blend_ = MatX3::Zero(n, 3);

  // Soft-tissue nodes and their DoF offsets.
  node_dof_.assign(n, -1);
  std::vector<int> soft;
  for (int j = 0; j < n; ++j)
    if (data.bone_of_node[j] < 0) {
      node_dof_[j] = 3 * int(soft.size());
      soft.push_back(j);
    }
  reduced_ = avatar.reducedModelEnabled();
  const ReducedData* rom = reduced_ ? &avatar.reducedData() : nullptr;
  if (!rom) {
    state_nodes_ = Eigen::Map<const VecXi>(soft.data(), Eigen::Index(soft.size()));
  } else {
    num_handles_ = rom->numHandles();
    if (rom->basis.rows() != n || rom->basis.cols() != num_handles_)
      throw InputError("Simulable: the avatar's reduced basis is " +
                       std::to_string(rom->basis.rows()) + " × " +
                       std::to_string(rom->basis.cols()) + ", expected #nodes × #handles = " +
                       std::to_string(n) + " × " + std::to_string(num_handles_));
    state_nodes_ = rom->handles;
    state_dof_.assign(n, -1);
    for (int h = 0; h < num_handles_; ++h) state_dof_[rom->handles[h]] = 3 * h;
    // Rows of φ (the basis is stored by columns); bone nodes never move (u = 0).
    const SpMat rows = rom->basis.transpose();
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

  // Lumped masses, and the elastic elements: every tet with a soft node (tets whose four nodes
  // are bone nodes never deform, u = 0 there), or the elastic cubature's sample tets.
  const MatX4i& all_tets = templ.mesh.tets;
  mass_ = VecX::Zero(n);
  std::vector<int> kept;
  std::vector<double> kept_weight;
  auto hasSoftNode = [&](int e) {
    for (int a = 0; a < 4; ++a)
      if (node_dof_[all_tets(e, a)] >= 0) return true;
    return false;
  };
  for (int e = 0; e < all_tets.rows(); ++e) {
    Vec3 X[4];
    for (int a = 0; a < 4; ++a) X[a] = rest_.row(all_tets(e, a)).transpose();
    const double volume = std::abs((X[1] - X[0]).cross(X[2] - X[0]).dot(X[3] - X[0])) / 6.0;
    const double node_mass = data.materials.density[e] * volume / 4.0;
    for (int a = 0; a < 4; ++a) mass_[all_tets(e, a)] += node_mass;
  }
  if (rom && rom->elastic.elements.size() > 0) {
    for (Eigen::Index k = 0; k < rom->elastic.elements.size(); ++k) {
      const int e = rom->elastic.elements[k];
      if (e < 0 || e >= all_tets.rows())
        throw InputError("Simulable: the avatar's elastic cubature names tet " +
                         std::to_string(e) + ", expected [0, " +
                         std::to_string(all_tets.rows()) + ")");
      if (!hasSoftNode(e)) continue;  // zero energy whatever the state
      kept.push_back(e);
      kept_weight.push_back(rom->elastic.weights[k]);
    }
  } else {
    for (int e = 0; e < all_tets.rows(); ++e)
      if (hasSoftNode(e)) {
        kept.push_back(e);
        kept_weight.push_back(1.0);
      }
  }
  tets_.resize(Eigen::Index(kept.size()), 4);
  element_weight_ = Eigen::Map<const VecX>(kept_weight.data(), Eigen::Index(kept_weight.size()));
  elements_.reserve(kept.size());
  materials_.reserve(kept.size());
  for (size_t k = 0; k < kept.size(); ++k) {
    const int e = kept[k];
    tets_.row(Eigen::Index(k)) = all_tets.row(e);
    Mat34 X;
    for (int a = 0; a < 4; ++a) X.col(a) = rest_.row(all_tets(e, a)).transpose();
    elements_.push_back(tetElementRest(X, e));
    materials_.push_back(femMaterialPoint(data.materials, e));
  }
  if (rom && rom->elastic_rest_stiffness.size() > 0) {
    rest_stiffness_ = rom->elastic_rest_stiffness;
    if (rest_stiffness_.rows() != 3 * num_handles_ || rest_stiffness_.cols() != 3 * num_handles_)
      throw InputError("Simulable: the avatar's elastic rest stiffness is " +
                       std::to_string(rest_stiffness_.rows()) + " × " +
                       std::to_string(rest_stiffness_.cols()) + ", expected 3·#handles square (" +
                       std::to_string(3 * num_handles_) + ")");
    for (int a = 0; a < num_handles_; ++a)
      for (int b = 0; b < num_handles_; ++b)
        if (!rest_stiffness_.block<3, 3>(3 * a, 3 * b).isZero(0.0))
          rest_stiffness_blocks_.emplace_back(a, b);
  }
  if (reduced_) {  // each elastic tet's handles and its shape gradients through the basis
    tet_handle_start_.assign(1, 0);
    std::vector<Mat3X> gradients;
    int columns = 0;
    for (Eigen::Index e = 0; e < tets_.rows(); ++e) {
      std::vector<int> handles;
      for (int a = 0; a < 4; ++a)
        for (int k = phi_start_[tets_(e, a)]; k < phi_start_[tets_(e, a) + 1]; ++k)
          handles.push_back(phi_[k].first);
      std::sort(handles.begin(), handles.end());
      handles.erase(std::unique(handles.begin(), handles.end()), handles.end());
      Mat4X Phi = Mat4X::Zero(4, Eigen::Index(handles.size()));
      for (size_t s = 0; s < handles.size(); ++s) {
        tet_handles_.push_back(handles[s]);
        for (int a = 0; a < 4; ++a)
          for (int k = phi_start_[tets_(e, a)]; k < phi_start_[tets_(e, a) + 1]; ++k)
            if (phi_[k].first == handles[s]) Phi(a, Eigen::Index(s)) = phi_[k].second;
      }
      gradients.push_back(reducedShapeGradients(elements_[size_t(e)], Phi));
      columns += int(handles.size());
      tet_handle_start_.push_back(int(tet_handles_.size()));
      max_tet_handles_ = std::max(max_tet_handles_, int(handles.size()));
    }
    tet_gradients_.resize(3, columns);
    for (size_t e = 0; e < gradients.size(); ++e)
      tet_gradients_.middleCols(tet_handle_start_[e], gradients[e].cols()) = gradients[e];
    if (rest_stiffness_.size() > 0) {  // each sample tet's own rest quadratic K̃_e
      rest_hessian_start_.assign(1, 0);
      for (size_t e = 0; e < gradients.size(); ++e) {
        const int m = 3 * int(gradients[e].cols());
        rest_hessian_start_.push_back(rest_hessian_start_.back() + m * m);
      }
      rest_hessians_.resize(rest_hessian_start_.back());
      for (size_t e = 0; e < gradients.size(); ++e) {
        const int count = int(gradients[e].cols()), m = 3 * count;
        if (count == 0) continue;
        Eigen::Map<MatX> K(rest_hessians_.data() + rest_hessian_start_[e], m, m);
        Eigen::Ref<MatX> view = K;
        reducedTetElasticEnergy(elements_[e].volume, materials_[e], gradients[e],
                                Mat3X::Zero(3, count), nullptr, &view, false);
      }
      rest_floors_ = restSplitFloors();
    }
  }

  // Inertia and gravity: every node with its lumped mass, or the inertial cubature's nodes.
  inertia_mass_ = rom && rom->inertial.elements.size() > 0
                      ? inertialNodeMasses(data, rom->inertial)
                      : mass_;
  for (int j = 0; j < n; ++j)
    if (inertia_mass_[j] > 0.0) mass_nodes_.push_back(j);

  // Nodes skinned by prepare(): all in the FEM; in the ROM the mass nodes (the elastic energy
  // reads u only; contact and output skin the surface nodes they need).
  if (!reduced_) {
    eval_nodes_.resize(n);
    for (int j = 0; j < n; ++j) eval_nodes_[j] = j;
  } else {
    eval_nodes_ = mass_nodes_;
  }

  // Fixed coupling positions of the FEM's inertia and gravity Hessians.
  if (!reduced_) {
    coupling_start_.assign(mass_nodes_.size() + 1, 0);
    for (size_t idx = 0; idx < mass_nodes_.size(); ++idx) {
      const int j = mass_nodes_[idx];
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
  }

  // The FEM elastic Hessian's blocks: soft-node pairs sharing a tet as (column node, row node),
  // sorted, so that the blocks are column-major.
  if (!reduced_) {
    std::vector<std::pair<int, int>> pairs;
    for (Eigen::Index e = 0; e < tets_.rows(); ++e)
      for (int a = 0; a < 4; ++a)
        for (int b = 0; b < 4; ++b)
          if (node_dof_[tets_(e, a)] >= 0 && node_dof_[tets_(e, b)] >= 0)
            pairs.emplace_back(tets_(e, b), tets_(e, a));
    std::sort(pairs.begin(), pairs.end());
    pairs.erase(std::unique(pairs.begin(), pairs.end()), pairs.end());
    tet_block_.assign(16 * size_t(tets_.rows()), -1);
    for (Eigen::Index e = 0; e < tets_.rows(); ++e)
      for (int a = 0; a < 4; ++a)
        for (int b = 0; b < 4; ++b) {
          const std::pair<int, int> key(tets_(e, b), tets_(e, a));  // (column, row)
          if (node_dof_[key.first] < 0 || node_dof_[key.second] < 0) continue;
          tet_block_[16 * e + 4 * a + b] =
              int(std::lower_bound(pairs.begin(), pairs.end(), key) - pairs.begin());
        }
    block_dofs_.resize(pairs.size());
    for (size_t k = 0; k < pairs.size(); ++k)
      block_dofs_[k] = {bone_dofs_ + node_dof_[pairs[k].second],
                        bone_dofs_ + node_dof_[pairs[k].first]};
  }

  areas_ = avatar.vertexAreas();
  x_hat_ = rest_;
  for (BonePairBlocks& blocks : pair_blocks_) blocks.resize(num_bones_);
  for (auto& moments : pair_moments_) moments.resize(size_t(num_bones_) * num_bones_, PairMoments{});
  all_nodes_.resize(n);
  for (int j = 0; j < n; ++j) all_nodes_[j] = j;
  surface_nodes_.assign(all_nodes_.begin(), all_nodes_.begin() + num_surface_);

  // Pose blend and the broad-phase bounds.
  const int features = int(posedirs_->cols());
  feature_ = VecX::Zero(features);
  blend_bound_.resize(num_surface_);
  for (int i = 0; i < num_surface_; ++i)
    blend_bound_[i] = posedirs_->middleRows(3 * i, 3).norm();
  if (reduced_) {
    blend_stamp_.assign(n, 0);  // pose_stamp_ 0: the zero feature, whose offsets are zero
    blend_slot_.assign(n, -1);
    int slots = 0;
    for (int j = 0; j < num_surface_; ++j) blend_slot_[j] = slots++;
    for (int j : mass_nodes_)
      if (blend_slot_[j] < 0) blend_slot_[j] = slots++;
    posedirs_T_.resize(features, 3 * slots);
    for (int j = 0; j < n; ++j)
      if (blend_slot_[j] >= 0)
        posedirs_T_.middleCols(3 * blend_slot_[j], 3) = posedirs_->middleRows(3 * j, 3).transpose();
    phi_sum_ = VecX::Zero(num_surface_);
    for (int i = 0; i < num_surface_; ++i)
      for (int k = phi_start_[i]; k < phi_start_[i + 1]; ++k) phi_sum_[i] += phi_[k].second;
    buildReducedPattern();
    splitMassNodes();
  }
}

void SoftTissue::buildReducedPattern() {
  // Every (handle, handle) pair some node or elastic tet couples, plus the rest stiffness's;
  // every (bone row block, handle) pair some node's skinning couples.
  const int H = num_handles_, rows = 2 * num_bones_;
  std::vector<char> zz(size_t(H) * H, 0), bz(size_t(rows) * H, 0);
  for (int j = 0; j < numNodes(); ++j) {
    for (int a = phi_start_[j]; a < phi_start_[j + 1]; ++a) {
      for (int b = phi_start_[j]; b < phi_start_[j + 1]; ++b)
        zz[size_t(phi_[a].first) * H + phi_[b].first] = 1;
      for (int k = influence_start_[j]; k < influence_start_[j + 1]; ++k)
        for (int r = 0; r < 2; ++r)
          bz[size_t(2 * influences_[k].bone + r) * H + phi_[a].first] = 1;
    }
  }
  for (size_t e = 0; e + 1 < tet_handle_start_.size(); ++e)
    for (int s = tet_handle_start_[e]; s < tet_handle_start_[e + 1]; ++s)
      for (int r = tet_handle_start_[e]; r < tet_handle_start_[e + 1]; ++r)
        zz[size_t(tet_handles_[s]) * H + tet_handles_[r]] = 1;
  for (const auto& [a, b] : rest_stiffness_blocks_) zz[size_t(a) * H + b] = 1;
  // Slots: the z–z blocks, then the bone–z blocks, then their transposes (z–bone).
  zz_slot_.assign(zz.size(), -1);
  bz_slot_.assign(bz.size(), -1);
  reduced_positions_.clear();
  for (int k = 0; k < H; ++k)  // column-major
    for (int h = 0; h < H; ++h)
      if (zz[size_t(h) * H + k]) {
        zz_slot_[size_t(h) * H + k] = int(reduced_positions_.size());
        reduced_positions_.emplace_back(bone_dofs_ + 3 * h, bone_dofs_ + 3 * k);
      }
  num_zz_ = int(reduced_positions_.size());
  zz_mirror_.clear();  // the terms sum the upper blocks (h ≤ k); the lower ones are their transposes
  for (int h = 0; h < H; ++h)
    for (int k = 0; k < h; ++k)
      if (zz_slot_[size_t(h) * H + k] >= 0)
        zz_mirror_.emplace_back(zz_slot_[size_t(h) * H + k], zz_slot_[size_t(k) * H + h]);
  for (int h = 0; h < H; ++h)
    for (int r = 0; r < rows; ++r)
      if (bz[size_t(r) * H + h]) {
        bz_slot_[size_t(r) * H + h] = int(reduced_positions_.size());
        reduced_positions_.emplace_back(3 * r, bone_dofs_ + 3 * h);
      }
  num_bz_ = int(reduced_positions_.size()) - num_zz_;
  for (int k = 0; k < num_bz_; ++k) {
    const auto [row, col] = reduced_positions_[size_t(num_zz_ + k)];
    reduced_positions_.emplace_back(col, row);
  }
  for (auto& values : reduced_values_) values.assign(reduced_positions_.size(), Mat3::Zero());
  // Gravity's rotation–handle blocks: D_bh = Σ_j m_j w_jb φ_jh over the mass nodes.
  std::vector<double> D(size_t(num_bones_) * H, 0.0);
  for (int j : mass_nodes_)
    for (int k = influence_start_[j]; k < influence_start_[j + 1]; ++k)
      for (int a = phi_start_[j]; a < phi_start_[j + 1]; ++a)
        D[size_t(influences_[k].bone) * H + phi_[a].first] +=
            inertia_mass_[j] * influences_[k].weight * phi_[a].second;
  gravity_handles_.clear();
  for (int b = 0; b < num_bones_; ++b)
    for (int h = 0; h < H; ++h)
      if (D[size_t(b) * H + h] != 0.0)
        gravity_handles_.push_back({bz_slot_[size_t(2 * b + 1) * H + h], b, D[size_t(b) * H + h]});
}

// ---- positions ----------------------------------------------------------------------------

void SoftTissue::setPoseBlend(const std::vector<Mat3>& R) {
  for (int b = 1; b < num_bones_; ++b) {
    const Mat3 local = R[parents_[b]].transpose() * R[b];
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) feature_[9 * (b - 1) + 3 * r + c] = local(r, c) - (r == c);
  }
  if (reduced_) {
    ++pose_stamp_;
    return;
  }
  const VecX offsets = (*posedirs_) * feature_;  // row 3j + c
  blend_ = Eigen::Map<const MatX3>(offsets.data(), numNodes(), 3);
}

Vec3 SoftTissue::blendOf(int j) const {
  if (!reduced_ || blend_stamp_[j] == pose_stamp_) return blend_.row(j).transpose();
  const int slot = blend_slot_[j];
  const Vec3 P = slot >= 0 ? Vec3(posedirs_T_.middleCols<3>(3 * slot).transpose() * feature_)
                           : Vec3(posedirs_->middleRows<3>(3 * j) * feature_);
  blend_.row(j) = P.transpose();
  blend_stamp_[j] = pose_stamp_;
  return P;
}

const MatX3& SoftTissue::poseBlend() const {
  if (reduced_)
    for (int j = 0; j < numNodes(); ++j) blendOf(j);
  return blend_;
}

void SoftTissue::setPoseBlendOffsets(const MatX3& offsets) {
  blend_ = offsets;
  if (reduced_) std::fill(blend_stamp_.begin(), blend_stamp_.end(), pose_stamp_);
}

double SoftTissue::displacementWeight(int i) const {
  if (!reduced_) return node_dof_[i] >= 0 ? 1.0 : 0.0;
  return phi_sum_[i];
}

double SoftTissue::largestSoftState() const {
  double largest = 0.0;
  for (Eigen::Index k = 0; k + 2 < u.size(); k += 3) largest = std::max(largest, u.segment<3>(k).norm());
  return largest;
}

void SoftTissue::positionsOf(const std::vector<int>& nodes, const BoneFrames& bones,
                             const VecX& state, MatX3& x) const {
  Vec3 shift[kNumJoints];
  for (int b = 0; b < num_bones_; ++b)
    shift[b] = bones.t.row(b).transpose() - bones.R[b] * joints_.row(b).transpose();
  if (x.rows() != numNodes()) x.resize(numNodes(), 3);
  // Distinct nodes: each writes its own row (and blendOf its own row and stamp).
  const long count = long(nodes.size());
#pragma omp parallel for schedule(static) if (count >= 512)
  for (long idx = 0; idx < count; ++idx) {
    const int j = nodes[size_t(idx)];
    const Vec3 Y = rest_.row(j).transpose() + blendOf(j) + nodeDisplacement(state, j);
    Vec3 p = Vec3::Zero();
    for (int k = influence_start_[j]; k < influence_start_[j + 1]; ++k) {
      const Influence& inf = influences_[k];
      p += inf.weight * (bones.R[inf.bone] * Y + shift[inf.bone]);
    }
    x.row(j) = p.transpose();
  }
}

void SoftTissue::positions(const BoneFrames& bones, const VecX& displacement, MatX3& x) const {
  positionsOf(all_nodes_, bones, displacement, x);
}

void SoftTissue::setPrediction(const BoneFrames& bones_n, const BoneFrames& bones_nm1) {
  // Only the mass nodes carry inertia.
  MatX3 x_n, x_nm1;
  positionsOf(mass_nodes_, bones_n, u_n, x_n);
  positionsOf(mass_nodes_, bones_nm1, u_nm1, x_nm1);
  for (int j : mass_nodes_) x_hat_.row(j) = 2.0 * x_n.row(j) - x_nm1.row(j);
}

void SoftTissue::prepare(long version, const BoneFrames& bones) const {
  cur_R_ = &bones.R;
  cur_t_ = &bones.t;
  if (version == version_) return;
  version_ = version;
  skinNodes(eval_nodes_);
}

void SoftTissue::skinNodes(const std::vector<int>& nodes) const {
  const int n = numNodes();
  if (Y_.rows() != n) Y_.setZero(n, 3);
  if (x_.rows() != n) x_.setZero(n, 3);
  node_M_.resize(n);
  const std::vector<Mat3>& R = *cur_R_;
  const MatX3& t = *cur_t_;
  Vec3 shift[kNumJoints];
  for (int b = 0; b < num_bones_; ++b) shift[b] = t.row(b).transpose() - R[b] * joints_.row(b).transpose();
  // Nodes are distinct: each writes its own rows (and blendOf its own row and stamp).
  const long count = long(nodes.size());
#pragma omp parallel for schedule(static) if (count >= 512)
  for (long idx = 0; idx < count; ++idx) {
    const int j = nodes[size_t(idx)];
    const Vec3 Y = rest_.row(j).transpose() + blendOf(j) + nodeDisplacement(u, j);
    Vec3 p = Vec3::Zero();
    Mat3 M = Mat3::Zero();
    for (int k = influence_start_[j]; k < influence_start_[j + 1]; ++k) {
      const Influence& inf = influences_[k];
      p += inf.weight * (R[inf.bone] * Y + shift[inf.bone]);
      M += inf.weight * R[inf.bone];
    }
    Y_.row(j) = Y.transpose();
    x_.row(j) = p.transpose();
    node_M_[j] = M;
  }
}

void SoftTissue::surface(MatX3* x, MatX3* Y) const {
  if (reduced_) skinNodes(surface_nodes_);
  if (x) *x = x_.topRows(num_surface_);
  if (Y) *Y = Y_.topRows(num_surface_);
}

// ---- the chain rule to the soft state -----------------------------------------------------------

void SoftTissue::displacementBasis(int j, std::vector<std::pair<int, double>>& out) const {
  out.clear();
  if (!reduced_) {
    if (node_dof_[j] >= 0) out.emplace_back(node_dof_[j], 1.0);
    return;
  }
  for (int k = phi_start_[j]; k < phi_start_[j + 1]; ++k)
    out.emplace_back(3 * phi_[k].first, phi_[k].second);
}

void SoftTissue::addSoftGradient(VecX& g, int offset, int j, const Vec3& v) const {
  const int base = offset + bone_dofs_;
  if (!reduced_) {
    if (node_dof_[j] >= 0) g.segment<3>(base + node_dof_[j]) += v;
    return;
  }
  for (int k = phi_start_[j]; k < phi_start_[j + 1]; ++k)
    g.segment<3>(base + 3 * phi_[k].first) += phi_[k].second * v;
}

template <int Rows>
void SoftTissue::addBoneSoft(std::vector<Triplet>& H, int offset, int row, int j,
                             const Eigen::Matrix<double, Rows, 3>& B, int list) const {
  if (!reduced_) {
    if (node_dof_[j] < 0) return;
    const int u_index = offset + bone_dofs_ + node_dof_[j];
    addBlock(H, offset + row, u_index, B);
    addBlock(H, u_index, offset + row, B.transpose());
    return;
  }
  Mat3* values = reduced_values_[size_t(list)].data();
  const size_t handles = size_t(num_handles_);
  for (int k = phi_start_[j]; k < phi_start_[j + 1]; ++k)
    for (int r = 0; r < Rows; r += 3)
      values[bz_slot_[size_t((row + r) / 3) * handles + size_t(phi_[k].first)]] +=
          phi_[k].second * B.template middleRows<3>(r);
}

void SoftTissue::addSoftSoft(std::vector<Triplet>& H, int offset, int j, const Mat3& B,
                             int list) const {
  if (!reduced_) {
    if (node_dof_[j] < 0) return;
    const int u_index = offset + bone_dofs_ + node_dof_[j];
    addBlock(H, u_index, u_index, B);
    return;
  }
  // B is symmetric: the upper triangle of handle pairs (φ_ rows are sorted by handle);
  // flushReduced mirrors it.
  Mat3* values = reduced_values_[size_t(list)].data();
  const size_t handles = size_t(num_handles_);
  for (int a = phi_start_[j]; a < phi_start_[j + 1]; ++a) {
    const size_t row = size_t(phi_[a].first) * handles;
    for (int b = a; b < phi_start_[j + 1]; ++b)
      values[zz_slot_[row + size_t(phi_[b].first)]] += (phi_[a].second * phi_[b].second) * B;
  }
}

namespace {
// reducedHessians maps this share of inertia's mass nodes beside the potential terms: on the full
// synthetic body (684 mass nodes, ~390 elastic tets) the other 90 % of inertia's blocks cost about
// as much as contact, gravity, every elastic tet and the rest-stiffness term (265 against 260–290 µs
// per Hessian; scene Hessian 0.42–0.46 ms against 0.50 with the elastic tets split instead).
// reducedGradient runs half of the tets beside inertia's and gravity's force mapping (about as
// costly as contact).
constexpr double kHessianMassNodesBesideElastic = 0.1, kGradientTetsBesideInertia = 0.5;

// Runs part(0) and part(1) on a team of two OpenMP threads (both on one thread when the team has
// one, e.g. in a nested region); the first exception either throws is rethrown after both.
template <class Part>
void onTwoThreads(Part&& part) {
  FirstFailure failure;
#pragma omp parallel num_threads(2)
  {
    const int threads = omp_get_num_threads(), t = omp_get_thread_num();
    for (int p = t; p < 2; p += threads) failure.run([&] { part(p); });
  }
  failure.rethrow();
}

// Zeroes `count` 3 × 3 blocks stored back to back (one vectorized pass).
void zeroBlocks(Mat3* blocks, int count) {
  static_assert(sizeof(Mat3) == 9 * sizeof(double), "Mat3 must be 9 packed doubles");
  Eigen::Map<VecX>(blocks->data(), 9 * Eigen::Index(count)).setZero();
}
}  // namespace

void SoftTissue::beginReduced(int list) const {
  if (!reduced_) return;
  // The summed slots only (z–z and bone–z; the z–bone ones are written by the mirroring).
  zeroBlocks(reduced_values_[size_t(list)].data(), num_zz_ + num_bz_);
  mirrored_[size_t(list)] = false;
}

void SoftTissue::mirrorReduced(int list, int part, int parts) const {
  std::vector<Mat3>& values = reduced_values_[size_t(list)];
  const size_t mirrors = zz_mirror_.size();
  for (size_t k = part * mirrors / parts; k < (part + 1) * mirrors / parts; ++k)
    values[size_t(zz_mirror_[k].first)] = values[size_t(zz_mirror_[k].second)].transpose();
  for (int k = part * num_bz_ / parts; k < (part + 1) * num_bz_ / parts; ++k)
    values[size_t(num_zz_ + num_bz_ + k)] = values[size_t(num_zz_ + k)].transpose();
}

void SoftTissue::flushReduced(int list, std::vector<Triplet>& H, int offset,
                              std::vector<FixedHessianBlocks>* blocks) const {
  if (!reduced_) return;
  std::vector<Mat3>& values = reduced_values_[size_t(list)];
  if (!mirrored_[size_t(list)]) mirrorReduced(list, 0, 1);
  if (blocks) {
    blocks->push_back({&reduced_positions_, &values, offset});
    return;
  }
  for (size_t k = 0; k < values.size(); ++k)
    if (!values[k].isZero(0.0))
      addBlock(H, offset + reduced_positions_[k].first, offset + reduced_positions_[k].second,
               values[k]);
}

// ---- mapping node derivatives to the state ----------------------------------------------------

void SoftTissue::mapForces(const std::vector<int>& nodes, const std::vector<Vec3>& forces,
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

void SoftTissue::mapHessian(const std::vector<int>& nodes, const std::vector<Mat3>* K,
                            const std::vector<Vec3>* forces, std::vector<Triplet>& H, int offset,
                            bool psd, int list, std::vector<Mat3>* fixed,
                            const std::vector<double>* K_scalar) const {
  if (fixed) fixed->assign(coupling_dofs_.size(), Mat3::Zero());
  const std::vector<Mat3>& R = *cur_R_;
  BonePairBlocks& pair_blocks = pair_blocks_[size_t(list)];
  auto block = [&](int b, int c) -> Mat6& { return pair_blocks.block(b, c); };
  // K_j = κ_j I: J_aᵀ J_c = w_a w_c [I, −[r_c]×; [r_a]×, (r_a·r_c) I − r_c r_aᵀ] is summed over
  // the nodes as moments per bone pair (κ w w, its r_c- and r_a-weighted sums and Σ κ w w r_c
  // r_aᵀ), 16 products per pair and node instead of a 6 × 3 × 6 product; blocks at the end.
  TouchedValues<PairMoments>& moments = pair_moments_[size_t(list)];
  Mat3 curvature[kNumJoints];
  bool has_curvature[kNumJoints] = {};
  Eigen::Matrix<double, 3, 6> Jb[kNumJoints];
  Vec3 lever[kNumJoints];
  int bones[kNumJoints];
  for (size_t idx = 0; idx < nodes.size(); ++idx) {
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
    const bool k_coupling = (K || K_scalar) && dof >= 0, f_coupling = force && !psd && dof >= 0;
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
        const Mat3 MtKM = kappa * (M.transpose() * M);
        if (fixed)
          (*fixed)[size_t(coupling_start_[idx + 1]) - 1] = MtKM;
        else
          addSoftSoft(H, offset, j, MtKM, list);
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
        else
          addSoftSoft(H, offset, j, node_M_[j].transpose() * KM, list);
      }
    }
    if (force) {
      const Vec3& f = (*forces)[idx];
      for (int a = 0; a < count; ++a) {
        const int b = bones[a];
        const double w = influences_[influence_start_[j] + a].weight;
        if (!has_curvature[b]) curvature[b].setZero();
        has_curvature[b] = true;
        curvature[b] += w * rotationCurvature(f, lever[a]);
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
    if (has_curvature[b])
      block(b, b).bottomRightCorner<3, 3>() += psd ? projectToPSD<3>(curvature[b]) : curvature[b];
  pair_blocks.emit(H, offset);
}

// ---- energies -------------------------------------------------------------------------------

double SoftTissue::inertia(VecX* g, std::vector<Triplet>* H, int offset, bool psd,
                           FixedHessianBlocks* blocks) const {
  const double k = 1.0 / (h_ * h_);
  const size_t count = mass_nodes_.size();
  double E = 0.0;
  node_forces_[0].resize(count);
  for (size_t idx = 0; idx < count; ++idx) {
    const int j = mass_nodes_[idx];
    const Vec3 d = (x_.row(j) - x_hat_.row(j)).transpose();
    E += 0.5 * k * inertia_mass_[j] * d.squaredNorm();
    node_forces_[0][idx] = k * inertia_mass_[j] * d;
  }
  if (g) mapForces(mass_nodes_, node_forces_[0], *g, offset);
  if (H) {
    node_scalars_.resize(count);
    for (size_t idx = 0; idx < count; ++idx) node_scalars_[idx] = k * inertia_mass_[mass_nodes_[idx]];
    // psd: Gauss–Newton Σ m JᵀJ; exact: plus the curvature of the rotating nodes.
    const bool fixed = blocks && !reduced_;
    mapHessian(mass_nodes_, nullptr, psd ? nullptr : &node_forces_[0], *H, offset, psd, 0,
               fixed ? &inertia_fixed_ : nullptr, &node_scalars_);
    if (fixed) *blocks = {&coupling_dofs_, &inertia_fixed_, offset};
  }
  return E;
}

double SoftTissue::gravity(const Vec3& gravity, VecX* g, std::vector<Triplet>* H, int offset,
                           bool psd, FixedHessianBlocks* blocks) const {
  const size_t count = mass_nodes_.size();
  double E = 0.0;
  node_forces_[1].resize(count);
  for (size_t idx = 0; idx < count; ++idx) {
    const int j = mass_nodes_[idx];
    E -= inertia_mass_[j] * gravity.dot(x_.row(j).transpose());
    node_forces_[1][idx] = -inertia_mass_[j] * gravity;
  }
  if (g) mapForces(mass_nodes_, node_forces_[1], *g, offset);
  if (H && reduced_) {
    reducedGravityHessian(gravity, *H, offset, psd);
  } else if (H) {
    // The PSD form has no coupling blocks: the fixed list is then all zeros, so that its
    // positions (and an assembler's cached slots) stay the same in both forms.
    mapHessian(mass_nodes_, nullptr, &node_forces_[1], *H, offset, psd, 1,
               blocks ? &gravity_fixed_ : nullptr);
    if (blocks) *blocks = {&coupling_dofs_, &gravity_fixed_, offset};
  }
  return E;
}

void SoftTissue::splitMassNodes() {
  const size_t first =
      size_t((1.0 - kHessianMassNodesBesideElastic) * double(mass_nodes_.size()));
  mass_node_parts_[0].assign(mass_nodes_.begin(), mass_nodes_.begin() + long(first));
  mass_node_parts_[1].assign(mass_nodes_.begin() + long(first), mass_nodes_.end());
}

void SoftTissue::inertiaHessianPart(int part, std::vector<Triplet>& H, int offset,
                                    bool psd) const {
  // inertia()'s Hessian on this part's nodes, into value list `part`.
  const double k = 1.0 / (h_ * h_);
  const std::vector<int>& nodes = mass_node_parts_[part];
  std::vector<double>& kappa = part_scalars_[part];
  std::vector<Vec3>& forces = part_forces_[part];
  kappa.resize(nodes.size());
  if (!psd) forces.resize(nodes.size());
  for (size_t idx = 0; idx < nodes.size(); ++idx) {
    const int j = nodes[idx];
    kappa[idx] = k * inertia_mass_[j];
    if (!psd) forces[idx] = kappa[idx] * (x_.row(j) - x_hat_.row(j)).transpose();
  }
  mapHessian(nodes, nullptr, psd ? nullptr : &forces, H, offset, psd, part, nullptr, &kappa);
}

void SoftTissue::reducedGravityHessian(const Vec3& gravity, std::vector<Triplet>& H, int offset,
                                       bool psd) const {
  // The node forces f_j = −m_j g are constant, so mapHessian's per-node sums collapse to per-bone
  // ones: the rotation curvature Σ_j w_jb C(f_j, R_b (Y_j − J_b)) = C(−g, R_b v_b) with v_b =
  // Σ_j m_j w_jb (Y_j − J_b) (C is bilinear), and, in the exact form, the rotation–handle blocks
  // Σ_j −w_jb φ_jh [f_j]× R_b = D_bh [g]× R_b (D_bh constant, buildReducedPattern).
  const std::vector<Mat3>& R = *cur_R_;
  Vec3 v[kNumJoints];
  double mass[kNumJoints];
  for (int b = 0; b < num_bones_; ++b) {
    v[b].setZero();
    mass[b] = 0.0;
  }
  for (int j : mass_nodes_) {
    const Vec3 Y = Y_.row(j).transpose();
    for (int k = influence_start_[j]; k < influence_start_[j + 1]; ++k) {
      const double mw = inertia_mass_[j] * influences_[k].weight;
      v[influences_[k].bone] += mw * Y;
      mass[influences_[k].bone] += mw;
    }
  }
  for (int b = 0; b < num_bones_; ++b) {
    if (mass[b] == 0.0) continue;
    const Vec3 lever = R[b] * (v[b] - mass[b] * joints_.row(b).transpose());
    const Mat3 C = rotationCurvature(-gravity, lever);
    addBlock(H, offset + 6 * b + 3, offset + 6 * b + 3, psd ? projectToPSD<3>(C) : C);
  }
  if (psd) return;
  Mat3* values = reduced_values_[1].data();
  const Mat3 G = skew(gravity);
  for (const GravityHandle& gh : gravity_handles_) values[gh.slot] += gh.weight * (G * R[gh.bone]);
}

Eigen::Matrix<double, 3, 4> SoftTissue::elementDisplacement(int e) const {
  Eigen::Matrix<double, 3, 4> U;
  for (int a = 0; a < 4; ++a) U.col(a) = nodeDisplacement(u, tets_(e, a));
  return U;
}

double SoftTissue::elastic(VecX* g, std::vector<Triplet>* H, int offset, bool psd,
                           FixedHessianBlocks* blocks) const {
  if (reduced_) return elasticReduced(g, H ? &reduced_values_[1] : nullptr, offset, psd);
  const int T = int(tets_.rows());
  if (g) element_gradients_.resize(T);
  if (H) element_hessians_.resize(T);
  double E = 0.0;
  FirstFailure failure;
#pragma omp parallel for schedule(static) reduction(+ : E) if (T > 2000)
  for (int e = 0; e < T; ++e) {
    double tet = 0.0;  // the reduction's E stays outside the lambda
    failure.run([&] {
      const double w = element_weight_[e];
      tet = w * tetElasticEnergy(elements_[e], materials_[e], elementDisplacement(e),
                                 g ? &element_gradients_[e] : nullptr,
                                 H ? &element_hessians_[e] : nullptr, psd);
      if (w != 1.0) {
        if (g) element_gradients_[e] *= w;
        if (H) element_hessians_[e] *= w;
      }
    });
    E += tet;
  }
  failure.rethrow();
  if (g) {
    for (int e = 0; e < T; ++e)
      for (int a = 0; a < 4; ++a)
        addSoftGradient(*g, offset, tets_(e, a), element_gradients_[e].segment<3>(3 * a));
  }
  if (H) {
    blocks_.assign(block_dofs_.size(), Mat3::Zero());
    for (int e = 0; e < T; ++e) {
      const int* slots = &tet_block_[16 * size_t(e)];
      for (int a = 0; a < 4; ++a)
        for (int b = 0; b < 4; ++b)
          if (slots[4 * a + b] >= 0)
            blocks_[slots[4 * a + b]] += element_hessians_[e].block<3, 3>(3 * a, 3 * b);
    }
    if (blocks) {
      *blocks = {&block_dofs_, &blocks_, offset};
    } else {
      for (size_t k = 0; k < block_dofs_.size(); ++k)
        addBlock(*H, offset + block_dofs_[k].first, offset + block_dofs_[k].second, blocks_[k]);
    }
  }
  return E;
}

double SoftTissue::elasticTets(int first, int last, double* gz, Mat3* values, bool psd) const {
  // Per elastic tet, F = I + Z G̃ᵀ on the tet's handles (reducedTetElasticEnergy): gradient
  // and Hessian come straight in the handles' coordinates, one 3 × 3 block per handle pair.
  const size_t handles = size_t(num_handles_);
  const bool hessian = values != nullptr;
  double E = 0.0;
  Mat3X Z(3, max_tet_handles_);
  VecX ge(3 * max_tet_handles_);
  MatX He(hessian ? 3 * max_tet_handles_ : 0, hessian ? 3 * max_tet_handles_ : 0);
  for (int e = first; e < last; ++e) {
    const int begin = tet_handle_start_[e], count = tet_handle_start_[e + 1] - begin;
    if (count == 0) continue;
    const int* tet_handles = &tet_handles_[size_t(begin)];
    for (int s = 0; s < count; ++s) Z.col(s) = u.segment<3>(3 * tet_handles[s]);
    Eigen::Ref<VecX> gradient = ge.head(3 * count);
    Eigen::Ref<MatX> tet_hessian =
        He.topLeftCorner(hessian ? 3 * count : 0, hessian ? 3 * count : 0);
    double w = element_weight_[e];
    if (rest_stiffness_.size() == 0) {
      E += w * reducedTetElasticEnergy(elements_[size_t(e)].volume, materials_[size_t(e)],
                                       tet_gradients_.middleCols(begin, count), Z.leftCols(count),
                                       gz ? &gradient : nullptr, hessian ? &tet_hessian : nullptr,
                                       psd);
    } else {
      E += sampleTetExcess(e, count, w, Z.leftCols(count), gz != nullptr, hessian, psd, gradient,
                           tet_hessian);
      w = 1.0;  // the excess comes weighted
    }
    if (gz)
      for (int s = 0; s < count; ++s)
        Eigen::Map<Vec3>(gz + 3 * tet_handles[s]) += w * gradient.segment<3>(3 * s);
    if (hessian)  // upper triangle of handle pairs (tet_handles_ ascending)
      for (int s = 0; s < count; ++s) {
        const size_t row = size_t(tet_handles[s]) * handles;
        for (int r = s; r < count; ++r)
          values[zz_slot_[row + size_t(tet_handles[r])]] +=
              w * tet_hessian.block<3, 3>(3 * s, 3 * r);
      }
  }
  return E;
}

double SoftTissue::sampleTetExcess(int e, int count, double w, const Eigen::Ref<const Mat3X>& Z,
                                   bool want_gradient, bool want_hessian, bool psd,
                                   Eigen::Ref<VecX> gradient, Eigen::Ref<MatX> hessian) const {
  // restSplitExcess (fem_material.h) of the tet's energy, with its stored rest Hessian.
  const int m = 3 * count, begin = tet_handle_start_[e];
  const Eigen::Map<const MatX> K(rest_hessians_.data() + rest_hessian_start_[e], m, m);
  const bool derivatives = want_gradient || want_hessian;  // the Hessian needs the gradient
  const double psi = reducedTetElasticEnergy(
      elements_[size_t(e)].volume, materials_[size_t(e)], tet_gradients_.middleCols(begin, count),
      Z, derivatives ? &gradient : nullptr, want_hessian ? &hessian : nullptr, psd);
  return restSplitExcess(psi, Eigen::Map<const VecX>(Z.data(), m), K, w,
                         derivatives ? &gradient : nullptr, want_hessian ? &hessian : nullptr, psd,
                         nullptr, rest_floors_[e]);
}

VecX SoftTissue::restSplitFloors() const {
  // The sample tets' rest Hessians assembled in the subspace, without and with their weights.
  const int H = num_handles_, T = int(tets_.rows());
  MatX unit = MatX::Zero(3 * H, 3 * H), weighted = MatX::Zero(3 * H, 3 * H);
  VecX weights(T);
  for (int e = 0; e < T; ++e) {
    weights[e] = element_weight_[e];
    const int begin = tet_handle_start_[e], count = tet_handle_start_[e + 1] - begin;
    const Eigen::Map<const MatX> K(rest_hessians_.data() + rest_hessian_start_[e], 3 * count,
                                   3 * count);
    for (int s = 0; s < count; ++s)
      for (int r = 0; r < count; ++r) {
        const int a = tet_handles_[size_t(begin + s)], b = tet_handles_[size_t(begin + r)];
        unit.block<3, 3>(3 * a, 3 * b) += K.block<3, 3>(3 * s, 3 * r);
        weighted.block<3, 3>(3 * a, 3 * b) += weights[e] * K.block<3, 3>(3 * s, 3 * r);
      }
  }
  try {
    return flsh::restSplitFloors(rest_stiffness_, unit, weighted, weights);
  } catch (const InputError& error) {
    throw InputError(std::string("Simulable: the avatar's elastic cubature (ReducedData): ") +
                     error.what());
  }
}

double SoftTissue::restStiffnessTerm(VecX* g, Mat3* values, int offset) const {
  if (rest_stiffness_.size() == 0) return 0.0;
  // ½ zᵀ K z, K the exact rest stiffness of the subspace (positive definite).
  const VecX Kz = rest_stiffness_ * u;
  if (g) g->segment(offset + bone_dofs_, Kz.size()) += Kz;
  if (values)
    for (const auto& [a, b] : rest_stiffness_blocks_)
      if (a <= b)
        values[zz_slot_[size_t(a) * size_t(num_handles_) + size_t(b)]] +=
            rest_stiffness_.block<3, 3>(3 * a, 3 * b);
  return 0.5 * u.dot(Kz);
}

double SoftTissue::elasticReduced(VecX* g, std::vector<Mat3>* list, int offset, bool psd) const {
  const int T = int(tets_.rows());
  const int base = offset + bone_dofs_;
  const bool hessian = list != nullptr;
  double E = 0.0;
  const int threads = std::min(2, omp_get_max_threads());
  if (hessian || T < 256 || threads < 2 || omp_in_parallel()) {
    // The Hessian's block sums stay on one thread (Simulable runs them beside inertia's).
    E = elasticTets(0, T, g ? g->data() + base : nullptr, hessian ? list->data() : nullptr, psd);
  } else {
    // Energy or gradient alone: the tets in two halves, the second half's gradient apart.
    VecX second = g ? VecX::Zero(3 * num_handles_) : VecX();
    double energies[2] = {0.0, 0.0};
    onTwoThreads([&](int part) {
      energies[part] = part == 0
                           ? elasticTets(0, T / 2, g ? g->data() + base : nullptr, nullptr, psd)
                           : elasticTets(T / 2, T, g ? second.data() : nullptr, nullptr, psd);
    });
    E = energies[0] + energies[1];
    if (g) g->segment(base, second.size()) += second;
  }
  return E + restStiffnessTerm(g, hessian ? list->data() : nullptr, offset);
}

double SoftTissue::reducedGradient(const Vec3& gravity, VecX& g, int offset,
                                   const std::function<void(VecX&)>& potential_first) const {
  if (!reduced_) throw Error("SoftTissue::reducedGradient: the ROM only");
  const int T = int(tets_.rows());
  const int base = offset + bone_dofs_;
  const double k = 1.0 / (h_ * h_);
  const size_t count = mass_nodes_.size();
  const int split = int(kGradientTetsBesideInertia * T);
  node_forces_[0].resize(count);
  gradient_scratch_.setZero(g.size());
  double energies[2] = {0.0, 0.0};
  onTwoThreads([&](int part) {
    if (part == 0) {
      // ∂/∂x_j of inertia plus gravity: m_j ((x_j − x̂_j) / h² − g); their energies
      // m_j (‖x_j − x̂_j‖² / (2h²) − g · x_j).
      double E = 0.0;
      for (size_t idx = 0; idx < count; ++idx) {
        const int j = mass_nodes_[idx];
        const Vec3 x = x_.row(j).transpose(), d = x - x_hat_.row(j).transpose();
        E += inertia_mass_[j] * (0.5 * k * d.squaredNorm() - gravity.dot(x));
        node_forces_[0][idx] = inertia_mass_[j] * (k * d - gravity);
      }
      mapForces(mass_nodes_, node_forces_[0], g, offset);
      energies[0] = E + elasticTets(0, split, g.data() + base, nullptr, true);
    } else {
      if (potential_first) potential_first(gradient_scratch_);
      energies[1] = elasticTets(split, T, gradient_scratch_.data() + base, nullptr, true) +
                    restStiffnessTerm(&gradient_scratch_, nullptr, offset);
    }
  });
  g += gradient_scratch_;
  return energies[0] + energies[1];
}

void SoftTissue::reducedHessians(const Vec3& gravity, std::vector<Triplet>& H_dynamic,
                                 std::vector<Triplet>& H_potential, int offset, bool psd,
                                 const std::function<void()>& potential_first) const {
  if (!reduced_) throw Error("SoftTissue::reducedHessians: the ROM only");
  const int T = int(tets_.rows());
  mirrored_[0] = mirrored_[1] = false;
  onTwoThreads([&](int part) {
    beginReduced(part);
    if (part == 0) {
      inertiaHessianPart(0, H_dynamic, offset, psd);
    } else {
      if (potential_first) potential_first();
      Mat3* values = reduced_values_[1].data();
      reducedGravityHessian(gravity, H_potential, offset, psd);  // gravity()'s node loop unneeded
      elasticTets(0, T, nullptr, values, psd);
      restStiffnessTerm(nullptr, values, 0);
      inertiaHessianPart(1, H_potential, offset, psd);
    }
  });
  onTwoThreads([&](int list) { mirrorReduced(list, 0, 1); });
  mirrored_[0] = mirrored_[1] = true;
}

double SoftTissue::contact(const std::vector<Collider>& colliders, double time,
                           const ContactOptions& options, VecX* g, std::vector<Triplet>* H,
                           int offset, bool psd, int* active,
                           const std::vector<int>* candidates, bool skin) const {
  if (active) *active = 0;
  if (colliders.empty()) return 0.0;
  const std::vector<int>& list = candidates ? *candidates : surface_nodes_;
  if (list.empty()) return 0.0;
  if (reduced_ && skin) skinNodes(list);  // the ROM skins only the mass nodes in prepare()
  const int V = int(list.size());
  contact_x_.resize(V, 3);
  contact_areas_.resize(V);
  for (int k = 0; k < V; ++k) {
    contact_x_.row(k) = x_.row(list[k]);
    contact_areas_[k] = areas_[list[k]];
  }
  ContactOptions contact_options = options;
  contact_options.exact_hessian = !psd;
  VecX gradient = VecX::Zero(3 * V);
  std::vector<Triplet> node_hessian;
  std::vector<ContactPoint> points;
  const double E = colliderContactEnergy(contact_x_, contact_areas_, colliders, time,
                                         contact_options, &gradient,
                                         H ? &node_hessian : nullptr, 0, &points);
  if (active) *active = int(points.size());
  if (!g && !H) return E;
  // The touching vertices, their forces and (for H) their 3 × 3 blocks (p.vertex indexes list).
  std::vector<int> nodes;
  std::vector<Vec3> forces;
  std::vector<int> slot(V, -1);
  for (const ContactPoint& p : points)
    if (slot[p.vertex] < 0) {
      slot[p.vertex] = int(nodes.size());
      nodes.push_back(list[p.vertex]);
      forces.push_back(gradient.segment<3>(3 * p.vertex));
    }
  if (g) mapForces(nodes, forces, *g, offset);
  if (H) {
    std::vector<Mat3> K(nodes.size(), Mat3::Zero());
    for (const Triplet& t : node_hessian) {
      const int i = t.row() / 3;
      if (slot[i] >= 0) K[slot[i]](t.row() - 3 * i, t.col() - 3 * i) += t.value();
    }
    mapHessian(nodes, &K, &forces, *H, offset, psd, 1);
  }
  return E;
}

void SoftTissue::surfaceJacobian(std::vector<Triplet>& triplets) const {
  if (reduced_) skinNodes(surface_nodes_);
  const std::vector<Mat3>& R = *cur_R_;
  std::vector<std::pair<int, double>> basis;
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
    for (const auto& [dof, weight] : basis)
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c)
          triplets.emplace_back(3 * i + r, bone_dofs_ + dof + c, weight * node_M_[i](r, c));
  }
}

}  // namespace flsh::detail
