// Basic numeric types of flsh. Double precision everywhere, SI units (m, kg, s, Pa).
//
// Shapes are documented as `#V × 3` etc. Point sets and index lists are row-major so that
// a `#V × 3` matrix is the same memory as a numpy array of shape (V, 3).
#pragma once

#include <Eigen/Core>
#include <Eigen/SparseCore>

namespace flsh {

using Vec3 = Eigen::Vector3d;
using Vec4 = Eigen::Vector4d;
using Mat3 = Eigen::Matrix3d;
using Mat4 = Eigen::Matrix4d;
using VecX = Eigen::VectorXd;
using VecXi = Eigen::VectorXi;
using MatX = Eigen::MatrixXd;  // column-major, for linear algebra
/// Row-major dense matrix, for data that maps to numpy arrays (e.g. T × 72 poses).
using RowMatX = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
/// `#V × 3` points (vertex or node positions), row-major.
using MatX3 = Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>;
/// `#F × 3` triangle indices, row-major.
using MatX3i = Eigen::Matrix<int, Eigen::Dynamic, 3, Eigen::RowMajor>;
/// `#T × 4` tetrahedron indices, row-major.
using MatX4i = Eigen::Matrix<int, Eigen::Dynamic, 4, Eigen::RowMajor>;
using SpMat = Eigen::SparseMatrix<double>;                   // column-major sparse
using SpMatR = Eigen::SparseMatrix<double, Eigen::RowMajor>;  // row-major sparse
using Triplet = Eigen::Triplet<double>;

// Small fixed sizes: a bone's 6 DoFs (translation, rotation), 3 × 3 pairs, two bones.
using Vec6 = Eigen::Matrix<double, 6, 1>;
using Mat6 = Eigen::Matrix<double, 6, 6>;
using Vec9 = Eigen::Matrix<double, 9, 1>;
using Mat9 = Eigen::Matrix<double, 9, 9>;
using Vec12 = Eigen::Matrix<double, 12, 1>;
using Mat12 = Eigen::Matrix<double, 12, 12>;

}  // namespace flsh
