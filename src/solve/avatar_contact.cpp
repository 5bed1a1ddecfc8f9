// Avatar–avatar contact of a Scene: each avatar's surface vertices against the other avatars'
// bone capsules (Scene::avatarContactEnergy, scene.h), with a broad phase over vertex clusters.
#include "avatar_contact.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

#include "flsh/contact/contact_energy.h"
#include "flsh/core/error.h"
#include "flsh/core/rotation.h"

namespace flsh {

namespace {
// Vertices per broad-phase cluster: small enough to prune, large enough to amortize the test.
constexpr int kClusterSize = 24;
using Mat36 = Eigen::Matrix<double, 3, 6>;

/// ½(g pᵀ + p gᵀ) − (g·p) I: the Hessian of gᵀ exp([δ]×) p at δ = 0 (second-order rotation
/// term of a point p = R(X − J) rotated by a world-frame increment δ, contracted with g).
Mat3 rotationCurvature(const Vec3& g, const Vec3& p) {
  Mat3 M = 0.5 * (g * p.transpose() + p * g.transpose());
  M.diagonal().array() -= g.dot(p);
  return M;
}
}  // namespace

namespace {
/// Appends the dense block B at (row, col) as triplets.
template <class Derived>
void appendBlock(std::vector<Triplet>& H, int row, int col, const Eigen::MatrixBase<Derived>& B) {
  for (int c = 0; c < B.cols(); ++c)
    for (int r = 0; r < B.rows(); ++r) H.emplace_back(row + r, col + c, B(r, c));
}

/// Squared distance from x to the segment [a, b].
double segmentDistanceSquared(const Vec3& x, const Vec3& a, const Vec3& b) {
  const Vec3 ab = b - a;
  const double length2 = ab.squaredNorm();
  double t = length2 > 0.0 ? (x - a).dot(ab) / length2 : 0.0;
  t = std::min(1.0, std::max(0.0, t));
  return (x - a - t * ab).squaredNorm();
}
}  // namespace

// ---- avatar–avatar contact -------------------------------------------------------------------

Scene::AvatarContactData& Scene::contactData(int i) const {
  auto& slot = contact_data_[i];
  const Simulable& sim = *simulables_[i];
  const SoftAvatar& avatar = sim.avatar();
  const MatX3& X = avatar.restVertices();
  const MatX3& J = avatar.restJoints();
  if (!slot) {
    const MatX& W = avatar.body().weights;
    const int V = int(W.rows()), bones = int(W.cols());
    if (sim.numBoneDofs() != 6 * bones)
      throw Error("Scene::avatarContactEnergy: simulable " + std::to_string(i) + " has " +
                  std::to_string(sim.numBoneDofs()) +
                  " bone DoFs; avatar–avatar contact needs 6 per skinning bone (" +
                  std::to_string(6 * bones) + ")");
    if (X.rows() != V || avatar.vertexAreas().size() != V || J.rows() != bones)
      throw Error("Scene::avatarContactEnergy: simulable " + std::to_string(i) +
                  ": avatar rest vertices / areas / joints do not match the skinning weights " +
                  shapeString({long(V), long(bones)}) + " (is the avatar initialized?)");
    auto data = std::make_unique<AvatarContactData>();
    data->bones = bones;
    data->soft = sim.numDofs() > sim.numBoneDofs();
    if (data->soft) {
      data->soft_start.assign(1, 0);
      for (int v = 0; v < V; ++v) {
        for (const auto& [index, block] : sim.nodeDisplacementBasis(v)) {
          if (index < sim.numBoneDofs() || index + 3 > sim.numDofs())
            throw Error("Scene::avatarContactEnergy: simulable " + std::to_string(i) +
                        ": nodeDisplacementBasis(" + std::to_string(v) + ") names state index " +
                        std::to_string(index) + ", outside the soft-tissue DoFs [" +
                        std::to_string(sim.numBoneDofs()) + ", " + std::to_string(sim.numDofs()) +
                        ")");
          data->soft_basis.emplace_back(index, block);
        }
        data->soft_start.push_back(int(data->soft_basis.size()));
      }
    }
    data->skinned = SkinnedSurface::build(W, X, J, kClusterSize);
    const int clusters = int(data->skinned.clusters.size());
    data->group_center.assign(bones, Vec3::Zero());
    data->group_bound.assign(bones, 0.0);
    data->cluster_center.assign(clusters, Vec3::Zero());
    data->cluster_bound.assign(clusters, 0.0);
    data->cluster_posed.assign(clusters, 0);
    data->cluster_shift.assign(clusters, 0.0);
    data->group_shift.assign(bones, 0.0);
    data->rotation_gap.assign(bones * bones, 0.0);
    data->joint_gap.assign(bones * bones, 0.0);
    data->joint_gap_c.assign(bones * bones, 0.0);
    data->nodes.resize(V, 3);
    slot = std::move(data);
  }

  // Refresh the posed data when the bone transforms (or the unposed surface) changed since the
  // last call.
  AvatarContactData& data = *slot;
  const std::vector<Mat3>& R = sim.boneRotations();
  const MatX3& T = sim.bonePositions();
  bool same = data.valid && data.key_positions.rows() == T.rows() && data.key_positions == T;
  for (int b = 0; same && b < data.bones; ++b) same = data.key_rotations[b] == R[b];
  MatX3 surface;
  if (data.soft) {
    surface = sim.getUnposedSurface();
    if (surface.rows() != X.rows())
      throw Error("Scene::avatarContactEnergy: simulable " + std::to_string(i) +
                  ": getUnposedSurface() has " + std::to_string(surface.rows()) +
                  " rows, expected #V = " + std::to_string(X.rows()));
    same = same && surface.rows() == data.surface.rows() && surface == data.surface;
  }
  if (same) return data;

  data.key_rotations = R;
  data.key_positions = T;
  ++data.version;
  const int bones = data.bones;
  if (data.soft &&
      !(data.valid && surface.rows() == data.surface.rows() && surface == data.surface)) {
    data.surface = std::move(surface);
    for (size_t k = 0; k < data.skinned.clusters.size(); ++k) {
      double shift = 0.0;
      for (const int* p = data.skinned.clusterBegin(int(k)); p != data.skinned.clusterEnd(int(k));
           ++p) {
        const int v = *p;
        double weight_sum = 0.0;
        for (int w = data.skinned.weights.start[v]; w < data.skinned.weights.start[v + 1]; ++w)
          weight_sum += std::abs(data.skinned.weights.entries[w].weight);
        shift = std::max(shift, weight_sum * (data.surface.row(v) - X.row(v)).norm());
      }
      data.cluster_shift[k] = shift;
    }
    for (int b = 0; b < bones; ++b) {
      data.group_shift[b] = 0.0;
      for (int k = data.skinned.bone_clusters[b]; k < data.skinned.bone_clusters[b + 1]; ++k)
        data.group_shift[b] = std::max(data.group_shift[b], data.cluster_shift[k]);
    }
  }
  for (int b = 0; b < bones; ++b) {
    for (const auto& co : data.skinned.bone_bound[b].co) {
      const int c = co.bone;
      data.rotation_gap[b * bones + c] =
          std::sqrt(std::max(0.0, 3.0 - (R[b].transpose() * R[c]).trace()));  // ‖R_c − R_b‖₂
      const Vec3 joints = (J.row(b) - J.row(c)).transpose();
      const Vec3 shift = (T.row(c) - T.row(b)).transpose();
      data.joint_gap[b * bones + c] = (R[c] * joints + shift).norm();
      data.joint_gap_c[b * bones + c] = (R[b] * joints + shift).norm();
    }
  }
  const auto posedBound = [&](int b, const SurfaceBound& rest, Vec3& center, double& bound) {
    double margin = 0.0;
    for (const auto& co : rest.co) {
      const int pair = b * bones + co.bone;
      margin += co.weight * std::min(data.rotation_gap[pair] * rest.extent + data.joint_gap[pair],
                                     data.rotation_gap[pair] * co.extent + data.joint_gap_c[pair]);
    }
    center = R[b] * rest.center + T.row(b).transpose();
    bound = rest.radius + margin;
  };
  for (int b = 0; b < bones; ++b) {
    posedBound(b, data.skinned.bone_bound[b], data.group_center[b], data.group_bound[b]);
    data.group_bound[b] += data.group_shift[b];
  }
  for (size_t k = 0; k < data.skinned.clusters.size(); ++k) {
    posedBound(data.skinned.clusters[k].bone, data.skinned.clusters[k].bound,
               data.cluster_center[k], data.cluster_bound[k]);
    data.cluster_bound[k] += data.cluster_shift[k];
    data.cluster_posed[k] = 0;
  }
  data.capsules.clear();
  for (const BoneCapsule& c : avatar.boneCapsules()) {
    if (!(c.radius > 0.0)) continue;  // bones that dominate no vertex have no capsule
    AvatarContactData::PosedCapsule p;
    p.bone = c.bone;
    const Vec3 joint = J.row(c.bone).transpose();
    const Vec3 t = T.row(c.bone).transpose();
    p.a_rotated = R[c.bone] * (c.a - joint);
    p.b_rotated = R[c.bone] * (c.b - joint);
    p.a = p.a_rotated + t;
    p.b = p.b_rotated + t;
    p.radius = c.radius;
    p.center = 0.5 * (p.a + p.b);
    p.bound = 0.5 * (p.a - p.b).norm() + c.radius;
    data.capsules.push_back(p);
  }
  data.valid = true;
  return data;
}

void Scene::poseCluster(int i, int cluster) const {
  AvatarContactData& data = *contact_data_[i];
  if (data.cluster_posed[cluster]) return;
  const Simulable& sim = *simulables_[i];
  const MatX3& Y = data.soft ? data.surface : sim.avatar().restVertices();
  const MatX3& J = sim.avatar().restJoints();
  const std::vector<Mat3>& R = sim.boneRotations();
  const MatX3& T = sim.bonePositions();
  for (const int* p = data.skinned.clusterBegin(cluster); p != data.skinned.clusterEnd(cluster);
       ++p) {
    const int v = *p;
    const Vec3 Yv = Y.row(v).transpose();
    Vec3 x = Vec3::Zero();
    for (int w = data.skinned.weights.start[v]; w < data.skinned.weights.start[v + 1]; ++w) {
      const int b = data.skinned.weights.entries[w].bone;
      x += data.skinned.weights.entries[w].weight *
           (R[b] * (Yv - J.row(b).transpose()) + T.row(b).transpose());
    }
    data.nodes.row(v) = x.transpose();
  }
  data.cluster_posed[cluster] = 1;
}

double Scene::avatarContactEnergy(VecX* g, std::vector<Triplet>* H, bool psd, int* active) const {
  int contacts = 0;
  double energy = 0.0;
  if (g && g->size() != num_dofs_)
    throw InputError("Scene::avatarContactEnergy: g must have numDofs() = " +
                     std::to_string(num_dofs_) + " entries, got " + std::to_string(g->size()));
  ContactOptions contact_options = options_.avatar_contact_options;
  contact_options.exact_hessian = !psd;
  const double stiffness = contact_options.stiffness;
  const int n_sim = int(simulables_.size());
  // Refresh every posed cache once; the cached contact pairs stay valid while no avatar moved.
  bool pairs_valid = int(contact_pairs_versions_.size()) == n_sim &&
                     contact_pairs_.size() == size_t(n_sim) * n_sim;
  contact_pairs_versions_.resize(n_sim, -1);
  contact_pairs_.resize(size_t(n_sim) * n_sim);
  for (int i = 0; i < n_sim; ++i) {
    const long version = contactData(i).version;
    pairs_valid = pairs_valid && contact_pairs_versions_[i] == version;
    contact_pairs_versions_[i] = version;
  }

  Vec9 grad9;
  Mat9 hess9;
  std::vector<Mat36> P;  // ∂x/∂(t_k, δω_k) per weight of the vertex
  std::vector<Mat36> HxxP;
  std::vector<Mat36> Huk;       // ∂²E/∂u∂(t_k, δω_k) per weight (soft vertices)
  std::vector<Vec3> p_rotated;  // R_k (X − J_k) per weight of the vertex
  for (int ia = 0; ia < n_sim; ++ia) {
    AvatarContactData& A = *contact_data_[ia];
    const Simulable& simA = *simulables_[ia];
    const SoftAvatar& avatarA = simA.avatar();
    const MatX3& YA = A.soft ? A.surface : avatarA.restVertices();
    const MatX3& JA = avatarA.restJoints();
    const VecX& areas = avatarA.vertexAreas();
    const std::vector<Mat3>& RA = simA.boneRotations();
    for (int ib = 0; ib < n_sim; ++ib) {
      if (ib == ia) continue;
      const AvatarContactData& B = *contact_data_[ib];
      if (H) blocks_->reset(A.bones + B.bones);
      // Broad phase once per state: the (capsule, vertex) pairs in contact are kept while
      // neither avatar moved (energy, gradient and Hessian at one state share them).
      std::vector<std::pair<int, int>>& pairs = contact_pairs_[ia * n_sim + ib];
      if (!pairs_valid) {
        pairs.clear();
        for (int ci = 0; ci < int(B.capsules.size()); ++ci) {
          const auto& cap = B.capsules[ci];
          const double bound2 = cap.bound * cap.bound, radius2 = cap.radius * cap.radius;
          for (int bone = 0; bone < A.bones; ++bone) {
            if (A.skinned.bone_clusters[bone] == A.skinned.bone_clusters[bone + 1] ||
                (A.group_center[bone] - cap.center).norm() > A.group_bound[bone] + cap.bound)
              continue;
            for (int cluster = A.skinned.bone_clusters[bone];
                 cluster < A.skinned.bone_clusters[bone + 1]; ++cluster) {
              const double reach = A.cluster_bound[cluster] + cap.radius;
              if (segmentDistanceSquared(A.cluster_center[cluster], cap.a, cap.b) > reach * reach)
                continue;
              poseCluster(ia, cluster);
              for (const int* p = A.skinned.clusterBegin(cluster);
                   p != A.skinned.clusterEnd(cluster); ++p) {
                const int v = *p;
                const Vec3 x = A.nodes.row(v).transpose();
                if ((x - cap.center).squaredNorm() > bound2) continue;
                if (segmentDistanceSquared(x, cap.a, cap.b) >= radius2) continue;
                pairs.emplace_back(ci, v);
              }
            }
          }
        }
      }
      for (const auto& [ci, v] : pairs) {
        const auto& cap = B.capsules[ci];
        const Vec3 x = A.nodes.row(v).transpose();
        ++contacts;
        const bool derivatives = g || H;
        energy +=
            vertexCapsulePenalty(x, cap.a, cap.b, cap.radius, stiffness * areas[v], contact_options,
                                 derivatives ? &grad9 : nullptr, H ? &hess9 : nullptr);
        if (!derivatives) continue;

        // Chain rule through x = Σ_k w_k (R_k (Y − J_k) + t_k) (+ u: ∂x/∂u = M = Σ_k w_k R_k)
        // and a' = R_b (a − J_b) + t_b.
        const int w_begin = A.skinned.weights.start[v], w_end = A.skinned.weights.start[v + 1];
        const int nw = w_end - w_begin;
        const int s_begin = A.soft ? A.soft_start[v] : 0;
        const int s_end = A.soft ? A.soft_start[v + 1] : 0;
        const bool has_u = s_end > s_begin;
        p_rotated.resize(nw);
        Mat3 M = Mat3::Zero();
        for (int w = 0; w < nw; ++w) {
          const int bone = A.skinned.weights.entries[w_begin + w].bone;
          p_rotated[w] = RA[bone] * (YA.row(v) - JA.row(bone)).transpose();
          if (has_u) M += A.skinned.weights.entries[w_begin + w].weight * RA[bone];
        }
        const Vec3 gx = grad9.segment<3>(0), ga = grad9.segment<3>(3), gb = grad9.segment<3>(6);
        if (g) {
          for (int w = 0; w < nw; ++w) {
            const int dof = offsets_[ia] + 6 * A.skinned.weights.entries[w_begin + w].bone;
            const double weight = A.skinned.weights.entries[w_begin + w].weight;
            g->segment<3>(dof) += weight * gx;
            g->segment<3>(dof + 3) += weight * p_rotated[w].cross(gx);
          }
          const int dof = offsets_[ib] + 6 * cap.bone;
          g->segment<3>(dof) += ga + gb;
          g->segment<3>(dof + 3) += cap.a_rotated.cross(ga) + cap.b_rotated.cross(gb);
          if (has_u) {
            const Vec3 gu = M.transpose() * gx;
            for (int k = s_begin; k < s_end; ++k)
              g->segment<3>(offsets_[ia] + A.soft_basis[k].first).noalias() +=
                  A.soft_basis[k].second.transpose() * gu;
          }
        }
        if (!H) continue;
        P.resize(nw);
        HxxP.resize(nw);
        const Mat3 Hxx = hess9.block<3, 3>(0, 0);
        for (int w = 0; w < nw; ++w) {
          const double weight = A.skinned.weights.entries[w_begin + w].weight;
          P[w].leftCols<3>() = weight * Mat3::Identity();
          P[w].rightCols<3>() = -weight * skew(p_rotated[w]);
          HxxP[w] = Hxx * P[w];
        }
        Mat6 Q;  // ∂(a', b')/∂(t_b, δω_b)
        Q << Mat3::Identity(), -skew(cap.a_rotated), Mat3::Identity(), -skew(cap.b_rotated);
        const Mat36 HxyQ = hess9.block<3, 6>(0, 3) * Q;
        const int bone_b = A.bones + cap.bone;  // local index in the accumulator
        Mat6& Bbb = blocks_->at(bone_b, bone_b);
        Bbb.noalias() += Q.transpose() * hess9.block<6, 6>(3, 3) * Q;
        if (!psd) {
          Bbb.bottomRightCorner<3, 3>() +=
              rotationCurvature(ga, cap.a_rotated) + rotationCurvature(gb, cap.b_rotated);
        }
        for (int w = 0; w < nw; ++w) {
          const int bone_k = A.skinned.weights.entries[w_begin + w].bone;
          for (int u = 0; u < nw; ++u)
            blocks_->at(bone_k, A.skinned.weights.entries[w_begin + u].bone).noalias() +=
                P[w].transpose() * HxxP[u];
          const Mat6 cross = P[w].transpose() * HxyQ;
          blocks_->at(bone_k, bone_b) += cross;
          blocks_->at(bone_b, bone_k) += cross.transpose();
          if (!psd)
            blocks_->at(bone_k, bone_k).bottomRightCorner<3, 3>() +=
                A.skinned.weights.entries[w_begin + w].weight * rotationCurvature(gx, p_rotated[w]);
        }
        if (has_u) {
          // u rows: Mᵀ Hxx M with itself, Mᵀ Hxx P_k with A's bones (plus, exact, the term of
          // x's change w_k [δω_k]× R_k δu: ∂²E/∂u∂δω_k = w_k R_kᵀ [gx]×), Mᵀ Hxy Q with B's bone;
          // then through u = Σ w q_index to the state entries.
          const Mat3 MtH = M.transpose() * Hxx;
          const Mat3 Huu = MtH * M;
          const Mat36 HuB = M.transpose() * HxyQ;
          Huk.resize(nw);
          for (int w = 0; w < nw; ++w) {
            const int bone_k = A.skinned.weights.entries[w_begin + w].bone;
            Huk[w] = MtH * P[w];
            if (!psd)
              Huk[w].rightCols<3>() +=
                  A.skinned.weights.entries[w_begin + w].weight * RA[bone_k].transpose() * skew(gx);
          }
          for (int k = s_begin; k < s_end; ++k) {
            const int du = offsets_[ia] + A.soft_basis[k].first;
            const Mat3 Bk_t = A.soft_basis[k].second.transpose();
            const Mat3 Bk_t_Huu = Bk_t * Huu;
            for (int l = s_begin; l < s_end; ++l)
              appendBlock(*H, du, offsets_[ia] + A.soft_basis[l].first,
                          Mat3(Bk_t_Huu * A.soft_basis[l].second));
            for (int w = 0; w < nw; ++w) {
              const int bone_k = A.skinned.weights.entries[w_begin + w].bone;
              const Mat36 block = Bk_t * Huk[w];
              appendBlock(*H, du, offsets_[ia] + 6 * bone_k, block);
              appendBlock(*H, offsets_[ia] + 6 * bone_k, du, block.transpose());
            }
            const Mat36 block = Bk_t * HuB;
            appendBlock(*H, du, offsets_[ib] + 6 * cap.bone, block);
            appendBlock(*H, offsets_[ib] + 6 * cap.bone, du, block.transpose());
          }
        }
      }
      if (H) {
        const int off_a = offsets_[ia], off_b = offsets_[ib], bones_a = A.bones;
        blocks_->flush(
            [&](int local) {
              return local < bones_a ? off_a + 6 * local : off_b + 6 * (local - bones_a);
            },
            *H);
      }
    }
  }
  avatar_contacts_ = contacts;
  if (active) *active = contacts;
  return energy;
}

}  // namespace flsh
