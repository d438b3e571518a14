# `cmake --install build --prefix <dir>`: the tools in <dir>/bin, the configs
# in <dir>/share/flat/configs, the headers in <dir>/include/flat, and the
# `flat` library (its module archives) with a CMake package in
# <dir>/lib/cmake/flat, so that find_package(flat) builds and links a program
# that embeds FLAT-C++ (tests/install/ checks all of it).
#
# Included before any target exists: the RPATH settings below become the
# targets' properties when they are created.
include(GNUInstallDirs)
include(CMakePackageConfigHelpers)

# Installed tools find libtorch, cudart and the other shared libraries where
# the build linked them (the torch wheel is not on the loader's path), and any
# shared library of ours in <prefix>/lib.
set(CMAKE_INSTALL_RPATH "$ORIGIN/../${CMAKE_INSTALL_LIBDIR}")
set(CMAKE_INSTALL_RPATH_USE_LINK_PATH ON)

set(FLAT_PACKAGE_DIR "${CMAKE_INSTALL_LIBDIR}/cmake/flat")

# Called once every module and executable exists (end of CMakeLists.txt).
function(flat_install)
  get_property(tools GLOBAL PROPERTY FLAT_TOOL_TARGETS)
  install(TARGETS ${tools} RUNTIME DESTINATION ${CMAKE_INSTALL_BINDIR})
  # Everything the install copies, without the tests:
  #   cmake --build build --target flat_tools && cmake --install build --prefix <dir>
  # (the tools link every module between them).
  add_custom_target(flat_tools)
  add_dependencies(flat_tools ${tools})

  # The library: the aggregate `flat`, every module archive, and the interface
  # targets that carry the dependencies and feature switches to a consumer.
  set(lib_targets flat ${FLAT_MODULE_TARGETS} flat_deps flat_png_jpeg flat_gltf)
  if(TARGET flat_model_sm90)
    list(APPEND lib_targets flat_model_sm90)
  endif()
  install(TARGETS ${lib_targets} EXPORT flatTargets
          ARCHIVE DESTINATION ${CMAKE_INSTALL_LIBDIR})
  install(EXPORT flatTargets NAMESPACE flat:: DESTINATION ${FLAT_PACKAGE_DIR})
  install(DIRECTORY ${CMAKE_SOURCE_DIR}/include/flat DESTINATION ${CMAKE_INSTALL_INCLUDEDIR})
  install(DIRECTORY ${CMAKE_SOURCE_DIR}/configs DESTINATION ${CMAKE_INSTALL_DATADIR}/flat)

  # Where this build found each dependency: hints for flatConfig.cmake (a
  # consumer's own <Pkg>_DIR or CMAKE_PREFIX_PATH still wins).
  set(FLAT_DEPENDENCY_HINTS "")
  foreach(pkg Torch yaml-cpp spdlog CLI11 nlohmann_json glm nanoflann OpenImageIO TinyGLTF)
    if(${pkg}_DIR AND EXISTS "${${pkg}_DIR}")
      string(APPEND FLAT_DEPENDENCY_HINTS "set(_flat_hint_${pkg} \"${${pkg}_DIR}\")\n")
    endif()
  endforeach()
  configure_package_config_file(${CMAKE_SOURCE_DIR}/cmake/flatConfig.cmake.in
                                ${CMAKE_BINARY_DIR}/flatConfig.cmake
                                INSTALL_DESTINATION ${FLAT_PACKAGE_DIR})
  write_basic_package_version_file(${CMAKE_BINARY_DIR}/flatConfigVersion.cmake
                                   COMPATIBILITY SameMinorVersion)
  install(FILES ${CMAKE_BINARY_DIR}/flatConfig.cmake ${CMAKE_BINARY_DIR}/flatConfigVersion.cmake
          DESTINATION ${FLAT_PACKAGE_DIR})
endfunction()
