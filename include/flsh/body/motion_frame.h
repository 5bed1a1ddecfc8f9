// Where a motion stands in flsh's world, whose up axis is +y: the up axis of the frame a clip
// was recorded in (AMASS clips are z up), a motion placed by a yaw and an offset, the ground
// under a clip's lowest point, and whether the body stands upright (docs/formats.md, "Motions").
#pragma once

#include <string>

#include "flsh/body/body_model.h"
#include "flsh/body/motion.h"
#include "flsh/core/types.h"

namespace flsh {

/// Rotation from a frame whose up axis is `up` to flsh's y-up world: the identity for "y", the
/// rotation by −90° about x for "z", (x, y, z) ↦ (x, z, −y). Throws InputError naming `what`
/// for anything else.
Mat3 worldFromUpAxis(const std::string& up, const std::string& what = "up");

/// Turns every frame of `motion` by R about the root joint's rest position J₀:
/// trans ← R trans and R_root ← R R_root. The posed body of any shape then moves as a whole,
/// each vertex v ↦ J₀ + R (v − J₀), and so does the clip's floor.
void rotateMotion(Motion& motion, const Mat3& R);

/// The motion turned by `yaw` (rad) about +y through the root's rest position, then moved by
/// `offset` (m): trans ← R_y trans + offset, R_root ← R_y R_root.
Motion placedMotion(Motion motion, double yaw, const Vec3& offset);

/// World height y (m) of the lowest vertex of `body`, shaped by `betas`, over the frames of
/// `motion` within its first `seconds` (frame 0 at least): where the floor under the clip is.
/// The body is posed once per frame (poseBodyBatch). Throws InputError for an empty motion.
double lowestPointHeight(const BodyModel& body, const VecX& betas, const Motion& motion,
                         double seconds = 1.0);

/// The body's up direction at frame 0 in the world, R_root · ŷ (SMPL bodies stand along +y in
/// their rest pose).
Vec3 bodyUpAtStart(const Motion& motion);

/// A warning sentence when the body leans more than 60° from upright (+y) at frame 0, naming
/// the clip's up axis and how to set another; "" when it stands upright. Clips that start
/// lying down are rare; a wrong up axis is the usual cause.
std::string uprightWarning(const Motion& motion);

}  // namespace flsh
