// AMASS-style motion files (`.npz`): reading (SMPL or SMPL-H poses) and writing (SMPL poses).
#include <cmath>
#include <iostream>
#include <string>

#include "flsh/body/motion.h"
#include "flsh/body/motion_frame.h"
#include "flsh/body/smpl_skeleton.h"
#include "flsh/core/error.h"
#include "flsh/format/npz.h"

namespace flsh {

namespace {

constexpr double kDefaultFps = 30.0;

double readFrameRate(const io::NpzFile& file) {
  for (const char* key : {"mocap_framerate", "mocap_frame_rate"}) {
    if (!file.has(key)) continue;
    const double fps = file.scalar(key);  // rejects NaN/Inf
    if (!(fps > 0.0))
      throw InputError(file.path() + ": key '" + key + "': frame rate must be > 0, got " +
                       std::to_string(fps));
    return fps;
  }
  std::cerr << "flsh: warning: " << file.path()
            << ": no 'mocap_framerate' or 'mocap_frame_rate' key; assuming " << kDefaultFps
            << " fps\n";
  return kDefaultFps;
}

}  // namespace

Motion loadMotion(const std::string& path, const std::string& up) {
  const io::NpzFile file(path);
  Motion motion;
  motion.source = path;

  const RowMatX poses = file.matrix("poses");
  if (poses.cols() != kSmplPoseSize && poses.cols() != kSmplhPoseSize)
    throw InputError(path +
                     ": key 'poses': expected shape (T, 72) (SMPL) or (T, 156) (SMPL-H), "
                     "got " +
                     shapeString({long(poses.rows()), long(poses.cols())}));
  const long T = poses.rows();
  if (T < 1)
    throw InputError(path + ": key 'poses' has no frames, shape " +
                     shapeString({T, long(poses.cols())}));
  motion.poses = toSmplPoses(poses, path + ": key 'poses'");

  const RowMatX trans = file.matrix("trans", -1, 3);
  if (trans.rows() != T)
    throw InputError(path + ": key 'trans' has " + std::to_string(trans.rows()) +
                     " frames but key 'poses' has " + std::to_string(T) + " (shapes " +
                     shapeString({long(trans.rows()), 3}) + " and " +
                     shapeString({T, long(poses.cols())}) + ")");
  motion.trans = trans;

  if (file.has("betas")) {
    // AMASS stores (B,); some tools store (1, B).
    const std::vector<long>& shape = file.raw("betas").shape;
    if (shape.size() == 1) {
      motion.betas = file.vector("betas");
    } else if (shape.size() == 2 && shape[0] == 1) {
      motion.betas = file.matrix("betas", 1, -1).row(0).transpose();
    } else {
      throw InputError(path + ": key 'betas': expected shape (B,) or (1, B), got " +
                       shapeString(shape));
    }
  }
  motion.fps = readFrameRate(file);
  motion.gender = file.string("gender");

  // The clip's up axis: the caller's, else the file's own key, else AMASS's z up.
  if (!up.empty()) {
    worldFromUpAxis(up, path + ": up axis asked for");
    motion.up = up;
  } else if (file.has("up")) {
    motion.up = file.string("up");
    worldFromUpAxis(motion.up, path + ": key 'up'");
  } else {
    motion.up = "z";
  }
  if (motion.up != "y") rotateMotion(motion, worldFromUpAxis(motion.up));  // y: as stored
  const std::string warning = uprightWarning(motion);
  if (!warning.empty()) std::cerr << "flsh: warning: " << warning << "\n";
  return motion;
}

void saveMotion(const Motion& motion, const std::string& path, const std::string& up) {
  const Mat3 file_from_world = worldFromUpAxis(up, "saveMotion(" + path + "): up").transpose();
  const long T = motion.poses.rows();
  if (motion.poses.cols() != kSmplPoseSize)
    throw InputError("saveMotion(" + path + "): poses: expected shape (T, 72), got " +
                     shapeString({T, long(motion.poses.cols())}));
  if (motion.trans.rows() != T || motion.trans.cols() != 3)
    throw InputError("saveMotion(" + path + "): trans: expected shape " + shapeString({T, 3}) +
                     " (T from poses), got " +
                     shapeString({long(motion.trans.rows()), long(motion.trans.cols())}));
  if (!motion.poses.allFinite() || !motion.trans.allFinite() || !motion.betas.allFinite())
    throw InputError("saveMotion(" + path + "): poses, trans or betas contain NaN or Inf");
  if (!(motion.fps > 0.0) || !std::isfinite(motion.fps))
    throw InputError("saveMotion(" + path + "): fps must be finite and > 0, got " +
                     std::to_string(motion.fps));
  Motion stored = motion;
  if (up != "y") rotateMotion(stored, file_from_world);
  io::NpzWriter writer;
  writer.add("poses", stored.poses);
  writer.add("trans", stored.trans);
  writer.add("betas", motion.betas);
  writer.addScalar("mocap_framerate", motion.fps);
  if (!motion.gender.empty()) writer.addString("gender", motion.gender);
  writer.addString("up", up);
  writer.save(path);
}

}  // namespace flsh
