#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>

#include "flsh/body/motion.h"
#include "flsh/core/error.h"
#include "flsh/format/npz.h"
#include "format/raw_npz.h"
#include "support/test_support.h"

namespace flsh {
namespace {

using ::testing::HasSubstr;
namespace fs = std::filesystem;
using test::messageOf;

RowMatX randomMatrix(long rows, long cols, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> uni(-1.0, 1.0);
  RowMatX m(rows, cols);
  for (long k = 0; k < m.size(); ++k) m.data()[k] = uni(rng);
  return m;
}

/// Writes an AMASS-style file with the given arrays (any shapes), for error tests.
struct AmassFile {
  RowMatX poses = randomMatrix(5, 156, 1);
  RowMatX trans = randomMatrix(5, 3, 2);
  VecX betas = VecX::LinSpaced(16, -1.0, 1.0);
  double fps = 120.0;
  const char* fps_key = "mocap_framerate";
  std::string gender = "female";

  std::string write(const std::string& path) const {
    io::NpzWriter writer;
    writer.add("poses", poses);
    writer.add("trans", trans);
    writer.add("betas", betas);
    if (fps_key) writer.addScalar(fps_key, fps);
    if (!gender.empty()) writer.addString("gender", gender);
    writer.save(path, true);
    return path;
  }
};

TEST(MotionIo, RoundTripOfSmplPoses) {
  const std::string dir = test::freshTempDir("motion_roundtrip");
  Motion motion;
  motion.poses = randomMatrix(7, 72, 3);
  motion.trans = randomMatrix(7, 3, 4);
  motion.betas = VecX::LinSpaced(10, 0.0, 0.9);
  motion.fps = 59.94;
  motion.gender = "male";
  saveMotion(motion, dir + "/m.npz");
  EXPECT_EQ(std::vector<std::string>{"m.npz"},
            std::vector<std::string>{fs::directory_iterator(dir)->path().filename()});

  const Motion loaded = loadMotion(dir + "/m.npz");
  EXPECT_EQ(loaded.poses, motion.poses);
  EXPECT_EQ(loaded.trans, motion.trans);
  EXPECT_EQ(loaded.betas, motion.betas);
  EXPECT_EQ(loaded.fps, 59.94);
  EXPECT_EQ(loaded.gender, "male");
  EXPECT_EQ(loaded.source, dir + "/m.npz");
  EXPECT_EQ(loaded.numFrames(), 7);
  EXPECT_DOUBLE_EQ(loaded.duration(), 6 / 59.94);

  // The file is AMASS-shaped: poses T × 72, trans T × 3, a 0-d frame rate.
  const io::NpzFile file(dir + "/m.npz");
  EXPECT_EQ(file.raw("poses").shape, (std::vector<long>{7, 72}));
  EXPECT_EQ(file.raw("mocap_framerate").shape, std::vector<long>{});
}

TEST(MotionIo, EmptyBetasAndGenderRoundTrip) {
  const std::string path = test::freshTempDir("motion_minimal") + "/m.npz";
  Motion motion;
  motion.poses = randomMatrix(1, 72, 5);
  motion.trans = randomMatrix(1, 3, 6);
  saveMotion(motion, path);
  const Motion loaded = loadMotion(path);
  EXPECT_EQ(loaded.betas.size(), 0);
  EXPECT_EQ(loaded.gender, "");
  EXPECT_EQ(loaded.fps, 30.0);
  EXPECT_EQ(loaded.poses, motion.poses);
}

TEST(MotionIo, SmplhPosesKeepBodyJointsAndZeroTheHands) {
  const std::string dir = test::freshTempDir("motion_smplh");
  AmassFile amass;
  // Read as recorded y up, so that the values are the file's (AmassFrame tests the z-up turn).
  const Motion motion = loadMotion(amass.write(dir + "/smplh.npz"), "y");
  ASSERT_EQ(motion.poses.rows(), 5);
  ASSERT_EQ(motion.poses.cols(), 72);
  EXPECT_EQ(motion.poses.leftCols(66), amass.poses.leftCols(66));  // joints 0–21
  EXPECT_TRUE(motion.poses.rightCols(6).isZero(0.0));              // joints 22–23
  EXPECT_FALSE(amass.poses.middleCols(66, 6).isZero(0.0));         // the hands were not zero
  EXPECT_EQ(motion.trans, amass.trans);
  EXPECT_EQ(motion.betas, amass.betas);
  EXPECT_EQ(motion.fps, 120.0);
  EXPECT_EQ(motion.gender, "female");
}

TEST(MotionIo, AcceptsFloat32AlternateFrameRateKeyAndRowBetas) {
  const std::string path = test::freshTempDir("motion_float32") + "/f32.npz";
  std::vector<float> poses(2 * 72), trans(2 * 3);
  for (size_t k = 0; k < poses.size(); ++k) poses[k] = 0.01f * float(k);
  for (size_t k = 0; k < trans.size(); ++k) trans[k] = 0.5f * float(k);
  const std::vector<float> betas = {0.25f, -0.5f};
  const std::vector<double> rate = {50.0};
  test::writeRawZip(path, {{"poses.npy", test::npyOf("<f4", "(2, 72)", poses)},
                           {"trans.npy", test::npyOf("<f4", "(2, 3)", trans)},
                           {"betas.npy", test::npyOf("<f4", "(1, 2)", betas)},
                           {"mocap_frame_rate.npy", test::npyOf("<f8", "()", rate)}});
  const Motion motion = loadMotion(path, "y");
  EXPECT_EQ(motion.poses(1, 71), double(0.01f * 143.0f));
  EXPECT_EQ(motion.trans(1, 2), 2.5);
  EXPECT_EQ(motion.betas, (VecX(2) << 0.25, -0.5).finished());
  EXPECT_EQ(motion.fps, 50.0);
}

TEST(MotionIo, MissingFrameRateWarnsAndUses30) {
  const std::string path = test::freshTempDir("motion_nofps") + "/m.npz";
  AmassFile amass;
  amass.fps_key = nullptr;
  amass.write(path);
  ::testing::internal::CaptureStderr();
  const Motion motion = loadMotion(path);
  const std::string warning = ::testing::internal::GetCapturedStderr();
  EXPECT_EQ(motion.fps, 30.0);
  EXPECT_THAT(warning, HasSubstr(path));
  EXPECT_THAT(warning, HasSubstr("mocap_framerate"));
}

TEST(MotionIo, ErrorsNameFileKeyAndShapes) {
  const std::string dir = test::freshTempDir("motion_errors");
  {
    AmassFile bad;
    bad.trans = randomMatrix(4, 3, 7);
    const std::string path = bad.write(dir + "/frames.npz");
    const std::string message = messageOf<InputError>([&] { loadMotion(path); });
    EXPECT_THAT(message, HasSubstr(path + ": key 'trans' has 4 frames but key 'poses' has 5"));
    EXPECT_THAT(message, HasSubstr("(4, 3) and (5, 156)"));
  }
  {
    AmassFile bad;
    bad.poses = randomMatrix(5, 69, 8);
    const std::string path = bad.write(dir + "/columns.npz");
    EXPECT_THAT(messageOf<InputError>([&] { loadMotion(path); }),
                HasSubstr(path + ": key 'poses': expected shape (T, 72) (SMPL) or (T, 156) "
                                 "(SMPL-H), got (5, 69)"));
  }
  {
    AmassFile bad;
    bad.trans = randomMatrix(5, 4, 9);
    const std::string path = bad.write(dir + "/trans_cols.npz");
    EXPECT_THAT(messageOf<InputError>([&] { loadMotion(path); }),
                HasSubstr(path + ": key 'trans': expected shape (*, 3), got (5, 4)"));
  }
  {
    AmassFile bad;
    bad.poses(2, 7) = std::nan("");
    const std::string path = bad.write(dir + "/nan.npz");
    EXPECT_THAT(messageOf<InputError>([&] { loadMotion(path); }),
                HasSubstr(path + ": key 'poses': contains NaN or Inf"));
  }
  for (double fps : {0.0, -30.0, std::numeric_limits<double>::infinity()}) {
    AmassFile bad;
    bad.fps = fps;
    const std::string path = bad.write(dir + "/fps.npz");
    EXPECT_THAT(messageOf<InputError>([&] { loadMotion(path); }),
                HasSubstr(path + ": key 'mocap_framerate'"))
        << fps;
  }
  {
    const std::string path = dir + "/string_poses.npz";
    io::NpzWriter writer;
    writer.addString("poses", "not numbers");
    writer.add("trans", randomMatrix(1, 3, 1));
    writer.save(path);
    EXPECT_THAT(messageOf<InputError>([&] { loadMotion(path); }),
                HasSubstr(path + ": key 'poses': expected a numeric array, got dtype '<U11'"));
  }
  {
    const std::string path = dir + "/no_trans.npz";
    io::NpzWriter writer;
    writer.add("poses", randomMatrix(3, 72, 1));
    writer.save(path);
    EXPECT_THAT(messageOf<InputError>([&] { loadMotion(path); }),
                HasSubstr(path + ": missing key 'trans'"));
  }
  {
    const std::string path = dir + "/no_frames.npz";
    io::NpzWriter writer;
    writer.add("poses", RowMatX(0, 72));
    writer.add("trans", RowMatX(0, 3));
    writer.save(path);
    EXPECT_THAT(messageOf<InputError>([&] { loadMotion(path); }), HasSubstr("no frames"));
  }
  {
    AmassFile bad;
    const std::string path = dir + "/betas.npz";
    io::NpzWriter writer;
    writer.add("poses", bad.poses);
    writer.add("trans", bad.trans);
    writer.add("betas", randomMatrix(2, 3, 1));
    writer.save(path);
    EXPECT_THAT(messageOf<InputError>([&] { loadMotion(path); }),
                HasSubstr(path + ": key 'betas': expected shape (B,) or (1, B), got (2, 3)"));
  }
  EXPECT_THROW(loadMotion(dir + "/missing.npz"), FileError);
  const std::string garbage = dir + "/garbage.npz";
  std::ofstream(garbage) << "poses,trans\n1,2\n";
  EXPECT_THROW(loadMotion(garbage), InputError);
}

TEST(MotionIo, TruncatedFileIsAnInputError) {
  const std::string dir = test::freshTempDir("motion_truncated");
  const std::string path = AmassFile().write(dir + "/m.npz");
  std::vector<uint8_t> bytes = test::readFileBytes(path);
  bytes.resize(bytes.size() * 2 / 3);
  test::writeFileBytes(path, bytes);
  EXPECT_THAT(messageOf<InputError>([&] { loadMotion(path); }), HasSubstr(path));
}

TEST(MotionIo, SaveRejectsInvalidMotionsAndLeavesNoFile) {
  const std::string dir = test::freshTempDir("motion_bad_save");
  Motion motion;
  motion.poses = randomMatrix(3, 72, 1);
  motion.trans = randomMatrix(2, 3, 2);
  EXPECT_THAT(messageOf<InputError>([&] { saveMotion(motion, dir + "/a.npz"); }),
              HasSubstr("trans: expected shape (3, 3)"));
  motion.trans = randomMatrix(3, 3, 2);
  motion.poses = randomMatrix(3, 156, 1);
  EXPECT_THAT(messageOf<InputError>([&] { saveMotion(motion, dir + "/b.npz"); }),
              HasSubstr("poses: expected shape (T, 72), got (3, 156)"));
  motion.poses = randomMatrix(3, 72, 1);
  motion.fps = 0.0;
  EXPECT_THROW(saveMotion(motion, dir + "/c.npz"), InputError);
  motion.fps = 30.0;
  motion.trans(0, 0) = std::nan("");
  EXPECT_THROW(saveMotion(motion, dir + "/d.npz"), InputError);
  EXPECT_TRUE(fs::is_empty(dir));

  motion.trans(0, 0) = 0.0;
  std::ofstream(dir + "/file") << "x";
  EXPECT_THROW(saveMotion(motion, dir + "/file/m.npz"), FileError);
  EXPECT_FALSE(fs::exists(dir + "/file/m.npz"));
}

}  // namespace
}  // namespace flsh
