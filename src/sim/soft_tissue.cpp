// Soft-tissue terms of the FEM soft skeleton; see soft_tissue.h for the formulas.
#include "soft_tissue.h"

#include "hessian_blocks.h"

#include <algorithm>
#include <cmath>
#include <exception>
#include <string>

#include "flsh/body/smpl_skeleton.h"
#include "flsh/core/error.h"
#include "flsh/core/rotation.h"
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
  soft_nodes_ = Eigen::Map<const VecXi>(soft.data(), Eigen::Index(soft.size()));
  u = u_n = u_nm1 = VecX::Zero(3 * soft_nodes_.size());

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

  // Elements: rest shapes, materials, lumped masses. Tets whose four nodes are bone nodes
  // never deform (u = 0 there) and are left out of the elastic sums.
  const MatX4i& all_tets = templ.mesh.tets;
  mass_ = VecX::Zero(n);
  std::vector<int> kept;
  for (int e = 0; e < all_tets.rows(); ++e) {
    Vec3 X[4];
    for (int a = 0; a < 4; ++a) X[a] = rest_.row(all_tets(e, a)).transpose();
    const double volume = std::abs((X[1] - X[0]).cross(X[2] - X[0]).dot(X[3] - X[0])) / 6.0;
    const double node_mass = data.materials.density[e] * volume / 4.0;
    for (int a = 0; a < 4; ++a) mass_[all_tets(e, a)] += node_mass;
    bool any_soft = false;
    for (int a = 0; a < 4; ++a) any_soft = any_soft || node_dof_[all_tets(e, a)] >= 0;
    if (any_soft) kept.push_back(e);
  }
  tets_.resize(Eigen::Index(kept.size()), 4);
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

  // Ordered soft-node pairs of the elastic Hessian.
  std::vector<std::pair<int, int>> pairs;
  for (Eigen::Index e = 0; e < tets_.rows(); ++e)
    for (int a = 0; a < 4; ++a)
      for (int b = 0; b < 4; ++b)
        if (node_dof_[tets_(e, a)] >= 0 && node_dof_[tets_(e, b)] >= 0)
          pairs.emplace_back(tets_(e, a), tets_(e, b));
  std::sort(pairs.begin(), pairs.end());
  pairs.erase(std::unique(pairs.begin(), pairs.end()), pairs.end());
  block_pairs_ = pairs;
  tet_block_.assign(16 * size_t(tets_.rows()), -1);
  for (Eigen::Index e = 0; e < tets_.rows(); ++e)
    for (int a = 0; a < 4; ++a)
      for (int b = 0; b < 4; ++b) {
        const std::pair<int, int> key(tets_(e, a), tets_(e, b));
        if (node_dof_[key.first] < 0 || node_dof_[key.second] < 0) continue;
        tet_block_[16 * e + 4 * a + b] =
            int(std::lower_bound(block_pairs_.begin(), block_pairs_.end(), key) -
                block_pairs_.begin());
      }

  areas_ = avatar.vertexAreas();
  x_hat_ = rest_;
  pair_blocks_.resize(num_bones_);
  all_nodes_.resize(n);
  for (int j = 0; j < n; ++j) all_nodes_[j] = j;
}

// ---- positions ----------------------------------------------------------------------------

void SoftTissue::setPoseBlend(const std::vector<Mat3>& R) {
  VecX feature(9 * (num_bones_ - 1));
  for (int b = 1; b < num_bones_; ++b) {
    const Mat3 local = R[parents_[b]].transpose() * R[b];
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) feature[9 * (b - 1) + 3 * r + c] = local(r, c) - (r == c);
  }
  const VecX offsets = (*posedirs_) * feature;  // row 3j + c
  blend_ = Eigen::Map<const MatX3>(offsets.data(), numNodes(), 3);
}

void SoftTissue::unposed(const VecX& displacement, MatX3& Y) const {
  const int n = numNodes();
  Y.resize(n, 3);
  for (int j = 0; j < n; ++j)
    Y.row(j) = rest_.row(j) + blend_.row(j) + nodeDisplacement(displacement, j).transpose();
}

void SoftTissue::positions(const BoneFrames& bones, const VecX& displacement, MatX3& x) const {
  const int n = numNodes();
  Vec3 shift[kNumJoints];
  for (int b = 0; b < num_bones_; ++b)
    shift[b] = bones.t.row(b).transpose() - bones.R[b] * joints_.row(b).transpose();
  x.resize(n, 3);
  for (int j = 0; j < n; ++j) {
    const Vec3 Y = (rest_.row(j) + blend_.row(j)).transpose() + nodeDisplacement(displacement, j);
    Vec3 p = Vec3::Zero();
    for (int k = influence_start_[j]; k < influence_start_[j + 1]; ++k) {
      const Influence& inf = influences_[k];
      p += inf.weight * (bones.R[inf.bone] * Y + shift[inf.bone]);
    }
    x.row(j) = p.transpose();
  }
}

