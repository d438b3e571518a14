# Every third-party dependency, found through find_package. Nothing is
# downloaded at configure time and no third-party code is copied into the tree.
find_package(Threads REQUIRED)
find_package(yaml-cpp REQUIRED)
find_package(spdlog REQUIRED)
find_package(CLI11 REQUIRED)
find_package(nlohmann_json 3 REQUIRED)
# Header-only packages extracted from Debian's .debs into .deps (the GPU
# machine cannot install them; scripts/prepare_device_carry.sh) are found
# there without a CMAKE_PREFIX_PATH.
foreach(_carried glm nanoflann)
  if(EXISTS "${CMAKE_SOURCE_DIR}/.deps/${_carried}/usr")
    list(APPEND CMAKE_PREFIX_PATH "${CMAKE_SOURCE_DIR}/.deps/${_carried}/usr")
  endif()
endforeach()
find_package(glm REQUIRED)   # on the GPU machine: a carried prefix (see README, GPU build)
# KD-tree of the mesh stitching (Debian libnanoflann-dev, header-only; carried like GLM to the GPU machine).
find_package(nanoflann REQUIRED)

if(FLAT_WITH_OIIO)
  find_package(OpenImageIO REQUIRED)
endif()

# libpng and libjpeg(-turbo) (Debian libpng-dev, libjpeg62-turbo-dev): PNG and
# JPEG files without OpenImageIO (src/core/png_jpeg_io.cpp; read_image and
# write_image use them when FLAT_WITH_OIIO is off). Looked up in every build,
# OpenImageIO or not, so that the OpenImageIO build tests the two against
# each other; without them only OpenImageIO reads images. Like flat_gltf, the
# switch is its own target, linked PRIVATE by the core module alone (tests
# ask png_jpeg_available()), so that it does not change the shared
# precompiled header's flags.
set(FLAT_PNG_JPEG_FOUND OFF)
find_package(PNG QUIET)
find_package(JPEG QUIET)
if(TARGET PNG::PNG AND TARGET JPEG::JPEG)
  set(FLAT_PNG_JPEG_FOUND ON)
else()
  message(STATUS "libpng/libjpeg not found (Debian libpng-dev, libjpeg62-turbo-dev): "
                 "without OpenImageIO, PNG/JPEG files cannot be read")
endif()
add_library(flat_png_jpeg INTERFACE)
target_compile_definitions(flat_png_jpeg INTERFACE FLAT_WITH_PNG_JPEG=$<BOOL:${FLAT_PNG_JPEG_FOUND}>)
if(FLAT_PNG_JPEG_FOUND)
  target_link_libraries(flat_png_jpeg INTERFACE PNG::PNG JPEG::JPEG)
endif()

# tinygltf (Debian libtinygltf-dev, a shared library there): the GLB writer of
# the export module. Optional: Ubuntu has no package, and without it only the
# GLB functions fail (the PLY export still works). The switch is carried by
# flat_gltf, linked PRIVATE by the export module alone, so that turning it on
# or off recompiles that module only (not the shared precompiled header).
set(FLAT_GLTF_FOUND OFF)
if(FLAT_WITH_GLTF)
  find_package(TinyGLTF QUIET)
  if(TARGET TinyGLTF::TinyGLTF)
    set(FLAT_GLTF_FOUND ON)
  else()
    message(STATUS "tinygltf not found (Debian libtinygltf-dev): GLB export disabled, PLY export still works")
  endif()
endif()
add_library(flat_gltf INTERFACE)
target_compile_definitions(flat_gltf INTERFACE FLAT_WITH_GLTF=$<BOOL:${FLAT_GLTF_FOUND}>)
if(FLAT_GLTF_FOUND)
  target_link_libraries(flat_gltf INTERFACE TinyGLTF::TinyGLTF)
endif()

if(FLAT_WITH_CUDA)
  if(NOT DEFINED CMAKE_CUDA_ARCHITECTURES)
    set(CMAKE_CUDA_ARCHITECTURES 90)  # H100 / H200
  endif()
  # Shared cudart: the same runtime instance as libtorch_cuda, so streams agree.
  set(CMAKE_CUDA_RUNTIME_LIBRARY Shared)
  enable_language(CUDA)
  find_package(CUDAToolkit REQUIRED)
  # Torch's CMake ignores CMAKE_CUDA_ARCHITECTURES and would otherwise probe a
  # GPU (none on CI) and fall back to every architecture.
  if(NOT DEFINED ENV{TORCH_CUDA_ARCH_LIST})
    set(ENV{TORCH_CUDA_ARCH_LIST} "9.0")
  endif()
