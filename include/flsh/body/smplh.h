// SMPL-H (SMPL+H, AMASS's body model): 52 joints, SMPL's 22 body joints followed by 15 joints
// per hand, and its conversion to SMPL's 24-joint skeleton, which the simulation runs.
//
// The conversion merges each hand's 15 finger joints into SMPL's hand joint (22 left, 23
// right): the finger skinning weights are summed onto it, it sits at the middle finger's first
// joint, and the finger pose blend shapes are dropped. The fingers thus move rigidly with the
// hand in the model's rest hand pose (flat for AMASS's SMPL+H), and a clip's 90 hand-pose
// values are ignored (toSmplPose). For every body pose with the hand joints at rest this is
// exact: the converted model poses to the same vertices as the SMPL-H model with its finger
// joints at rest.
#pragma once

#include <array>

#include "flsh/body/body_model.h"

namespace flsh {

constexpr int kNumSmplhJoints = 52;

/// SMPL-H's parent table: joints 0–21 as SMPL; per hand (left 22–36 under the left wrist 20,
/// right 37–51 under 21) index, middle, pinky, ring and thumb chains of three joints each.
extern const std::array<int, kNumSmplhJoints> kSmplhParents;

/// SMPL-H's first joint of the middle finger, where SMPL's hand joint is placed.
constexpr int kSmplhLeftMiddle1 = 25;
constexpr int kSmplhRightMiddle1 = 40;

/// True if `parents` is SMPL-H's 52-joint tree (kSmplhParents).
bool isSmplhSkeleton(const std::vector<int>& parents);

/// An SMPL-H model (52 joints, posedirs of 9·51 columns) as an SMPL model (24 joints, 207)
/// per this header's comment; family "SMPL-H". Throws InputError naming the model's source
/// unless it has SMPL-H's tree.
BodyModel smplFromSmplh(const BodyModel& smplh);

}  // namespace flsh