void SoftTissue::setPrediction(const BoneFrames& bones_n, const BoneFrames& bones_nm1) {
  MatX3 x_n, x_nm1;
  positions(bones_n, u_n, x_n);
  positions(bones_nm1, u_nm1, x_nm1);
  x_hat_ = 2.0 * x_n - x_nm1;
}

void SoftTissue::prepare(long version, const BoneFrames& bones) const {
  cur_R_ = &bones.R;
  cur_t_ = &bones.t;
  if (version == version_) return;
  unposed(u, Y_);
  positions(bones, u, x_);
  const int n = numNodes();
  node_M_.resize(n);
  for (int j = 0; j < n; ++j) {
    Mat3 M = Mat3::Zero();
    for (int k = influence_start_[j]; k < influence_start_[j + 1]; ++k)
      M += influences_[k].weight * bones.R[influences_[k].bone];
    node_M_[j] = M;
  }
  version_ = version;
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
    if (node_dof_[j] >= 0)
      g.segment<3>(offset + bone_dofs_ + node_dof_[j]) += node_M_[j].transpose() * f;
  }
}

void SoftTissue::mapHessian(const std::vector<int>& nodes, const std::vector<Mat3>* K,
                            const std::vector<Vec3>* forces, std::vector<Triplet>& H, int offset,
                            bool psd) const {
  const std::vector<Mat3>& R = *cur_R_;
  auto block = [&](int b, int c) -> Mat6& { return pair_blocks_.block(b, c); };
  Mat3 curvature[kNumJoints];
  bool has_curvature[kNumJoints] = {};
  Eigen::Matrix<double, 3, 6> Jb[kNumJoints];
  Vec3 lever[kNumJoints];
  int bones[kNumJoints];
  for (size_t idx = 0; idx < nodes.size(); ++idx) {
    const int j = nodes[idx];
    const int dof = node_dof_[j];
    const int u_index = offset + bone_dofs_ + dof;
    const Vec3 Y = Y_.row(j).transpose();
    const int count = influence_start_[j + 1] - influence_start_[j];
    for (int a = 0; a < count; ++a) {
      const Influence& inf = influences_[influence_start_[j] + a];
      bones[a] = inf.bone;
      lever[a] = R[inf.bone] * (Y - joints_.row(inf.bone).transpose());
      Jb[a].leftCols<3>() = inf.weight * Mat3::Identity();
      Jb[a].rightCols<3>() = -inf.weight * skew(lever[a]);
    }
    if (K) {
      const Mat3& Kj = (*K)[idx];
      for (int a = 0; a < count; ++a) {
        const Eigen::Matrix<double, 6, 3> JaT_K = Jb[a].transpose() * Kj;
        for (int c = 0; c < count; ++c) block(bones[a], bones[c]).noalias() += JaT_K * Jb[c];
      }
      if (dof >= 0) {
        const Mat3 KM = Kj * node_M_[j];
        for (int a = 0; a < count; ++a) {
          const Eigen::Matrix<double, 6, 3> B = Jb[a].transpose() * KM;
          addBlock(H, offset + 6 * bones[a], u_index, B);
          addBlock(H, u_index, offset + 6 * bones[a], B.transpose());
        }
        addBlock(H, u_index, u_index, node_M_[j].transpose() * KM);
      }
    }
    if (forces) {
      const Vec3& f = (*forces)[idx];
      if (f.isZero(0.0)) continue;
      for (int a = 0; a < count; ++a) {
        const int b = bones[a];
        const double w = influences_[influence_start_[j] + a].weight;
        if (!has_curvature[b]) curvature[b].setZero();
        has_curvature[b] = true;
        curvature[b] += w * rotationCurvature(f, lever[a]);
        if (!psd && dof >= 0) {
          const Mat3 C = -w * skew(f) * R[b];  // ∂²(f·x)/∂δω_b∂δu_j
          addBlock(H, offset + 6 * b + 3, u_index, C);
          addBlock(H, u_index, offset + 6 * b + 3, C.transpose());
        }
      }
    }
  }
  for (int b = 0; b < num_bones_; ++b)
    if (has_curvature[b])
      block(b, b).bottomRightCorner<3, 3>() += psd ? projectToPSD<3>(curvature[b]) : curvature[b];
  pair_blocks_.emit(H, offset);
}

// ---- energies -------------------------------------------------------------------------------

double SoftTissue::inertia(VecX* g, std::vector<Triplet>* H, int offset, bool psd) const {
  const int n = numNodes();
  const double k = 1.0 / (h_ * h_);
  double E = 0.0;
  node_forces_.resize(n);
  for (int j = 0; j < n; ++j) {
    const Vec3 d = (x_.row(j) - x_hat_.row(j)).transpose();
    E += 0.5 * k * mass_[j] * d.squaredNorm();
    node_forces_[j] = k * mass_[j] * d;
  }
  if (g) mapForces(all_nodes_, node_forces_, *g, offset);
  if (H) {
    node_blocks_.resize(n);
    for (int j = 0; j < n; ++j) node_blocks_[j] = k * mass_[j] * Mat3::Identity();
    // psd: Gauss–Newton Σ m JᵀJ; exact: plus the curvature of the rotating nodes.
    mapHessian(all_nodes_, &node_blocks_, psd ? nullptr : &node_forces_, *H, offset, psd);
  }
  return E;
}