endif()

# libtorch: PyTorch's own, from the torch wheel. The Python that holds the
# wheel is looked up on every configure (not only the first): the CUTLASS
# lookup below asks the same Python for the nvidia-cutlass wheel, and a second
# configure of an existing build folder finds Torch_DIR already cached.
set(FLAT_TORCH_PYTHON "" CACHE FILEPATH "python3 whose torch wheel provides libtorch")
set(_py "${FLAT_TORCH_PYTHON}")
# The venv that scripts/install_deps.sh makes, then any python3 on PATH.
if(NOT _py AND EXISTS "$ENV{HOME}/.cache/flat/venv/bin/python3")
  set(_py "$ENV{HOME}/.cache/flat/venv/bin/python3")
endif()
if(NOT _py)
  find_program(FLAT_PYTHON3 NAMES python3)
  set(_py "${FLAT_PYTHON3}")
endif()
if(NOT Torch_DIR AND _py)
  execute_process(COMMAND "${_py}" -c "import torch.utils; print(torch.utils.cmake_prefix_path)"
                  OUTPUT_VARIABLE _torch_prefix OUTPUT_STRIP_TRAILING_WHITESPACE
                  RESULT_VARIABLE _torch_rc ERROR_QUIET)
  if(_torch_rc EQUAL 0 AND _torch_prefix)
    list(APPEND CMAKE_PREFIX_PATH "${_torch_prefix}")
  endif()
endif()
find_package(Torch REQUIRED)
message(STATUS "libtorch ${Torch_VERSION} from ${Torch_DIR}")

# NCCL's header, which c10d's ProcessGroupNCCL.hpp includes (the "nccl"
# backend, src/distributed/nccl_process_group.cpp). The torch wheel's own
# nvidia-nccl wheel goes first: its header matches the libnccl that
# libtorch_cuda loads. Without it the backend fails at run time, by name.
set(FLAT_NCCL_INCLUDE_DIR "")
if(FLAT_WITH_CUDA)
  if(_py)
    execute_process(COMMAND "${_py}" -c "import nvidia.nccl as m; print(list(m.__path__)[0])"
                    OUTPUT_VARIABLE _nccl_wheel OUTPUT_STRIP_TRAILING_WHITESPACE ERROR_QUIET)
  endif()
  find_path(FLAT_NCCL_HEADER_DIR nccl.h HINTS "${_nccl_wheel}/include" ${CUDAToolkit_INCLUDE_DIRS}
            NO_CACHE)
  if(FLAT_NCCL_HEADER_DIR)
    set(FLAT_NCCL_INCLUDE_DIR "${FLAT_NCCL_HEADER_DIR}")
    message(STATUS "NCCL header from ${FLAT_NCCL_INCLUDE_DIR} (distributed.backend nccl)")
  else()
    message(WARNING "nccl.h not found (torch's nvidia-nccl wheel, CUDA toolkit): distributed.backend nccl "
                    "will fail at run time")
  endif()
endif()

# CUTLASS (header-only, NVIDIA): the Hopper implicit-GEMM convs of
# src/model/cuda_sm90. Looked up in FLAT_CUTLASS_DIR, then .deps/cutlass (what
# scripts/prepare_device_carry.sh extracts), then the nvidia-cutlass wheel that
# scripts/install_deps.sh puts next to torch. The folder holds include/ and
# tools/util/include/.
set(FLAT_WITH_CUTLASS OFF)
if(FLAT_WITH_CUDA AND FLAT_CUTLASS)
  set(FLAT_CUTLASS_DIR "" CACHE PATH "CUTLASS source folder (holds include/cutlass/cutlass.h)")
  set(_cutlass "${FLAT_CUTLASS_DIR}")
  if(NOT _cutlass AND EXISTS "${CMAKE_SOURCE_DIR}/.deps/cutlass/include/cutlass/cutlass.h")
    set(_cutlass "${CMAKE_SOURCE_DIR}/.deps/cutlass")
  endif()
  if(NOT _cutlass AND _py)
    execute_process(COMMAND "${_py}" -c
                    "import cutlass_library, os; print(os.path.join(os.path.dirname(cutlass_library.__file__), 'source'))"
                    OUTPUT_VARIABLE _cutlass OUTPUT_STRIP_TRAILING_WHITESPACE ERROR_QUIET)
  endif()
  if(NOT _cutlass OR NOT EXISTS "${_cutlass}/include/cutlass/cutlass.h")
    message(FATAL_ERROR "CUTLASS headers not found (looked in FLAT_CUTLASS_DIR, .deps/cutlass and the "
                        "nvidia-cutlass wheel of ${_py}). Run scripts/install_deps.sh, pass "
                        "-DFLAT_CUTLASS_DIR=<cutlass source folder>, or configure with -DFLAT_CUTLASS=OFF "
                        "(the decoder then uses cuDNN for every conv).")
  endif()
  set(FLAT_WITH_CUTLASS ON)
  set(FLAT_CUTLASS_INCLUDE_DIRS "${_cutlass}/include" "${_cutlass}/tools/util/include")
  message(STATUS "CUTLASS from ${_cutlass}")
