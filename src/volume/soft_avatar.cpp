// SoftAvatar: rest shape, bone inertias and capsules of one body shape (ARCHITECTURE.md §3–5).
//
// The skeleton model needs no tetrahedral mesh: its mass properties come from the closed rest
// surface filled with a uniform density (computeBoneInertia) and its collision proxies are one
// capsule per bone (fitBoneCapsules). With soft tissue the volumetric body is built on top
// (volumetric_data.h), and for the reduced model (ROM) its handles, basis and cubatures
// (reduced_data.h).
#include "flsh/volume/soft_avatar.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <mutex>
#include <string>
#include <tuple>
#include <vector>

#include "flsh/body/body_forward.h"
#include "flsh/body/model_finalized.h"
#include "flsh/core/error.h"
#include "flsh/core/sha256.h"
#include "flsh/volume/tet_material_map.h"
#include "volume/reduced_data_file.h"

namespace flsh {

namespace {

// Template mass moments shared by the avatars of one body model (same density and voxel size):
// entries stay while their body model is alive, so a second β never re-voxelizes.
std::shared_ptr<const VertexMassMoments> sharedTemplateMoments(
    const std::shared_ptr<const BodyModel>& body, const MatX3& template_vertices, double density,
    double voxel_size) {
  struct Entry {
    std::weak_ptr<const BodyModel> body;
    double density, voxel_size;
    std::shared_ptr<const VertexMassMoments> moments;
  };
  static std::mutex mutex;
  static std::vector<Entry> cache;
  std::lock_guard<std::mutex> lock(mutex);
  cache.erase(
      std::remove_if(cache.begin(), cache.end(), [](const Entry& e) { return e.body.expired(); }),
      cache.end());
  for (const Entry& e : cache)
    if (e.body.lock() == body && e.density == density && e.voxel_size == voxel_size)
      return e.moments;
  auto moments = std::make_shared<const VertexMassMoments>(
      computeVertexMassMoments(template_vertices, body->faces, density, voxel_size));
  cache.push_back({body, density, voxel_size, moments});
  return moments;
}

// Enclosed volume of a closed surface (divergence theorem: signed tetrahedra (0, a, b, c)).
double enclosedVolume(const MatX3& V, const MatX3i& F) {
  double volume = 0;
  for (int f = 0; f < F.rows(); ++f)
    volume += Vec3(V.row(F(f, 0))).dot(Vec3(V.row(F(f, 1))).cross(Vec3(V.row(F(f, 2))))) / 6;
  return volume;
}

}  // namespace

SoftAvatar::SoftAvatar(std::shared_ptr<const BodyModel> body, const VecX& betas,
                       const SoftAvatarSettings& settings)
    : body_(std::move(body)), settings_(settings) {
  const std::string fn = "SoftAvatar: ";
  if (!body_) throw InputError(fn + "body is null, expected a body model");
  requireFinalized(*body_, "SoftAvatar");
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
  derived_.forget();
  // The reduced model is a soft-tissue model: without soft tissue there is nothing to reduce,
  // and silently simulating the skeleton instead would hide the mistake. The cubatures refine
  // the reduced model; without it they have nothing to act on and are ignored.
  if (reduced_ && !soft_tissue_)
    throw InputError(
        "SoftAvatar::initVolumetricData: the reduced model is enabled but soft tissue is off; "
        "the reduced model (ROM soft skeleton) is a soft-tissue model: call enableSoftTissue() "
        "too, or enableReducedModel(false) for the skeleton");
  const auto start = std::chrono::steady_clock::now();
  buildRestShape();
  skeleton_seconds_ =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  const BodyModel& body = *body_;
  // Built into locals first: a failing reduced build leaves no half-built avatar behind.
  std::shared_ptr<const VolumetricData> volumetric;
  VolumetricBuildReport volumetric_report;
  std::shared_ptr<const ReducedData> reduced_data;
  ReducedBuildReport reduced_report;
  if (soft_tissue_)
    volumetric = std::make_shared<const VolumetricData>(
        buildVolumetricData(body, betas_, settings_.volumetric, &volumetric_report));
  if (soft_tissue_ && reduced_) {
    std::unique_ptr<AvatarCache> cache;
    if (settings_.volumetric.use_cache)
      cache = std::make_unique<AvatarCache>(settings_.volumetric.cache_dir);
    ReducedData rom = buildReducedData(*volumetric, body, settings_.reduced, elastic_cubature_,
                                       inertial_cubature_, cache.get(), &reduced_report);
    rom.elastic_floors = elasticCubatureFloors(*volumetric, rom);
    reduced_data = std::make_shared<const ReducedData>(std::move(rom));
  }
  volumetric_ = std::move(volumetric);
  build_report_ = std::move(volumetric_report);
  reduced_data_ = std::move(reduced_data);
  reduced_report_ = std::move(reduced_report);
  initialized_ = true;
}

// The rest data of betas_ that every model needs: shaped surface, joints, areas, volume, bone
// inertias (the template's moments carried by the shaped vertices), capsules and their
// β-derivatives.
void SoftAvatar::buildRestShape() {
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

  // Bone inertia: the template's voxel moments carried by the shaped vertices, masses scaled
  // to the shaped volume (see soft_avatar.h: smooth in β, for the adjoint).
  const long K = body.numBetas();
  const MatX3 template_vertices = shapedVertices(body, VecX::Zero(K));
  template_volume_ = enclosedVolume(template_vertices, F);
  if (!(template_volume_ > 0))
    throw InputError("SoftAvatar::initVolumetricData: the template surface of " + modelName(body) +
                     " encloses a volume of " + std::to_string(template_volume_) +
                     " m³, expected > 0");
  template_moments_ =
      sharedTemplateMoments(body_, template_vertices, settings_.density, settings_.voxel_size);
  const double mass_scale = volume / template_volume_;
  bone_inertia_ = lumpBoneInertia(*template_moments_, vertices, body.weights, joints, mass_scale);
  capsules_ = fitBoneCapsules(vertices, body.weights, joints, body.parents);
  buildShapeJacobians(vertices, joints, mass_scale);
  rest_vertices_ = std::move(vertices);
  rest_joints_ = std::move(joints);
  vertex_areas_ = std::move(areas);
  volume_ = volume;
}

void SoftAvatar::setReducedData(std::shared_ptr<const ReducedData> data) {
  const std::string fn = "SoftAvatar::setReducedData: ";
  derived_.forget();
  if (!initialized_ || !soft_tissue_ || !reduced_)
    throw Error(fn +
                "call it after initVolumetricData() on an avatar with enableSoftTissue() "
                "and enableReducedModel()");
  if (!data) throw InputError(fn + "data is null");
  const VolumetricData& vol = *volumetric_;
  const int n = vol.numNodes(), T = vol.numTets(), H = data->numHandles();
  const bool modes = data->basis_kind != ReducedBasisKind::Handles;
  const bool handles = data->basis_kind != ReducedBasisKind::Modes;
  if (handles && H < 1) throw InputError(fn + "handles is empty, expected at least one handle");
  if (!handles && H > 0)
    throw InputError(fn + "handles has " + std::to_string(H) +
                     " entries for the basis kind 'modes', expected none");
  const MatX& Psi = data->modes;
  if (modes) detail::checkModes(vol, Psi, fn + "modes");
  if (!modes && Psi.size() > 0)
    throw InputError(fn + "modes is " + std::to_string(Psi.rows()) + " × " +
                     std::to_string(Psi.cols()) + " for the basis kind 'handles', expected empty");
  if (data->basis.rows() != n || data->basis.cols() != H)
    throw InputError(fn + "basis is " + std::to_string(data->basis.rows()) + " × " +
                     std::to_string(data->basis.cols()) + ", expected #nodes × #handles = " +
                     std::to_string(n) + " × " + std::to_string(H));
  std::vector<char> seen(n, 0);
  for (int h = 0; h < H; ++h) {
    const int j = data->handles[h];
    if (j < 0 || j >= n || vol.bone_of_node[j] >= 0 || seen[j])
      throw InputError(fn + "handles[" + std::to_string(h) + "] = " + std::to_string(j) +
                       " is out of [0, " + std::to_string(n) +
                       "), a bone node or repeated; expected distinct soft-tissue nodes");
    seen[j] = 1;
  }
  for (int h = 0; h < H; ++h)
    for (SpMat::InnerIterator it(data->basis, h); it; ++it)
      if (!(it.value() >= 0.0 && it.value() <= 1.0) || vol.bone_of_node[it.row()] >= 0)
        throw InputError(fn + "basis(" + std::to_string(it.row()) + ", " + std::to_string(h) +
                         ") = " + std::to_string(it.value()) +
                         ": expected a value in [0, 1], and none on bone nodes");
  auto checkCubature = [&](const Cubature& c, const char* name) {
    if (c.elements.size() != c.weights.size())
      throw InputError(fn + name + ": " + std::to_string(c.elements.size()) + " elements but " +
                       std::to_string(c.weights.size()) + " weights");
    for (Eigen::Index k = 0; k < c.elements.size(); ++k)
      if (c.elements[k] < 0 || c.elements[k] >= T || !(c.weights[k] > 0.0) ||
          !std::isfinite(c.weights[k]))
        throw InputError(fn + name + ": element " + std::to_string(k) + " (tet " +
                         std::to_string(c.elements[k]) + ", weight " +
                         std::to_string(c.weights[k]) + "): expected a tet in [0, " +
                         std::to_string(T) + ") and a finite weight > 0");
  };
  checkCubature(data->elastic, "elastic");
  checkCubature(data->inertial, "inertial");
  const MatX& C = data->elastic_rest_stiffness;
  const int m = data->numSoftDofs();
  if (C.size() > 0 && (C.rows() != m || C.cols() != m || !C.allFinite()))
    throw InputError(fn + "elastic_rest_stiffness is " + std::to_string(C.rows()) + " × " +
                     std::to_string(C.cols()) + (C.allFinite() ? "" : " with NaN or Inf") +
                     ", expected empty or (3·#handles + #modes) square = " + std::to_string(m) +
                     " × " + std::to_string(m) + " finite");
  if (data->elastic_floors.size() > 0 &&
      data->elastic_floors.size() != data->elastic.elements.size())
    throw InputError(fn + "elastic_floors has " + std::to_string(data->elastic_floors.size()) +
                     " entries, expected empty or one per elastic cubature sample (" +
                     std::to_string(data->elastic.elements.size()) + ")");
  if (data->elastic_floors.size() == 0 && data->elastic.elements.size() > 0 && C.size() > 0) {
    auto filled = std::make_shared<ReducedData>(*data);
    filled->elastic_floors = elasticCubatureFloors(vol, *filled);
    data = std::move(filled);
  }
  reduced_data_ = std::move(data);
}

// The same discretization (tet mesh, rest nodes, bone nodes, frames, reduced basis, cubature
// samples, weights and floors) with the materials of `model` at this β: the per-tet map
// (tet_material_map.h) re-evaluated and, for the ROM, the subspace's exact rest stiffness K.
std::shared_ptr<SoftAvatar> SoftAvatar::withMaterial(const MaterialModel& model) const {
  const std::string fn = "SoftAvatar::withMaterial: ";
  if (!initialized_ || !volumetric_)
    throw Error(fn +
                "the avatar has no volumetric body (enableSoftTissue() and "
                "initVolumetricData() first)");
  if (model.numBetas() != betas_.size())
    throw InputError(fn + "the material model is for " + std::to_string(model.numBetas()) +
                     " shape components, expected " + std::to_string(betas_.size()) +
                     " (the body's)");
  model.validate("SoftAvatar::withMaterial: material", betas_);
  auto out = std::make_shared<SoftAvatar>(*this);
  auto data = std::make_shared<VolumetricData>(*volumetric_);
  const TetMaterialMap map(tetMaterialGeometry(*volumetric_), model.coefficientValues(betas_));
  data->materials = map.materials();
  data->material_model = model;
  const std::string text = model.canonicalText();
  Sha256 h;
  h.update(volumetric_->key);
  h.updateField("materials", text.data(), text.size());
  data->key = h.hexDigest();
  if (reduced_data_) out->reduced_data_ = reducedDataFor(*data);
  out->volumetric_ = std::move(data);
  return out;
}

std::shared_ptr<const ReducedData> SoftAvatar::reducedDataFor(const VolumetricData& data) const {
  auto rom = std::make_shared<ReducedData>(*reduced_data_);
  if (rom->elastic_rest_stiffness.size() > 0)
    rom->elastic_rest_stiffness = elasticRestStiffness(data, *rom);
  Sha256 k;
  k.update(reduced_data_->key);
  k.update(data.key);
  rom->key = k.hexDigest();
  return rom;
}

// The same discretization at β′ (see the header): the skeleton's rest data rebuilt, the
// volumetric body's rest nodes and materials re-evaluated on the kept tet mesh, bone nodes and
// frames.
std::shared_ptr<SoftAvatar> SoftAvatar::withShape(const VecX& betas) const {
  const std::string fn = "SoftAvatar::withShape: ";
  if (!initialized_) throw Error(fn + "call initVolumetricData() first");
  auto out = std::make_shared<SoftAvatar>(body_, betas, settings_);
  out->soft_tissue_ = soft_tissue_;
  out->reduced_ = reduced_;
  out->inertial_cubature_ = inertial_cubature_;
  out->elastic_cubature_ = elastic_cubature_;
  out->buildRestShape();
  out->initialized_ = true;
  if (!volumetric_) return out;
  const VolumetricTemplate& templ = *volumetric_->templ;
  const MaterialModel& model = volumetric_->material_model;
  model.validate("SoftAvatar::withShape: material", out->betas_);
  auto data = std::make_shared<VolumetricData>(*volumetric_);
  data->rest_nodes = shapedNodes(templ.mesh, templ.fields, out->betas_);
  data->rest_joints = out->rest_joints_;
  const TetMaterialMap map(tetMaterialGeometry(templ.mesh, data->rest_nodes, templ.fields.weights,
                                               volumetric_->materials.frame),
                           model.coefficientValues(out->betas_));
  data->materials = map.materials();
  Sha256 h;
  h.update(volumetric_->key);
  h.updateField("betas", out->betas_.data(), size_t(out->betas_.size()) * sizeof(double));
  data->key = h.hexDigest();
  if (reduced_data_) out->reduced_data_ = reducedDataFor(*data);
  out->volumetric_ = std::move(data);
  return out;
}

const ReducedData& SoftAvatar::reducedData() const {
  if (!reduced_data_)
    throw Error(std::string("SoftAvatar::reducedData: ") +
                (soft_tissue_ && reduced_
                     ? "call initVolumetricData() first"
                     : "this avatar has no reduced data (the reduced model is off: "
                       "enableSoftTissue() and enableReducedModel() before "
                       "initVolumetricData())"));
  return *reduced_data_;
}

const VolumetricData& SoftAvatar::volumetricData() const {
  if (!volumetric_)
    throw Error(std::string("SoftAvatar::volumetricData: ") +
                (soft_tissue_ ? "call initVolumetricData() first"
                              : "this avatar has no volumetric body (soft tissue is off: "
                                "enableSoftTissue() before initVolumetricData())"));
  return *volumetric_;
}

// Exact β-derivatives of the rest data (all polynomials in β): joints J = J_regressor X(β),
// areas and volume of the shaped surface, and the bone inertias of lumpBoneInertia with
// dX_i/dβ = shapedirs_i and the mass scale s = vol(β)/vol(0).
void SoftAvatar::buildShapeJacobians(const MatX3& X, const MatX3& J, double mass_scale) {
  const BodyModel& body = *body_;
  const MatX& S = body.shapedirs;  // 3#V × K
  const long K = S.cols(), nv = X.rows(), nb = J.rows();
  const MatX3i& F = body.faces;
  joints_shape_jacobian_ = MatX::Zero(3 * nb, K);
  for (int b = 0; b < nb; ++b)
    for (SpMatR::InnerIterator it(body.J_regressor, b); it; ++it)
      joints_shape_jacobian_.middleRows<3>(3 * b) += it.value() * S.middleRows<3>(3 * it.col());
  areas_shape_jacobian_ = MatX::Zero(nv, K);
  volume_shape_gradient_ = VecX::Zero(K);
  for (int f = 0; f < F.rows(); ++f) {
    const int ia = F(f, 0), ib = F(f, 1), ic = F(f, 2);
    const Vec3 a = X.row(ia), b = X.row(ib), c = X.row(ic);
    const Vec3 n = (b - a).cross(c - a);
    const double length = n.norm();
    const auto Sa = S.middleRows<3>(3 * ia), Sb = S.middleRows<3>(3 * ib),
               Sc = S.middleRows<3>(3 * ic);
    // Area = |n|/6 per vertex, with ∂|n|/∂a = n̂ × (c − b) (and cyclically for b, c).
    if (length > 0) {
      const Vec3 nh = n / length;
      const Eigen::RowVectorXd dlength = (nh.cross(c - b)).transpose() * Sa +
                                         (nh.cross(a - c)).transpose() * Sb +
                                         (nh.cross(b - a)).transpose() * Sc;
      for (int k = 0; k < 3; ++k) areas_shape_jacobian_.row(F(f, k)) += dlength / 6;
    }
    volume_shape_gradient_ += ((b.cross(c)).transpose() * Sa + (c.cross(a)).transpose() * Sb +
                               (a.cross(b)).transpose() * Sc)
                                  .transpose() /
                              6;
  }
  // Bone inertias: unscaled sums U (mass, first, second) and their derivatives, then
  // d(s U) = ds U + s dU with ds = dvol / vol(0).
  const VertexMassMoments& M = *template_moments_;
  const MatX& W = body.weights;
  inertia_shape_jacobian_ = MatX::Zero(10 * nb, K);
  const VecX ds = volume_shape_gradient_ / template_volume_;
  for (int b = 0; b < nb; ++b) {
    const BoneInertia& in = bone_inertia_[b];  // already scaled: U = in / s
    const Mat3& Sm = in.second_moment;
    Eigen::Matrix<double, 10, 1> U;
    U << in.mass, in.first_moment, Sm(0, 0), Sm(1, 1), Sm(2, 2), Sm(0, 1), Sm(0, 2), Sm(1, 2);
    inertia_shape_jacobian_.middleRows<10>(10 * b) = (U / mass_scale) * ds.transpose();
  }
  for (int v = 0; v < nv; ++v) {
    const double m = M.mass[v];
    if (m == 0) continue;
    const Vec3 fv = M.first_moment.row(v).transpose();
    const auto Sv = S.middleRows<3>(3 * v);
    for (int b = 0; b < nb; ++b) {
      const double w = W(v, b);
      if (w == 0) continue;
      const Vec3 o = X.row(v).transpose() - J.row(b).transpose();
      const double sw = mass_scale * w;
      for (long k = 0; k < K; ++k) {
        const Vec3 d = Sv.col(k) - joints_shape_jacobian_.block<3, 1>(3 * b, k);
        const Mat3 dS =
            fv * d.transpose() + d * fv.transpose() + m * (d * o.transpose() + o * d.transpose());
        auto col = inertia_shape_jacobian_.block<10, 1>(10 * b, k);
        col.segment<3>(1) += sw * m * d;
        col[4] += sw * dS(0, 0);
        col[5] += sw * dS(1, 1);
        col[6] += sw * dS(2, 2);
        col[7] += sw * dS(0, 1);
        col[8] += sw * dS(0, 2);
        col[9] += sw * dS(1, 2);
      }
    }
  }
}

double SoftAvatar::totalMass() const {
  double mass = 0;
  for (const BoneInertia& bone : bone_inertia_) mass += bone.mass;
  return mass;
}

}  // namespace flsh
