// Whether a body model's derived data matches its arrays, and the error that names the caller.
#include "flsh/body/model_finalized.h"

#include <gtest/gtest.h>

#include <string>

#include "flsh/core/error.h"
#include "support/test_support.h"

namespace flsh {
namespace {

TEST(ModelFinalized, FinalizedModelPassesAndChangedArraysDoNot) {
  BodyModel model = test::makeRandomModel(300, 10);
  model.source = "random.npz";
  EXPECT_TRUE(isFinalized(model));
  EXPECT_NO_THROW(requireFinalized(model, "caller"));

  BodyModel fresh;  // never finalized
  EXPECT_FALSE(isFinalized(fresh));

  BodyModel fewer_betas = model;  // shape components changed after finalize()
  fewer_betas.shapedirs = MatX(model.shapedirs.leftCols(4));
  EXPECT_FALSE(isFinalized(fewer_betas));
  const std::string message =
      test::messageOf<InputError>([&] { requireFinalized(fewer_betas, "SoftAvatar"); });
  EXPECT_EQ(message.rfind("SoftAvatar: body model 'random.npz' is not finalized", 0), 0u)
      << message;
  EXPECT_NE(message.find("call BodyModel::finalize()"), std::string::npos) << message;

  fewer_betas.finalize();
  EXPECT_TRUE(isFinalized(fewer_betas));
}

}  // namespace
}  // namespace flsh