endif()

if(FLAT_BUILD_TESTS)
  find_package(Catch2 REQUIRED)   # v2 on Debian 12, v3 on Ubuntu 24.04: tests/catch.h bridges both
endif()

# One interface target carrying every dependency and the feature switches, so
# that all modules compile with identical flags (and can share one PCH).
add_library(flat_deps INTERFACE)
if(TARGET yaml-cpp::yaml-cpp)
  set(_yaml yaml-cpp::yaml-cpp)
else()
  set(_yaml yaml-cpp)
endif()
# libstdc++ goes first among the shared libraries: the torch wheel's small
# libtorch.so exports its own copy of std::filesystem, which would otherwise
# interpose on ours, and its remove_all() crashes (null call) on a non-empty folder.
# libtorch only in the build: an installed package links the Torch that its
# consumer finds (cmake/flatConfig.cmake.in), not this machine's wheel paths.
set(_torch_build_libs "")
foreach(_l IN LISTS TORCH_LIBRARIES)
  list(APPEND _torch_build_libs "$<BUILD_INTERFACE:${_l}>")
endforeach()
target_link_libraries(flat_deps INTERFACE "-Wl,--push-state,--no-as-needed" stdc++ "-Wl,--pop-state"
                      ${_torch_build_libs} ${_yaml} spdlog::spdlog CLI11::CLI11
                      nlohmann_json::nlohmann_json glm::glm Threads::Threads)
# C++17 for a program that embeds the installed library too (the build sets
# CMAKE_CXX_STANDARD itself).
target_compile_features(flat_deps INTERFACE cxx_std_17)
target_compile_definitions(flat_deps INTERFACE
  FLAT_WITH_CUDA=$<BOOL:${FLAT_WITH_CUDA}> FLAT_WITH_OIIO=$<BOOL:${FLAT_WITH_OIIO}>
  FLAT_WITH_CUTLASS=$<BOOL:${FLAT_WITH_CUTLASS}>
  GLM_FORCE_XYZW_ONLY)
# Only a non-default tile size adds a definition: the default build's flags
# (and its compiled objects) stay as they are.
if(NOT FLAT_SPLAT_TILE_SIZE EQUAL 16)
  if(NOT FLAT_SPLAT_TILE_SIZE MATCHES "^(8|16)$")
    message(FATAL_ERROR "FLAT_SPLAT_TILE_SIZE=${FLAT_SPLAT_TILE_SIZE}: expected 8 or 16")
  endif()
  target_compile_definitions(flat_deps INTERFACE FLAT_SPLAT_TILE_SIZE=${FLAT_SPLAT_TILE_SIZE})
endif()
if(FLAT_WITH_OIIO)
  target_link_libraries(flat_deps INTERFACE OpenImageIO::OpenImageIO)
endif()
# libtorch ships its own fmt headers (v12) in its include folder, which would
# shadow the system fmt that spdlog was built against (spdlog then fails to
# compile). A folder holding only a link to the system fmt headers goes first.
if(TARGET fmt::fmt)
  get_target_property(_fmt_inc fmt::fmt INTERFACE_INCLUDE_DIRECTORIES)
  list(GET _fmt_inc 0 _fmt_inc)
  file(MAKE_DIRECTORY "${CMAKE_BINARY_DIR}/fmt_include")
  file(CREATE_LINK "${_fmt_inc}/fmt" "${CMAKE_BINARY_DIR}/fmt_include/fmt" SYMBOLIC)
  # (Build tree only; the installed package makes its own: flatConfig.cmake.in.)
  target_include_directories(flat_deps SYSTEM BEFORE INTERFACE "$<BUILD_INTERFACE:${CMAKE_BINARY_DIR}/fmt_include>")
endif()
if(FLAT_WITH_CUDA)
  target_link_libraries(flat_deps INTERFACE CUDA::cudart)
endif()
