#include "flsh/contact/contact_energy.h"

#include <cmath>
#include <string>

#include "contact/collider_detail.h"
#include "flsh/core/error.h"

namespace flsh {

namespace {

void checkStiffness(double stiffness, const char* what) {
  if (!(std::isfinite(stiffness) && stiffness >= 0.0))
    throw InputError(std::string(what) + " must be nonnegative and finite, got " +
                     detail::numberText(stiffness));
}

// Cheap check first so that the message string is only built when a path is actually bad.
bool pathIsValid(const ColliderPath& path) {
  if (path.times.size() != path.offsets.size()) return false;
  for (size_t k = 0; k < path.times.size(); ++k) {
    if (!std::isfinite(path.times[k]) || !path.offsets[k].allFinite()) return false;
    if (k > 0 && !(path.times[k] > path.times[k - 1])) return false;
  }
  return true;
}

}  // namespace

double colliderContactEnergy(const Eigen::Ref<const MatX3>& X, const Eigen::Ref<const VecX>& areas,
                             const std::vector<Collider>& colliders, double t,
                             const ContactOptions& options, VecX* gradient,
                             std::vector<Triplet>* hessian, int offset,
                             std::vector<ContactPoint>* active) {
  const Eigen::Index n = X.rows();
  if (areas.size() != n)
    throw InputError("colliderContactEnergy: areas has " + std::to_string(areas.size()) +
                     " entries, expected one per point of X (" + std::to_string(n) + ")");
  if (!X.allFinite()) throw InputError("colliderContactEnergy: points X contain NaN or Inf");
  if (!areas.allFinite() || (n > 0 && areas.minCoeff() < 0.0))
    throw InputError("colliderContactEnergy: areas must be finite and nonnegative (min " +
                     detail::numberText(n > 0 ? areas.minCoeff() : 0.0) + ")");
  checkStiffness(options.stiffness, "colliderContactEnergy: options.stiffness");
  if (offset < 0)
    throw InputError("colliderContactEnergy: offset must be nonnegative, got " +
                     std::to_string(offset));
  if (gradient) {
    if (gradient->size() == 0) {
      gradient->setZero(3 * n);
    } else if (gradient->size() != 3 * n) {
      throw InputError("colliderContactEnergy: gradient has size " +
                       std::to_string(gradient->size()) +
                       ", expected 3 × #X = " + std::to_string(3 * n) + " (or 0 to allocate)");
    }
  }
  if (!std::isfinite(t))
    throw InputError("colliderContactEnergy: time must be finite, got " + detail::numberText(t));

  const double k = options.stiffness;
  const bool curvature = hessian && options.exact_hessian;
  double energy = 0.0;

  // Adds vertex i's penalty against collider c, given d < 0 and ∇d (and ∇²d when exact).
  auto accumulate = [&](Eigen::Index i, int c, double d, const Vec3& g, const Mat3& H) {
    const double w = k * areas[i];
    energy += 0.5 * w * d * d;
    if (gradient) gradient->segment<3>(3 * i) += (w * d) * g;
    if (hessian) {
      Mat3 block = w * g * g.transpose();
      if (curvature) block += (w * d) * H;
      const int base = offset + 3 * static_cast<int>(i);
      for (int r = 0; r < 3; ++r)
        for (int s = 0; s < 3; ++s) hessian->emplace_back(base + r, base + s, block(r, s));
    }
    if (active) active->push_back(ContactPoint{static_cast<int>(i), c, d});
  };

  Vec3 g;
  Mat3 H = Mat3::Zero();
  Mat3* H_wanted = curvature ? &H : nullptr;
  for (int c = 0; c < static_cast<int>(colliders.size()); ++c) {
    const Collider& collider = colliders[c];
    if (!pathIsValid(collider.path))
      collider.path.validate("colliderContactEnergy: collider " + std::to_string(c) + " (" +
                             collider.name + ")");
    const Vec3 shift = collider.path.offsetAt(t);
    switch (collider.shape()) {
      case ColliderShape::Plane: {
        const Vec3 point = collider.p0() + shift;
        const Vec3& normal = collider.p1();
        H.setZero();  // flat: no curvature term
        for (Eigen::Index i = 0; i < n; ++i) {
          const double d = (X.row(i).transpose() - point).dot(normal);
          if (!(d < 0.0) || areas[i] == 0.0) continue;
          accumulate(i, c, d, normal, H);
        }
        break;
      }
      case ColliderShape::Sphere: {
        const Vec3 center = collider.p0() + shift;
        const double r = collider.radius();
        const double r2 = r * r;
        for (Eigen::Index i = 0; i < n; ++i) {
          const Vec3 x = X.row(i).transpose();
          if ((x - center).squaredNorm() >= r2 || areas[i] == 0.0) continue;
          const double d = detail::pointDistance(x, center, r, Vec3::UnitY(), &g, H_wanted);
          accumulate(i, c, d, g, H);
        }
        break;
      }
      case ColliderShape::Capsule: {
        const Vec3 a = collider.p0() + shift, b = collider.p1() + shift;
        const double r = collider.radius();
        // Broad phase: the capsule lies inside the sphere about its midpoint of radius |ab|/2 + r.
        const Vec3 middle = 0.5 * (a + b);
        const double bound = 0.5 * (b - a).norm() + r;
        const double bound2 = bound * bound;
        for (Eigen::Index i = 0; i < n; ++i) {
          const Vec3 x = X.row(i).transpose();
          if ((x - middle).squaredNorm() >= bound2 || areas[i] == 0.0) continue;
          const double d = detail::capsuleDistanceX(x, a, b, r, &g, H_wanted);
          if (!(d < 0.0)) continue;
          accumulate(i, c, d, g, H);
        }
        break;
      }
    }
  }
  return energy;
}

double vertexCapsulePenalty(const Vec3& x, const Vec3& a, const Vec3& b, double r,
                            double stiffness_area, const ContactOptions& options,
                            Eigen::Matrix<double, 9, 1>* gradient,
                            Eigen::Matrix<double, 9, 9>* hessian) {
  checkStiffness(stiffness_area, "vertexCapsulePenalty: stiffness_area");
  // Value first: most calls are not penetrating and need no derivatives.
  const double d0 = capsuleDistance(x, a, b, r);
  if (!(d0 < 0.0)) {
    if (gradient) gradient->setZero();
    if (hessian) hessian->setZero();
    return 0.0;
  }
  Eigen::Matrix<double, 9, 1> g;
  Eigen::Matrix<double, 9, 9> H;
  const bool curvature = hessian && options.exact_hessian;
  const double d = capsuleDistance(x, a, b, r, &g, curvature ? &H : nullptr);
  if (gradient) *gradient = (stiffness_area * d) * g;
  if (hessian) {
    hessian->noalias() = stiffness_area * g * g.transpose();
    if (curvature) hessian->noalias() += (stiffness_area * d) * H;
  }
  return 0.5 * stiffness_area * d * d;
}

double colliderContactBlocks(const Eigen::Ref<const MatX3>& X, const Eigen::Ref<const VecX>& areas,
                             const std::vector<Collider>& colliders, double t,
                             const ContactOptions& options, VecX* gradient,
                             std::vector<Mat3>& blocks, std::vector<ContactPoint>* active) {
  std::vector<Triplet> triplets;
  const double E =
      colliderContactEnergy(X, areas, colliders, t, options, gradient, &triplets, 0, active);
  blocks.assign(size_t(X.rows()), Mat3::Zero());
  for (const Triplet& e : triplets) {
    const int i = e.row() / 3;
    blocks[size_t(i)](e.row() - 3 * i, e.col() - 3 * i) += e.value();
  }
  return E;
}

}  // namespace flsh
