#include "body/synthetic_design.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <limits>

namespace flsh::synthetic {

namespace {

double signOf(double x) { return x > 0 ? 1.0 : (x < 0 ? -1.0 : 0.0); }

// Exact signed distance of a round cone (Inigo Quilez's closed form).
double roundConeDistance(const Vec3& p, const Vec3& a, const Vec3& b, double r1, double r2) {
  const Vec3 ba = b - a;
  const double l2 = ba.squaredNorm();
  const double rr = r1 - r2;
  const double a2 = l2 - rr * rr;
  const double il2 = 1.0 / l2;
  const Vec3 pa = p - a;
  const double y = pa.dot(ba);
  const double z = y - l2;
  const double x2 = (pa * l2 - ba * y).squaredNorm();
  const double y2 = y * y * l2;
  const double z2 = z * z * l2;
  const double k = signOf(rr) * rr * rr * x2;
  if (signOf(z) * a2 * z2 > k) return std::sqrt(x2 + z2) * il2 - r2;
  if (signOf(y) * a2 * y2 < k) return std::sqrt(x2 + y2) * il2 - r1;
  return (std::sqrt(x2 * a2 * il2) + y * rr) * il2 - r1;
}

// First-order distance bound of an axis-aligned ellipsoid centred at the origin.
double ellipsoidDistance(const Vec3& p, const Vec3& r) {
  const double k0 = p.cwiseQuotient(r).norm();
  const double k1 = p.cwiseQuotient(r.cwiseProduct(r)).norm();
  if (!(k1 > 1e-12)) return -r.minCoeff();
  return k0 * (k0 - 1.0) / k1;
}

BodyPrimitive roundCone(int joint, const Vec3& a, double ra, const Vec3& b, double rb,
                        double blend = 0.03, double depth_scale = 1.0) {
  BodyPrimitive part;
  part.kind = BodyPrimitive::Kind::RoundCone;
  part.a = a;
  part.b = b;
  part.radius_a = ra;
  part.radius_b = rb;
  part.blend = blend;
  part.depth_scale = depth_scale;
  part.joint = joint;
  return part;
}

BodyPrimitive ellipsoid(int joint, const Vec3& centre, const Vec3& radii, double blend = 0.03) {
  BodyPrimitive part;
  part.kind = BodyPrimitive::Kind::Ellipsoid;
  part.centre = centre;
  part.radii = radii;
  part.blend = blend;
  part.joint = joint;
  return part;
}

Vec3 mirror(const Vec3& p) { return Vec3(-p.x(), p.y(), p.z()); }

BodyPrimitive mirrored(const BodyPrimitive& part, int joint) {
  BodyPrimitive m = part;
  m.a = mirror(part.a);
  m.b = mirror(part.b);
  m.centre = mirror(part.centre);
  m.joint = joint;
  return m;
}

double gaussian(const Vec3& p, const Vec3& c, double sigma) {
  return std::exp(-(p - c).squaredNorm() / (sigma * sigma));
}

}  // namespace

double smoothMin(double a, double b, double k) {
  if (k <= 0) return std::min(a, b);
  const double h = std::max(k - std::abs(a - b), 0.0) / k;
  return std::min(a, b) - h * h * k * 0.25;
}

double BodyPrimitive::distance(const Vec3& p) const {
  Vec3 q = p;
  if (kind == Kind::RoundCone) {
    if (depth_scale != 1.0) q.z() = a.z() + (p.z() - a.z()) * depth_scale;
    return roundConeDistance(q, a, b, radius_a, radius_b);
  }
  if (depth_scale != 1.0) q.z() = centre.z() + (p.z() - centre.z()) * depth_scale;
  return ellipsoidDistance(q - centre, radii);
}

double BodyDesign::distance(const Vec3& p) const {
  double f = std::numeric_limits<double>::infinity();
  bool first = true;
  for (const BodyPrimitive& part : parts) {
    const double d = part.distance(p);
    f = first ? d : smoothMin(f, d, part.blend);
    first = false;
  }
  // Flat soles: smooth maximum with the half-space below the floor.
  return -smoothMin(-f, -(sole_y - p.y()), 0.015);
}

void BodyDesign::partDistances(const Vec3& p, std::array<double, kNumJoints>& out) const {
  out.fill(std::numeric_limits<double>::infinity());
  for (const BodyPrimitive& part : parts)
    out[part.joint] = std::min(out[part.joint], part.distance(p));
}

double BodyDesign::relativeEdgeLength(const Vec3& p) const {
  const Vec3 hand(0.78, 0.44, -0.04), head(0.0, 0.64, 0.04), foot(0.095, -0.93, 0.06);
  double finer = 0.45 * (gaussian(p, hand, 0.09) + gaussian(p, mirror(hand), 0.09)) +
                 0.30 * gaussian(p, head, 0.11) +
                 0.25 * (gaussian(p, foot, 0.11) + gaussian(p, mirror(foot), 0.11));
  return std::max(0.45, 1.0 - finer);
}

Vec3 BodyDesign::boxMin() const { return Vec3(-0.93, sole_y - 0.03, -0.19); }
Vec3 BodyDesign::boxMax() const { return Vec3(0.93, 0.80, 0.22); }

BodyDesign makeBodyDesign() {
  BodyDesign d;
  auto& J = d.joints;
  // Left side (+x) and spine; the right side mirrors the left.
  J[0] = Vec3(0.0, 0.0, 0.0);         // pelvis
  J[1] = Vec3(0.075, -0.09, 0.0);     // left_hip
  J[3] = Vec3(0.0, 0.115, -0.01);     // spine1
  J[4] = Vec3(0.095, -0.475, 0.01);   // left_knee
  J[6] = Vec3(0.0, 0.245, -0.01);     // spine2
  J[7] = Vec3(0.085, -0.87, -0.03);   // left_ankle
  J[9] = Vec3(0.0, 0.305, -0.01);     // spine3
  J[10] = Vec3(0.1, -0.94, 0.09);     // left_foot (ball of the foot)
  J[12] = Vec3(0.0, 0.505, -0.025);   // neck
  J[13] = Vec3(0.075, 0.42, -0.02);   // left_collar
  J[15] = Vec3(0.0, 0.58, 0.0);       // head (top of the neck)
  J[16] = Vec3(0.175, 0.445, -0.03);  // left_shoulder
  J[18] = Vec3(0.435, 0.44, -0.045);  // left_elbow
  J[20] = Vec3(0.69, 0.44, -0.05);    // left_wrist
  J[22] = Vec3(0.775, 0.44, -0.05);   // left_hand (knuckles)
  for (int left : {1, 4, 7, 10, 13, 16, 18, 20, 22}) J[left + 1] = mirror(J[left]);

  auto& E = d.bone_end;
  for (int j = 0; j < kNumJoints; ++j) E[j] = J[j];
  E[0] = J[3];
  E[3] = J[6];
  E[6] = J[9];
  E[9] = J[12];
  E[12] = J[15];
  E[15] = Vec3(0.0, 0.74, 0.015);
  E[1] = J[4];
  E[4] = J[7];
  E[7] = J[10];
  E[10] = Vec3(0.105, -0.945, 0.165);
  E[13] = J[16];
  E[16] = J[18];
  E[18] = J[20];
  E[20] = J[22];
  E[22] = Vec3(0.86, 0.44, -0.05);
  for (int left : {1, 4, 7, 10, 13, 16, 18, 20, 22}) E[left + 1] = mirror(E[left]);

  d.sole_y = -0.962;
  auto& P = d.parts;
  const double torso_depth = 1.0 / 0.64;  // torso cross-section: depth = 0.64 × width
  // Torso and head (on the mid-plane).
  P.push_back(ellipsoid(0, Vec3(0.0, -0.045, -0.005), Vec3(0.16, 0.115, 0.105)));
  P.push_back(roundCone(0, Vec3(0, 0, 0), 0.155, Vec3(0, 0.115, 0), 0.14, 0.04, torso_depth));
  P.push_back(roundCone(3, Vec3(0, 0.115, 0), 0.14, Vec3(0, 0.245, 0), 0.148, 0.04, torso_depth));
  P.push_back(roundCone(6, Vec3(0, 0.245, 0), 0.148, Vec3(0, 0.305, 0), 0.155, 0.04, torso_depth));
  P.push_back(ellipsoid(9, Vec3(0.0, 0.35, -0.005), Vec3(0.165, 0.13, 0.105), 0.04));
  P.push_back(roundCone(12, Vec3(0, 0.44, -0.025), 0.058, Vec3(0, 0.6, -0.005), 0.05, 0.035));
  P.push_back(ellipsoid(15, Vec3(0.0, 0.655, 0.015), Vec3(0.077, 0.1, 0.092), 0.035));
  P.push_back(ellipsoid(15, Vec3(0.0, 0.605, 0.045), Vec3(0.058, 0.05, 0.065), 0.03));
  P.push_back(ellipsoid(15, Vec3(0.0, 0.645, 0.11), Vec3(0.012, 0.02, 0.016), 0.01));
  // Left limbs, each followed by its mirror image.
  std::vector<BodyPrimitive> left;
  left.push_back(ellipsoid(0, Vec3(0.07, -0.085, -0.05), Vec3(0.08, 0.085, 0.07)));    // buttock
  left.push_back(ellipsoid(9, Vec3(0.07, 0.35, 0.055), Vec3(0.075, 0.06, 0.055)));     // pectoral
  left.push_back(roundCone(13, Vec3(0.03, 0.44, -0.025), 0.06, J[16], 0.055, 0.035));  // shoulder
  left.push_back(roundCone(16, J[16], 0.05, J[18], 0.037));                            // upper arm
  left.push_back(roundCone(18, J[18], 0.037, J[20], 0.027));                           // forearm
  left.push_back(ellipsoid(20, Vec3(0.735, 0.44, -0.05), Vec3(0.06, 0.022, 0.045), 0.015));
  left.push_back(ellipsoid(22, Vec3(0.82, 0.438, -0.052), Vec3(0.06, 0.016, 0.042), 0.015));
  left.push_back(roundCone(20, Vec3(0.71, 0.435, -0.025), 0.013, Vec3(0.765, 0.43, 0.02), 0.011,
                           0.01));                                                   // thumb
  left.push_back(roundCone(1, J[1], 0.085, J[4], 0.055));                            // thigh
  left.push_back(roundCone(4, J[4], 0.052, J[7], 0.034));                            // shin
  left.push_back(ellipsoid(4, Vec3(0.092, -0.6, -0.03), Vec3(0.046, 0.11, 0.048)));  // calf
  left.push_back(ellipsoid(7, Vec3(0.09, -0.925, 0.03), Vec3(0.043, 0.045, 0.105), 0.02));
  left.push_back(ellipsoid(10, Vec3(0.1, -0.945, 0.125), Vec3(0.045, 0.025, 0.055), 0.015));
  for (const BodyPrimitive& part : left) {
    P.push_back(part);
    // SMPL numbers a right joint one after its left twin (except the spine, owned by both).
    const bool sided = part.joint != 0 && part.joint != 9;
    P.push_back(mirrored(part, sided ? part.joint + 1 : part.joint));
  }
  return d;
}

}  // namespace flsh::synthetic
