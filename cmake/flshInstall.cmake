# Install rules: `cmake --install build [--prefix P]` installs
#   P/lib/libflsh.a, libflsh_cgal.a, libflsh_ceres.a   the static libraries
#   P/include/flsh/...                                 the public headers
#   P/bin/flsh                                         the command-line program
#   P/lib/cmake/flsh/                                  the CMake package: find_package(flsh CONFIG)
#                                                      gives flsh::flsh and flsh::ceres
#   P/${FLSH_PYTHON_INSTALL_DIR}/flsh/                 the Python package (module + .py files)
# The libraries are static, so the package's config finds their private dependencies too
# (CHOLMOD, libzip, PNG, CGAL: all Debian packages) for the consumer's link.
include(GNUInstallDirs)
include(CMakePackageConfigHelpers)

set(FLSH_CMAKE_INSTALL_DIR ${CMAKE_INSTALL_LIBDIR}/cmake/flsh)

set(flsh_install_targets flsh flsh_cli)
if(TARGET flsh_cgal)
  list(APPEND flsh_install_targets flsh_cgal)
endif()
if(TARGET flsh_ceres)
  list(APPEND flsh_install_targets flsh_ceres)
  set_target_properties(flsh_ceres PROPERTIES EXPORT_NAME ceres)
endif()
install(TARGETS ${flsh_install_targets} EXPORT flshTargets
  ARCHIVE DESTINATION ${CMAKE_INSTALL_LIBDIR}
  LIBRARY DESTINATION ${CMAKE_INSTALL_LIBDIR}
  RUNTIME DESTINATION ${CMAKE_INSTALL_BINDIR}
  INCLUDES DESTINATION ${CMAKE_INSTALL_INCLUDEDIR})
install(DIRECTORY ${CMAKE_SOURCE_DIR}/include/flsh DESTINATION ${CMAKE_INSTALL_INCLUDEDIR})
install(EXPORT flshTargets NAMESPACE flsh:: DESTINATION ${FLSH_CMAKE_INSTALL_DIR})

set(FLSH_HAS_CERES_TARGET OFF)
if(TARGET flsh_ceres)
  set(FLSH_HAS_CERES_TARGET ON)
endif()
configure_package_config_file(${CMAKE_SOURCE_DIR}/cmake/flshConfig.cmake.in
  ${CMAKE_BINARY_DIR}/flshConfig.cmake INSTALL_DESTINATION ${FLSH_CMAKE_INSTALL_DIR})
write_basic_package_version_file(${CMAKE_BINARY_DIR}/flshConfigVersion.cmake
  COMPATIBILITY SameMinorVersion)
install(FILES ${CMAKE_BINARY_DIR}/flshConfig.cmake ${CMAKE_BINARY_DIR}/flshConfigVersion.cmake
  ${CMAKE_SOURCE_DIR}/cmake/FindCHOLMOD.cmake DESTINATION ${FLSH_CMAKE_INSTALL_DIR})

# Python: where the interpreter the build uses finds packages under the prefix. On Debian both
# /usr/local/lib/python3.X/dist-packages (the default prefix) and /usr/lib/python3.X/dist-packages
# are on /usr/bin/python3's path, so `import flsh` works from any folder without PYTHONPATH.
if(TARGET _flsh)
  if(NOT FLSH_PYTHON_INSTALL_DIR)
    execute_process(
      COMMAND ${Python_EXECUTABLE} -c
        "import sys; print('lib/python%d.%d/%s' % (sys.version_info[0], sys.version_info[1], 'dist-packages' if any(p.endswith('dist-packages') for p in sys.path) else 'site-packages'))"
      OUTPUT_VARIABLE flsh_python_dir OUTPUT_STRIP_TRAILING_WHITESPACE)
    set(FLSH_PYTHON_INSTALL_DIR ${flsh_python_dir} CACHE STRING
      "Python package folder, relative to the install prefix")
  endif()
  install(TARGETS _flsh LIBRARY DESTINATION ${FLSH_PYTHON_INSTALL_DIR}/flsh)
  install(DIRECTORY ${CMAKE_SOURCE_DIR}/python/flsh/ DESTINATION ${FLSH_PYTHON_INSTALL_DIR}/flsh
    FILES_MATCHING PATTERN "*.py" PATTERN "__pycache__" EXCLUDE)
endif()
