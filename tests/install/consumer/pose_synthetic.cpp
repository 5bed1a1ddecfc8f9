// Poses the synthetic body through the installed headers and library; prints the vertex count
// and the height of the posed body.
#include <cstdio>

#include "flsh/body/body_forward.h"
#include "flsh/body/synthetic_body.h"

int main() {
  flsh::SyntheticBodyOptions options;
  options.vertices = 500;
  const flsh::BodyModel body = flsh::makeSyntheticBody(options);
  const flsh::VecX betas = flsh::VecX::Zero(10), pose = flsh::VecX::Zero(72);
  const flsh::PosedBody posed = flsh::poseBody(body, betas, pose, flsh::Vec3::Zero());
  const double height = posed.vertices.col(1).maxCoeff() - posed.vertices.col(1).minCoeff();
  std::printf("vertices %d height %.3f\n", int(posed.vertices.rows()), height);
  return posed.vertices.rows() == 500 && height > 1.0 ? 0 : 1;
}
