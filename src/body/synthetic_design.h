// The designed anatomy of the synthetic body (internal): SMPL joint centres and the body-part
// primitives whose smooth union is the skin, at the nominal height of 1.70 m, pelvis joint at
// the origin, y up, facing +z, the body's left = +x. Mirror symmetric about x = 0.
#pragma once

#include <array>
#include <vector>

#include "flsh/body/smpl_skeleton.h"
#include "flsh/core/types.h"

namespace flsh::synthetic {

/// A body-part solid: a round cone (sphere-swept segment with linearly varying radius) or an
/// ellipsoid, owned by one joint (the skinning weights follow the owners).
struct BodyPrimitive {
  enum class Kind { RoundCone, Ellipsoid };
  Kind kind = Kind::RoundCone;
  Vec3 a = Vec3::Zero(), b = Vec3::Zero();           // round cone: end centres, m
  double radius_a = 0, radius_b = 0;                 // round cone: end radii, m
  Vec3 centre = Vec3::Zero(), radii = Vec3::Zero();  // ellipsoid (axis aligned), m
  /// Scale of z before measuring (the torso's elliptic cross-section); 1 = none.
  double depth_scale = 1.0;
  /// Smooth-min blend width with the parts before it, m.
  double blend = 0.03;
  int joint = 0;

  /// Signed distance (ellipsoids: iq's first-order bound), m.
  double distance(const Vec3& p) const;
};

struct BodyDesign {
  /// 24 joint centres in SMPL order, m.
  std::array<Vec3, kNumJoints> joints;
  /// Parts in the order they are blended.
  std::vector<BodyPrimitive> parts;
  /// Height of the soles (the body is cut flat there with a small blend), m.
  double sole_y = 0;
  /// Per joint, the far end of its bone segment (the joint → child axis; a leaf joint gets a
  /// designed end point: top of the head, toes, fingertips), m.
  std::array<Vec3, kNumJoints> bone_end;

  /// Signed distance of the whole body (smooth union of the parts, flat soles), m.
  double distance(const Vec3& p) const;
  /// Signed distance to the parts owned by each joint (+inf for a joint owning no part).
  void partDistances(const Vec3& p, std::array<double, kNumJoints>& out) const;
  /// Relative target edge length (finer on hands, face and feet).
  double relativeEdgeLength(const Vec3& p) const;
  /// A box containing the body with a margin, m.
  Vec3 boxMin() const;
  Vec3 boxMax() const;
};

/// The nominal design (height ≈ 1.70 m before the exact rescale).
BodyDesign makeBodyDesign();

/// Polynomial smooth minimum with blend width k (k ≤ 0: plain min).
double smoothMin(double a, double b, double k);

}  // namespace flsh::synthetic
