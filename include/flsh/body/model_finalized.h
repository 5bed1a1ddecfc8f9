// Whether a body model's derived data (BodyModel::finalize) matches its current arrays: what
// every computation on the model needs first.
#pragma once

#include <string>

#include "flsh/body/body_model.h"

namespace flsh {

/// The model as error messages name it: "body model '<source>'" ("body model" without a source).
std::string modelName(const BodyModel& model);

/// True if finalize() ran on the model's current arrays (vertex count and shape components).
bool isFinalized(const BodyModel& model);

/// Throws InputError "<who>: body model '<source>' is not finalized for its current arrays (call
/// BodyModel::finalize())" unless isFinalized(model).
void requireFinalized(const BodyModel& model, const std::string& who);

}  // namespace flsh
