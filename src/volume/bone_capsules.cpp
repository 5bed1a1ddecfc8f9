// One capsule per bone fitted to the rest-pose vertices the bone dominates (fitBoneCapsules).
//
// Axis of bone b (a unit vector u through a point o):
// - one child c: u = (J_c − J_b)/‖J_c − J_b‖ through o = J_b (the anatomical segment: upper
//   arm, thigh, spine, …);
// - several children (pelvis, spine3) or none (head, hands, feet): the principal direction of
//   the bone's vertices through their centroid. Several children pull in different directions
//   (pelvis: both hips down, spine up), so their mean is not a direction of the part; the part's
//   own longest extent is (across the hips, across the chest). A leaf's direction is oriented
//   away from its parent joint; a multi-child bone's so that its largest component is positive.
// Radius: the 65th percentile of the vertices' distances from the axis line — most of the
// capsule stays inside the surface while it still covers the bulk of the part.
// Segment: the extent of the vertices projected on the axis, shrunk by the radius at both ends so
// the capsule's caps end near the part's ends (a point when the part is shorter than 2 r).
#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include "flsh/core/error.h"
#include "flsh/volume/soft_avatar.h"
#include "volume/kinematic_tree.h"

namespace flsh {

namespace {

// Fraction of a bone's vertices closer to its axis than the capsule radius.
constexpr double kRadiusPercentile = 0.65;

/// Principal direction (largest-variance axis) of the points, and their centroid.
Vec3 principalDirection(const std::vector<Vec3>& points, Vec3& centroid) {
  centroid = Vec3::Zero();
  for (const Vec3& p : points) centroid += p;
  centroid /= double(points.size());
  Mat3 covariance = Mat3::Zero();
  for (const Vec3& p : points) covariance += (p - centroid) * (p - centroid).transpose();
  const Eigen::SelfAdjointEigenSolver<Mat3> eigen(covariance);
  return eigen.eigenvectors().col(2).normalized();  // eigenvalues ascend
}

}  // namespace

std::vector<BoneCapsule> fitBoneCapsules(const MatX3& V, const MatX& weights, const MatX3& J,
                                         const std::vector<int>& parents) {
  const std::string fn = "fitBoneCapsules: ";
  const int nb = int(J.rows());
  if (nb < 1) throw InputError(fn + "J has 0 joints, expected at least 1");
  if (weights.rows() != V.rows() || weights.cols() != nb)
    throw InputError(fn + "weights has shape " +
                     shapeString({long(weights.rows()), long(weights.cols())}) + ", expected " +
                     shapeString({long(V.rows()), long(nb)}) + " (#V × bones)");
  detail::checkParents(parents, nb, fn);
  if (!V.allFinite() || !J.allFinite() || !weights.allFinite())
    throw InputError(fn + "V, J or weights contains NaN or Inf");

  // Vertices of each bone: those whose largest weight is the bone's (ties: lower bone index).
  std::vector<std::vector<Vec3>> part(nb);
  for (int v = 0; v < V.rows(); ++v) {
    int dominant = 0;
    weights.row(v).maxCoeff(&dominant);
    part[dominant].push_back(V.row(v).transpose());
  }
  const std::vector<std::vector<int>> children = detail::jointChildren(parents);

  std::vector<BoneCapsule> capsules(nb);
  for (int b = 0; b < nb; ++b) {
    BoneCapsule& capsule = capsules[b];
    capsule.bone = b;
    const Vec3 joint = J.row(b).transpose();
    capsule.a = capsule.b = joint;
    if (part[b].empty()) continue;  // zero radius at the joint

    Vec3 origin = joint, axis = Vec3::Zero();
    if (children[b].size() == 1) axis = J.row(children[b][0]).transpose() - joint;
    if (axis.norm() > 1e-9) {
      axis.normalize();
    } else if (part[b].size() == 1) {
      capsule.a = capsule.b = part[b][0];  // a single vertex: a point capsule of zero radius
      continue;
    } else {
      axis = principalDirection(part[b], origin);
      if (children[b].empty() && parents[b] >= 0) {
        if (axis.dot(origin - J.row(parents[b]).transpose()) < 0) axis = -axis;
      } else {
        int largest = 0;
        axis.cwiseAbs().maxCoeff(&largest);
        if (axis[largest] < 0) axis = -axis;
      }
    }

    std::vector<double> distances;
    distances.reserve(part[b].size());
    double t_min = std::numeric_limits<double>::infinity(), t_max = -t_min;
    for (const Vec3& p : part[b]) {
      const double t = (p - origin).dot(axis);
      t_min = std::min(t_min, t);
      t_max = std::max(t_max, t);
      distances.push_back((p - origin - t * axis).norm());
    }
    const size_t k = std::min(distances.size() - 1, size_t(kRadiusPercentile * distances.size()));
    std::nth_element(distances.begin(), distances.begin() + k, distances.end());
    capsule.radius = distances[k];
    double ta = t_min + capsule.radius, tb = t_max - capsule.radius;
    if (ta > tb) ta = tb = 0.5 * (t_min + t_max);
    capsule.a = origin + ta * axis;
    capsule.b = origin + tb * axis;
  }
  return capsules;
}

}  // namespace flsh
