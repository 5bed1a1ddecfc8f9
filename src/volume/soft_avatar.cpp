// SoftAvatar: rest shape, bone inertias and capsules of one body shape (ARCHITECTURE.md §3–5).
//
// The skeleton model needs no tetrahedral mesh: its mass properties come from the closed rest
// surface filled with a uniform density (computeBoneInertia) and its collision proxies are one
// capsule per bone (fitBoneCapsules). The soft-tissue models (FEM, ROM) are not part of this
// version; asking for them is an error rather than a silent fallback to the skeleton.
#include "flsh/volume/soft_avatar.h"

#include <Eigen/Geometry>
#include <cmath>
#include <string>

#include "body/body_model_derived.h"
#include "flsh/body/body_forward.h"
#include "flsh/core/error.h"

namespace flsh {

namespace {

std::string modelName(const BodyModel& m) {
  return m.source.empty() ? std::string("body model") : "body model '" + m.source + "'";
}

}  // namespace

SoftAvatar::SoftAvatar(std::shared_ptr<const BodyModel> body, const VecX& betas,
                       const SoftAvatarSettings& settings)
    : body_(std::move(body)), settings_(settings) {
  const std::string fn = "SoftAvatar: ";
  if (!body_) throw InputError(fn + "body is null, expected a body model");
  if (!body_->derived || body_->derived->weight_start.size() != size_t(body_->numVertices()) + 1)
    throw InputError(fn + modelName(*body_) +
                     " is not finalized for its current arrays (call BodyModel::finalize())");
  const long K = body_->numBetas();
  if (betas.size() > K)
    throw InputError(fn + "betas has " + std::to_string(betas.size()) +
                     " values, expected at most " + std::to_string(K) +
                     " (the shape components of " + modelName(*body_) + ")");
  if (!betas.allFinite()) throw InputError(fn + "betas contains NaN or Inf");
  betas_ = VecX::Zero(K);
  betas_.head(betas.size()) = betas;
  if (!(settings_.density > 0) || !std::isfinite(settings_.density))
    throw InputError(fn + "settings.density = " + std::to_string(settings_.density) +
                     ", expected finite and > 0 kg/m³");
  if (!(settings_.voxel_size > 0) || !std::isfinite(settings_.voxel_size))
    throw InputError(fn + "settings.voxel_size = " + std::to_string(settings_.voxel_size) +
                     ", expected finite and > 0 m");
}

void SoftAvatar::initVolumetricData() {
  if (initialized_) return;
  // The reduced model and the cubatures refine the soft-tissue model; without soft tissue
  // they have nothing to act on and are ignored.
  if (soft_tissue_)
    throw Error(
        "SoftAvatar::initVolumetricData: soft tissue is enabled, but the FEM and ROM "
        "soft-tissue models are not available yet in this version of flsh (they come with the "
        "volumetric body); use the skeleton model (enableSoftTissue(false))");
  const BodyModel& body = *body_;
  MatX3 vertices = shapedVertices(body, betas_);
  MatX3 joints = MatX3(body.J_regressor * vertices);

  const MatX3i& F = body.faces;
  VecX areas = VecX::Zero(vertices.rows());
  double volume = 0;
  for (int f = 0; f < F.rows(); ++f) {
    const Vec3 a = vertices.row(F(f, 0)), b = vertices.row(F(f, 1)), c = vertices.row(F(f, 2));
    const double third_area = (b - a).cross(c - a).norm() / 6;
    for (int k = 0; k < 3; ++k) areas[F(f, k)] += third_area;
    volume += a.dot(b.cross(c)) / 6;  // divergence theorem: signed tetrahedron (0, a, b, c)
  }
  if (!(volume > 0))
    throw InputError("SoftAvatar::initVolumetricData: the rest surface of " + modelName(body) +
                     " encloses a volume of " + std::to_string(volume) +
                     " m³, expected > 0 (a closed surface with outward, counter-clockwise faces)");

  bone_inertia_ = computeBoneInertia(vertices, F, body.weights, joints, settings_.density,
                                     settings_.voxel_size);
  capsules_ = fitBoneCapsules(vertices, body.weights, joints, body.parents);
  rest_vertices_ = std::move(vertices);
  rest_joints_ = std::move(joints);
  vertex_areas_ = std::move(areas);
  volume_ = volume;
  initialized_ = true;
}

double SoftAvatar::totalMass() const {
  double mass = 0;
  for (const BoneInertia& bone : bone_inertia_) mass += bone.mass;
  return mass;
}

}  // namespace flsh
