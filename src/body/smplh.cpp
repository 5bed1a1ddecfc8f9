// SMPL-H to SMPL: the finger joints merged into SMPL's hand joints (smplh.h).
#include "flsh/body/smplh.h"

#include <algorithm>
#include <string>
#include <vector>

#include "flsh/body/smpl_skeleton.h"
#include "flsh/core/error.h"

namespace flsh {

const std::array<int, kNumSmplhJoints> kSmplhParents = {
    -1, 0,  0,  0,  1,  2,  3,  4,  5,  6,  7,  8,  9,  9,  9,  12, 13, 14,  // body 0–17
    16, 17, 18, 19,                                                          // 18–21
    20, 22, 23, 20, 25, 26, 20, 28, 29, 20, 31, 32, 20, 34, 35,              // left hand
    21, 37, 38, 21, 40, 41, 21, 43, 44, 21, 46, 47, 21, 49, 50};             // right hand

bool isSmplhSkeleton(const std::vector<int>& parents) {
  return parents.size() == kSmplhParents.size() &&
         std::equal(parents.begin(), parents.end(), kSmplhParents.begin());
}

namespace {

/// The hand (0 left, 1 right) a finger joint j ≥ 22 belongs to.
int handOf(int j) { return j < 37 ? 0 : 1; }

}  // namespace

BodyModel smplFromSmplh(const BodyModel& smplh) {
  if (!isSmplhSkeleton(smplh.parents))
    throw InputError((smplh.source.empty() ? std::string("body model") : smplh.source) +
                     ": key 'kintree_table': not SMPL-H's 52-joint tree (" +
                     std::to_string(smplh.numJoints()) + " joints)");
  const long V = smplh.numVertices();
  constexpr int kBody = kNumBodyJointsSmplh;  // 22 joints shared with SMPL
  BodyModel smpl;
  smpl.v_template = smplh.v_template;
  smpl.shapedirs = smplh.shapedirs;
  smpl.faces = smplh.faces;
  smpl.source = smplh.source;
  smpl.family = "SMPL-H";
  smpl.parents.assign(kSmplParents.begin(), kSmplParents.end());

  // Pose blend shapes: joints 1–21 keep theirs (the first 9·21 columns); the hand joints have
  // none, like a finger at rest.
  smpl.posedirs = MatX::Zero(3 * V, 9 * (kNumJoints - 1));
  smpl.posedirs.leftCols(9 * (kBody - 1)) = smplh.posedirs.leftCols(9 * (kBody - 1));

  // Skinning: each finger's weight onto its hand joint.
  smpl.weights = MatX::Zero(V, kNumJoints);
  smpl.weights.leftCols(kBody) = smplh.weights.leftCols(kBody);
  for (int j = kBody; j < kNumSmplhJoints; ++j)
    smpl.weights.col(kBody + handOf(j)) += smplh.weights.col(j);

  // Joint regressor: body rows as they are, the hands at the middle fingers' first joints.
  std::vector<Eigen::Triplet<double>> entries;
  for (int k = 0; k < smplh.J_regressor.outerSize(); ++k) {
    const int row = k < kBody                 ? k
                    : k == kSmplhLeftMiddle1  ? kBody
                    : k == kSmplhRightMiddle1 ? kBody + 1
                                              : -1;
    if (row < 0) continue;
    for (SpMatR::InnerIterator it(smplh.J_regressor, k); it; ++it)
      entries.emplace_back(row, int(it.col()), it.value());
  }
  smpl.J_regressor.resize(kNumJoints, V);
  smpl.J_regressor.setFromTriplets(entries.begin(), entries.end());
  smpl.J_regressor.makeCompressed();
  smpl.finalize();
  return smpl;
}

}  // namespace flsh