double SoftTissue::gravity(const Vec3& gravity, VecX* g, std::vector<Triplet>* H, int offset,
                           bool psd) const {
  const int n = numNodes();
  double E = 0.0;
  node_forces_.resize(n);
  for (int j = 0; j < n; ++j) {
    E -= mass_[j] * gravity.dot(x_.row(j).transpose());
    node_forces_[j] = -mass_[j] * gravity;
  }
  if (g) mapForces(all_nodes_, node_forces_, *g, offset);
  if (H) mapHessian(all_nodes_, nullptr, &node_forces_, *H, offset, psd);
  return E;
}

Eigen::Matrix<double, 3, 4> SoftTissue::elementDisplacement(int e) const {
  Eigen::Matrix<double, 3, 4> U;
  for (int a = 0; a < 4; ++a) U.col(a) = nodeDisplacement(u, tets_(e, a));
  return U;
}

double SoftTissue::elastic(VecX* g, std::vector<Triplet>* H, int offset, bool psd) const {
  const int T = int(tets_.rows());
  if (g) element_gradients_.resize(T);
  if (H) element_hessians_.resize(T);
  double E = 0.0;
  // An exception must not leave an OpenMP region: the first one is kept and rethrown.
  std::exception_ptr failure;
#pragma omp parallel for schedule(static) reduction(+ : E) if (T > 2000)
  for (int e = 0; e < T; ++e) {
    try {
      E += tetElasticEnergy(elements_[e], materials_[e], elementDisplacement(e),
                            g ? &element_gradients_[e] : nullptr,
                            H ? &element_hessians_[e] : nullptr, psd);
    } catch (...) {
#pragma omp critical(flsh_soft_tissue_failure)
      if (!failure) failure = std::current_exception();
    }
  }
  if (failure) std::rethrow_exception(failure);
  if (g) {
    for (int e = 0; e < T; ++e)
      for (int a = 0; a < 4; ++a) {
        const int dof = node_dof_[tets_(e, a)];
        if (dof >= 0)
          g->segment<3>(offset + bone_dofs_ + dof) += element_gradients_[e].segment<3>(3 * a);
      }
  }
  if (H) {
    blocks_.assign(block_pairs_.size(), Mat3::Zero());
    for (int e = 0; e < T; ++e) {
      const int* slots = &tet_block_[16 * size_t(e)];
      for (int a = 0; a < 4; ++a)
        for (int b = 0; b < 4; ++b)
          if (slots[4 * a + b] >= 0)
            blocks_[slots[4 * a + b]] += element_hessians_[e].block<3, 3>(3 * a, 3 * b);
    }
    const int base = offset + bone_dofs_;
    for (size_t k = 0; k < block_pairs_.size(); ++k)
      addBlock(*H, base + node_dof_[block_pairs_[k].first], base + node_dof_[block_pairs_[k].second],
               blocks_[k]);
  }
  return E;
}

double SoftTissue::contact(const std::vector<Collider>& colliders, double time,
                           const ContactOptions& options, VecX* g, std::vector<Triplet>* H,
                           int offset, bool psd, int* active) const {
  if (active) *active = 0;
  if (colliders.empty()) return 0.0;
  const int V = num_surface_;
  ContactOptions contact_options = options;
  contact_options.exact_hessian = !psd;
  VecX gradient = VecX::Zero(3 * V);
  std::vector<Triplet> node_hessian;
  std::vector<ContactPoint> points;
  const double E = colliderContactEnergy(x_.topRows(V), areas_, colliders, time, contact_options,
                                         &gradient, H ? &node_hessian : nullptr, 0, &points);
  if (active) *active = int(points.size());
  if (!g && !H) return E;
  // The touching vertices, their forces and (for H) their 3 × 3 blocks.
  std::vector<int> nodes;
  std::vector<Vec3> forces;
  std::vector<int> slot(V, -1);
  for (const ContactPoint& p : points)
    if (slot[p.vertex] < 0) {
      slot[p.vertex] = int(nodes.size());
      nodes.push_back(p.vertex);
      forces.push_back(gradient.segment<3>(3 * p.vertex));
    }
  if (g) mapForces(nodes, forces, *g, offset);
  if (H) {
    std::vector<Mat3> K(nodes.size(), Mat3::Zero());
    for (const Triplet& t : node_hessian) {
      const int i = t.row() / 3;
      if (slot[i] >= 0) K[slot[i]](t.row() - 3 * i, t.col() - 3 * i) += t.value();
    }
    mapHessian(nodes, &K, &forces, *H, offset, psd);
  }
  return E;
}

void SoftTissue::surfaceJacobian(std::vector<Triplet>& triplets) const {
  const std::vector<Mat3>& R = *cur_R_;
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
    if (node_dof_[i] >= 0)
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c)
          triplets.emplace_back(3 * i + r, bone_dofs_ + node_dof_[i] + c, node_M_[i](r, c));
  }
}

}  // namespace flsh::detail
