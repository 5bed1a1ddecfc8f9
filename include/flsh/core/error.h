// Errors of flsh. Every error is an exception whose message names the input (file, key,
// argument), what was expected and what was found. The Python module maps InputError to
// ValueError and FileError to OSError.
#pragma once

#include <stdexcept>
#include <string>
#include <vector>

namespace flsh {

/// Base class of all flsh errors.
class Error : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// Bad input data: wrong shape, dtype, value (NaN/Inf), missing key, malformed file content.
class InputError : public Error {
 public:
  using Error::Error;
};

/// A file that cannot be opened, read or written.
class FileError : public Error {
 public:
  using Error::Error;
};

/// "(2, 24)" style text of a shape, for error messages.
std::string shapeString(const std::vector<long>& shape);

}  // namespace flsh
