# FindCHOLMOD: SuiteSparse's CHOLMOD without a CMake config (Debian 12 ships SuiteSparse 5.12,
# whose packages have none). Defines CHOLMOD_FOUND, CHOLMOD_INCLUDE_DIR, CHOLMOD_LIBRARIES and
# the imported target CHOLMOD::CHOLMOD (cholmod + suitesparseconfig).
include(FindPackageHandleStandardArgs)

find_path(CHOLMOD_INCLUDE_DIR cholmod.h
  PATH_SUFFIXES suitesparse
  HINTS ${CHOLMOD_ROOT} ENV CHOLMOD_ROOT
  PATHS /usr/include /usr/local/include)
find_library(CHOLMOD_LIBRARY NAMES cholmod
  HINTS ${CHOLMOD_ROOT} ENV CHOLMOD_ROOT)
find_library(SUITESPARSECONFIG_LIBRARY NAMES suitesparseconfig
  HINTS ${CHOLMOD_ROOT} ENV CHOLMOD_ROOT)

find_package_handle_standard_args(CHOLMOD
  REQUIRED_VARS CHOLMOD_LIBRARY SUITESPARSECONFIG_LIBRARY CHOLMOD_INCLUDE_DIR)

if(CHOLMOD_FOUND)
  set(CHOLMOD_LIBRARIES ${CHOLMOD_LIBRARY} ${SUITESPARSECONFIG_LIBRARY})
  if(NOT TARGET SuiteSparse::suitesparseconfig)
    add_library(SuiteSparse::suitesparseconfig UNKNOWN IMPORTED)
    set_target_properties(SuiteSparse::suitesparseconfig PROPERTIES
      IMPORTED_LOCATION "${SUITESPARSECONFIG_LIBRARY}"
      INTERFACE_INCLUDE_DIRECTORIES "${CHOLMOD_INCLUDE_DIR}")
  endif()
  if(NOT TARGET CHOLMOD::CHOLMOD)
    add_library(CHOLMOD::CHOLMOD UNKNOWN IMPORTED)
    set_target_properties(CHOLMOD::CHOLMOD PROPERTIES
      IMPORTED_LOCATION "${CHOLMOD_LIBRARY}"
      INTERFACE_INCLUDE_DIRECTORIES "${CHOLMOD_INCLUDE_DIR}"
      INTERFACE_LINK_LIBRARIES SuiteSparse::suitesparseconfig)
  endif()
endif()
mark_as_advanced(CHOLMOD_INCLUDE_DIR CHOLMOD_LIBRARY SUITESPARSECONFIG_LIBRARY)
