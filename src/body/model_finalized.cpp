#include "flsh/body/model_finalized.h"

#include "body/body_model_derived.h"
#include "flsh/core/error.h"

namespace flsh {

std::string modelName(const BodyModel& model) {
  return model.source.empty() ? std::string("body model") : "body model '" + model.source + "'";
}

bool isFinalized(const BodyModel& model) {
  return model.derived && model.derived->weights.numVertices() == model.numVertices() &&
         model.derived->joint_shapedirs.cols() == model.numBetas();
}

void requireFinalized(const BodyModel& model, const std::string& who) {
  if (isFinalized(model)) return;
  throw InputError(who + ": " + modelName(model) +
                   " is not finalized for its current arrays (call BodyModel::finalize())");
}

}  // namespace flsh
