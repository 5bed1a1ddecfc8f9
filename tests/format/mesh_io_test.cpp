// Tests of PLY/OBJ mesh files: exact round trips, colours, foreign PLY layouts (extra
// properties, other elements, float coordinates), OBJ index forms, and rejected input.
#include "flsh/format/mesh_io.h"

#include <gtest/gtest.h>

#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <sstream>

#include "flsh/core/error.h"
#include "support/test_support.h"

namespace flsh::io {
namespace {

namespace fs = std::filesystem;

// A tetrahedron with coordinates that have no short decimal form (exactness is tested).
void tetrahedron(MatX3& V, MatX3i& F) {
  V.resize(4, 3);
  V << 0.1, 1.0 / 3.0, -2.718281828459045,  //
      12345.678901234567, 1e-17, -0.0,      //
      -7.25, 3.141592653589793, 1e300,      //
      0.30000000000000004, -1.0 / 7.0, 2.5e-8;
  F.resize(4, 3);
  F << 0, 1, 2,  //
      0, 3, 1,   //
      1, 3, 2,   //
      2, 3, 0;
}

void writeText(const std::string& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary);
  out << text;
}

std::string readText(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream buffer;
  buffer << in.rdbuf();
  return buffer.str();
}

// Runs readMesh and returns the InputError message ("" if it did not throw one).
std::string readError(const std::string& path) {
  MatX3 V;
  MatX3i F;
  try {
    readMesh(path, V, F);
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

bool onlyFile(const std::string& dir, const std::string& name) {
  int count = 0;
  bool found = false;
  for (const auto& entry : fs::directory_iterator(dir)) {
    ++count;
    found |= entry.path().filename() == name;
  }
  return found && count == 1;
}

void appendF32(std::string& out, float f) {
  uint32_t bits;
  std::memcpy(&bits, &f, 4);
  for (int b = 0; b < 4; ++b) out.push_back(char((bits >> (8 * b)) & 0xff));
}
void appendI32(std::string& out, int32_t v) {
  for (int b = 0; b < 4; ++b) out.push_back(char((uint32_t(v) >> (8 * b)) & 0xff));
}

TEST(MeshIo, BinaryPlyRoundTripIsExact) {
  const std::string dir = test::freshTempDir("mesh_io_binary_ply");
  MatX3 V, V2;
  MatX3i F, F2;
  tetrahedron(V, F);
  const std::string path = dir + "/tet.ply";
  writePly(path, V, F);
  EXPECT_EQ(readText(path).find("format binary_little_endian 1.0\n"), 4u);
  readMesh(path, V2, F2);
  EXPECT_EQ(V2, V);  // bitwise: x, y, z are stored as double
  EXPECT_EQ(F2, F);
  EXPECT_TRUE(onlyFile(dir, "tet.ply"));  // no temporary file left behind
}

TEST(MeshIo, AsciiPlyRoundTripIsExact) {
  const std::string dir = test::freshTempDir("mesh_io_ascii_ply");
  MatX3 V, V2;
  MatX3i F, F2;
  tetrahedron(V, F);
  const std::string path = dir + "/tet.ply";
  writePly(path, V, F, Colors(), /*binary=*/false);
  EXPECT_NE(readText(path).find("format ascii 1.0\n"), std::string::npos);
  readMesh(path, V2, F2);
  EXPECT_EQ(V2, V);  // shortest round-trip decimal text
  EXPECT_EQ(F2, F);
}

TEST(MeshIo, ObjRoundTripIsExact) {
  const std::string dir = test::freshTempDir("mesh_io_obj");
  MatX3 V, V2;
  MatX3i F, F2;
  tetrahedron(V, F);
  const std::string path = dir + "/tet.obj";
  writeObj(path, V, F);
  readMesh(path, V2, F2);
  EXPECT_EQ(V2, V);
  EXPECT_EQ(F2, F);
  EXPECT_NE(readText(path).find("\nf 1 2 3\n"), std::string::npos);  // 1-based on disk
}

TEST(MeshIo, ColorsAreWrittenAsBytes) {
  const std::string dir = test::freshTempDir("mesh_io_colors");
  MatX3 V, V2;
  MatX3i F, F2;
  tetrahedron(V, F);
  Colors colors(4, 3);
  colors << 1.0, 0.0, 0.5,  //
      0.2, 0.4, 0.6,        //
      1.2, -0.1, 1.0,       // slightly out of [0, 1]: clamped
      0.0, 0.0, 0.0;

  const std::string ascii = dir + "/ascii.ply";
  writePly(ascii, V, F, colors, /*binary=*/false);
  const std::string text = readText(ascii);
  EXPECT_NE(text.find("property uchar red\nproperty uchar green\nproperty uchar blue\n"),
            std::string::npos);
  const size_t body = text.find("end_header\n") + std::strlen("end_header\n");
  std::istringstream lines(text.substr(body));
  std::vector<std::string> vertex_lines(4);
  for (auto& line : vertex_lines) std::getline(lines, line);
  EXPECT_EQ(vertex_lines[0].substr(vertex_lines[0].size() - 9), "255 0 128");
  EXPECT_EQ(vertex_lines[1].substr(vertex_lines[1].size() - 10), "51 102 153");
  EXPECT_EQ(vertex_lines[2].substr(vertex_lines[2].size() - 9), "255 0 255");

  const std::string binary = dir + "/binary.ply";
  writePly(binary, V, F, colors);
  const std::string bytes = readText(binary);
  const size_t header = bytes.find("end_header\n") + std::strlen("end_header\n");
  ASSERT_EQ(bytes.size(), header + 4 * (3 * 8 + 3) + 4 * (1 + 3 * 4));
  EXPECT_EQ(uint8_t(bytes[header + 24]), 255);  // vertex 0: red, green, blue
  EXPECT_EQ(uint8_t(bytes[header + 25]), 0);
  EXPECT_EQ(uint8_t(bytes[header + 26]), 128);
  readMesh(binary, V2, F2);  // the colour bytes are skipped
  EXPECT_EQ(V2, V);
  EXPECT_EQ(F2, F);
}

TEST(MeshIo, ReadsForeignAsciiPlyWithExtraProperties) {
  const std::string dir = test::freshTempDir("mesh_io_foreign_ascii");
  const std::string path = dir + "/foreign.ply";
  writeText(path,
            "ply\r\n"
            "format ascii 1.0\r\n"
            "comment from another program\r\n"
            "element vertex 4\r\n"
            "property float nx\r\n"
            "property float x\r\n"
            "property list uchar float tags\r\n"
            "property float y\r\n"
            "property float z\r\n"
            "property uchar red\r\n"
            "element face 2\r\n"
            "property uchar flags\r\n"
            "property list uchar uint vertex_index\r\n"
            "element edge 1\r\n"
            "property int vertex1\r\n"
            "property int vertex2\r\n"
            "end_header\r\n"
            "9 0 2 7 7 0 0 1\r\n"
            "9 1 0 0 0 2\r\n"
            "9 1 1 5 1 0 3\r\n"
            "9 0.5 3 1 2 3 1 0.25 4\r\n"
            "0 3 0 1 2\r\n"
            "1 3 0 2 3\r\n"
            "0 1\r\n");
  MatX3 V;
  MatX3i F;
  readMesh(path, V, F);
  MatX3 expected_V(4, 3);
  expected_V << 0, 0, 0,  //
      1, 0, 0,            //
      1, 1, 0,            //
      0.5, 1, 0.25;
  MatX3i expected_F(2, 3);
  expected_F << 0, 1, 2,  //
      0, 2, 3;
  EXPECT_EQ(V, expected_V);
  EXPECT_EQ(F, expected_F);
}

TEST(MeshIo, ReadsForeignBinaryPlyWithFloatCoordinates) {
  const std::string dir = test::freshTempDir("mesh_io_foreign_binary");
  const std::string path = dir + "/foreign.ply";
  std::string data =
      "ply\nformat binary_little_endian 1.0\nelement vertex 3\n"
      "property float x\nproperty float y\nproperty float z\nproperty uchar alpha\n"
      "element face 1\nproperty list int int vertex_indices\nproperty double quality\n"
      "end_header\n";
  const float coordinates[3][3] = {{0.5f, -1.25f, 2.0f}, {3.0f, 0.0f, 0.125f}, {1.0f, 1.0f, 1.0f}};
  for (const auto& row : coordinates) {
    for (float c : row) appendF32(data, c);
    data.push_back(char(200));
  }
  appendI32(data, 3);
  appendI32(data, 2);
  appendI32(data, 0);
  appendI32(data, 1);
  data.append(8, '\0');  // quality
  writeText(path, data);
  MatX3 V;
  MatX3i F;
  readMesh(path, V, F);
  ASSERT_EQ(V.rows(), 3);
  for (int i = 0; i < 3; ++i) {
    for (int c = 0; c < 3; ++c) EXPECT_EQ(V(i, c), double(coordinates[i][c]));
  }
  ASSERT_EQ(F.rows(), 1);
  EXPECT_EQ(F.row(0), Eigen::RowVector3i(2, 0, 1));

  // The same file without its last bytes is rejected as truncated.
  writeText(path, data.substr(0, data.size() - 5));
  const std::string message = readError(path);
  EXPECT_NE(message.find("truncated"), std::string::npos) << message;
  EXPECT_NE(message.find(path), std::string::npos) << message;
}

// An element without properties takes no bytes, so its count is not bounded by the file
// size: a count of 10^18 was iterated row by row (a hang); it is skipped.
TEST(MeshIo, PropertylessElementsWithHugeCountsAreSkipped) {
  const std::string path = test::freshTempDir("mesh_io_propertyless") + "/marker.ply";
  writeText(path,
            "ply\nformat ascii 1.0\nelement marker 1000000000000000000\nelement vertex 3\n"
            "property double x\nproperty double y\nproperty double z\nelement face 1\n"
            "property list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n1 1 0\n3 0 1 2\n");
  MatX3 V;
  MatX3i F;
  readMesh(path, V, F);
  EXPECT_EQ(V.rows(), 3);
  EXPECT_EQ(F.rows(), 1);
}

TEST(MeshIo, ReadsObjIndexFormsAndNegativeIndices) {
  const std::string dir = test::freshTempDir("mesh_io_obj_forms");
  const std::string path = dir + "/forms.obj";
  writeText(path,
            "# a comment\n"
            "mtllib none.mtl\n"
            "o square\n"
            "v 0 0 0\n"
            "v 1 0 0 1.0\n"
            "v 1 1 0\n"
            "vt 0 0\nvt 1 0\nvt 1 1\n"
            "vn 0 0 1\n"
            "s off\n"
            "f 1/1/1 2/2/1 3/3/1\n"
            "v 0 1 0   # trailing comment\n"
            "f -4//1 -2//1 -1//1\n"
            "f 2/1 3/2 4/3\n");
  MatX3 V;
  MatX3i F;
  readMesh(path, V, F);
  ASSERT_EQ(V.rows(), 4);
  EXPECT_EQ(V.row(3), Eigen::RowVector3d(0, 1, 0));
  MatX3i expected(3, 3);
  expected << 0, 1, 2,  //
      0, 2, 3,          //
      1, 2, 3;
  EXPECT_EQ(F, expected);
}

TEST(MeshIo, RejectsMalformedFilesWithMessages) {
  const std::string dir = test::freshTempDir("mesh_io_malformed");
  struct Case {
    std::string name, text, expected;
  };
  const std::string ply_header =
      "ply\nformat ascii 1.0\nelement vertex 3\nproperty double x\nproperty double y\n"
      "property double z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n";
  const std::vector<Case> cases = {
      {"quad.ply",
       "ply\nformat ascii 1.0\nelement vertex 4\nproperty double x\nproperty double y\n"
       "property double z\nelement face 1\nproperty list uchar int vertex_indices\n"
       "end_header\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n",
       "only triangles"},
      {"range.ply", ply_header + "0 0 0\n1 0 0\n1 1 0\n3 0 1 7\n", "vertex index 7"},
      {"negative.ply", ply_header + "0 0 0\n1 0 0\n1 1 0\n3 0 -1 2\n", "vertex index -1"},
      {"short.ply", ply_header + "0 0 0\n1 0 0\n1 1 0\n3 0 1\n", "truncated"},
      {"word.ply", ply_header + "0 0 0\n1 zero 0\n1 1 0\n3 0 1 2\n", "'zero'"},
      {"nan.ply", ply_header + "0 0 0\n1 nan 0\n1 1 0\n3 0 1 2\n", "non-finite"},
      {"noend.ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty double x\n", "end_header"},
      {"noz.ply",
       "ply\nformat ascii 1.0\nelement vertex 1\nproperty double x\nproperty double y\n"
       "end_header\n0 0\n",
       "'z'"},
      {"huge.ply",
       "ply\nformat binary_little_endian 1.0\nelement vertex 1000000000000\n"
       "property double x\nproperty double y\nproperty double z\nend_header\n",
       "truncated"},
      // Rows whose byte count overflows a 64-bit integer (found by fuzz_mesh under UBSan).
      {"hugebody.ply",
       "ply\nformat ascii 1.0\nelement vertex 1\nproperty double x\nproperty double y\n"
       "property double z\nelement junk 1000000000000000000\nproperty double a\n"
       "property double b\nproperty double c\nproperty double d\nproperty double e\n"
       "end_header\n0 0 0\n",
       "need at least 10000000000000000000 bytes"},
      {"notply.ply", "solid cube\n", "not a PLY file"},
      {"quad.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n", "only triangles"},
      {"range.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 9\n", "out of range"},
      {"before.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nf -4 1 2\n", "before the first vertex"},
      {"zero.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nf 0 1 2\n", "bad face vertex"},
      {"badv.obj", "v 0 0\nv 1 0 0\n", "line 1"},
      {"mesh.stl", "solid cube\n", "unknown mesh format"},
      // Hostile headers and values (issue 23): clean errors, no huge allocation.
      {"hugefaces.ply",
       "ply\nformat ascii 1.0\nelement vertex 3\nproperty double x\nproperty double y\n"
       "property double z\nelement face 99999999999\nproperty list uchar int vertex_indices\n"
       "end_header\n0 0 0\n1 0 0\n1 1 0\n3 0 1 2\n",
       "truncated"},
      {"overflowcount.ply",
       "ply\nformat ascii 1.0\nelement vertex 99999999999999999999999\nproperty double x\n"
       "end_header\n",
       "expected 'element <name> <count>'"},
      {"negativecount.ply",
       "ply\nformat ascii 1.0\nelement vertex -3\nproperty double x\nend_header\n",
       "expected 'element <name> <count>'"},
      {"floatindex.ply",
       "ply\nformat ascii 1.0\nelement vertex 3\nproperty double x\nproperty double y\n"
       "property double z\nelement face 1\nproperty list uchar float vertex_indices\n"
       "end_header\n0 0 0\n1 0 0\n1 1 0\n3 0 1 nan\n",
       "floating-point item type"},
      {"hugeindex.ply", ply_header + "0 0 0\n1 0 0\n1 1 0\n3 0 1 99999999999999999999\n",
       "expected an integer"},
      {"inf.ply", ply_header + "0 0 0\n1 0 inf\n1 1 0\n3 0 1 2\n", "non-finite"},
      {"nan.obj", "v 0 0 0\nv 1 nan 0\nv 1 1 0\nf 1 2 3\n", "needs 3 finite coordinates"},
      {"hugeindex.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 99999999999999999999\n",
       "bad face vertex"},
      {"bigindex.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 9999999999\n", "too large"},
      {"negativeindex.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 -99999999999\n",
       "before the first vertex"},
  };
  for (const Case& c : cases) {
    const std::string path = dir + "/" + c.name;
    writeText(path, c.text);
    const std::string message = readError(path);
    EXPECT_NE(message.find(c.expected), std::string::npos)
        << c.name << ": expected '" << c.expected << "' in: " << message;
    EXPECT_NE(message.find(path), std::string::npos) << c.name << ": " << message;
  }
  MatX3 V;
  MatX3i F;
  EXPECT_THROW(readMesh(dir + "/missing.ply", V, F), FileError);
}

TEST(MeshIo, WritersCheckTheirArguments) {
  const std::string dir = test::freshTempDir("mesh_io_arguments");
  MatX3 V;
  MatX3i F;
  tetrahedron(V, F);
  const std::string path = dir + "/bad.ply";
  auto message = [](const std::function<void()>& write) -> std::string {
    try {
      write();
    } catch (const InputError& e) {
      return e.what();
    }
    return "";
  };

  MatX3 nan_V = V;
  nan_V(2, 1) = std::numeric_limits<double>::quiet_NaN();
  std::string text = message([&] { writePly(path, nan_V, F); });
  EXPECT_NE(text.find("argument V"), std::string::npos) << text;
  EXPECT_NE(text.find("row 2"), std::string::npos) << text;
  text = message([&] { writeObj(path, nan_V, F); });
  EXPECT_NE(text.find("non-finite"), std::string::npos) << text;

  MatX3i bad_F = F;
  bad_F(1, 2) = 4;
  text = message([&] { writePly(path, V, bad_F); });
  EXPECT_NE(text.find("argument F"), std::string::npos) << text;
  EXPECT_NE(text.find("index 4"), std::string::npos) << text;
  bad_F(1, 2) = -1;
  text = message([&] { writeObj(path, V, bad_F); });
  EXPECT_NE(text.find("index -1"), std::string::npos) << text;

  const Colors short_colors = Colors::Constant(3, 3, 0.5);
  text = message([&] { writePly(path, V, F, short_colors); });
  EXPECT_NE(text.find("colors"), std::string::npos) << text;
  EXPECT_NE(text.find("(3, 3)"), std::string::npos) << text;
  EXPECT_NE(text.find("(4, 3)"), std::string::npos) << text;
  Colors nan_colors = Colors::Constant(4, 3, 0.5);
  nan_colors(0, 0) = std::numeric_limits<double>::infinity();
  text = message([&] { writePly(path, V, F, nan_colors); });
  EXPECT_NE(text.find("non-finite"), std::string::npos) << text;

  EXPECT_TRUE(fs::is_empty(dir));  // nothing written by a rejected call
}

TEST(MeshIo, UnwritablePathThrowsFileErrorAndLeavesNoFile) {
  const std::string dir = test::freshTempDir("mesh_io_unwritable");
  MatX3 V;
  MatX3i F;
  tetrahedron(V, F);
  writeText(dir + "/a_file", "x");
  EXPECT_THROW(writePly(dir + "/a_file/mesh.ply", V, F), FileError);
  fs::create_directory(dir + "/a_dir");
  EXPECT_THROW(writeObj(dir + "/a_dir", V, F), FileError);  // target is a directory
  EXPECT_EQ(std::distance(fs::directory_iterator(dir), fs::directory_iterator()), 2);
  EXPECT_TRUE(fs::is_empty(dir + "/a_dir"));
}

TEST(MeshIo, EmptyMeshRoundTrips) {
  const std::string dir = test::freshTempDir("mesh_io_empty");
  MatX3 V(0, 3), V2;
  MatX3i F(0, 3), F2;
  writePly(dir + "/empty.ply", V, F);
  readMesh(dir + "/empty.ply", V2, F2);
  EXPECT_EQ(V2.rows(), 0);
  EXPECT_EQ(F2.rows(), 0);
}

}  // namespace
}  // namespace flsh::io
