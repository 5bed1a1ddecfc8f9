#include "sim/soft/held_mass_moments.h"

#include "flsh/body/smpl_skeleton.h"

namespace flsh::detail {

long HeldMassMoments::update() const {
  if (build_id_ > 0 && y_stamp_ == kin_.unposedStamp() &&
      joints_of_.rows() == kin_.joints().rows() && joints_of_ == kin_.joints())
    return build_id_;
  kin_.ensurePrepared();  // Y's rows of the mass nodes (the presolve defers the skinning)
  build();
  return build_id_;
}

void HeldMassMoments::build() const {
  const int bones = kin_.numBones();
  const std::vector<int>& nodes = masses_.nodes;
  const MatX3& Y = kin_.Y();
  const MatX3& J = kin_.joints();
  index_.assign(size_t(bones) * size_t(bones), -1);
  pairs_.clear();
  L_.assign(size_t(bones), Vec3::Zero());
  Vec3 lever[kNumJoints];
  for (const int j : nodes) {
    const double m = masses_.mass[j];
    const SoftKinematics::Influence* begin = kin_.influencesBegin(j);
    const int count = int(kin_.influencesEnd(j) - begin);
    for (int a = 0; a < count; ++a)
      lever[a] = Y.row(j).transpose() - J.row(begin[a].bone).transpose();
    for (int a = 0; a < count; ++a) {
      const int b = begin[a].bone;
      const double mw = m * begin[a].weight;
      L_[size_t(b)] += mw * lever[a];
      for (int c = 0; c < count; ++c) {
        int& slot = index_[size_t(b) * size_t(bones) + size_t(begin[c].bone)];
        if (slot < 0) {
          slot = int(pairs_.size());
          pairs_.emplace_back();
          pairs_.back().b = b;
          pairs_.back().c = begin[c].bone;
        }
        Pair& p = pairs_[size_t(slot)];
        const double s = mw * begin[c].weight;
        p.S += s;
        p.Ub += s * lever[a];
        p.Uc += s * lever[c];
        p.V.noalias() += (s * lever[a]) * lever[c].transpose();
      }
    }
  }
  joints_of_ = J;
  y_stamp_ = kin_.unposedStamp();
  ++build_id_;
}

}  // namespace flsh::detail
