# Imported targets for the Debian packages sonomesh uses (scripts/setup.sh installs them).
# Each heavy dependency is linked PRIVATE by the one module that needs it.
find_package(PkgConfig REQUIRED)
find_package(Threads REQUIRED)
find_package(Eigen3 3.4 REQUIRED NO_MODULE)
find_package(ZLIB REQUIRED)

# OpenCV: only core + imgproc are installed, and their -dev packages ship no CMake config.
find_path(OPENCV_INCLUDE_DIR opencv2/core.hpp PATH_SUFFIXES opencv4 REQUIRED)
find_library(OPENCV_CORE_LIB opencv_core REQUIRED)
find_library(OPENCV_IMGPROC_LIB opencv_imgproc REQUIRED)
add_library(sonomesh_dep_opencv INTERFACE)
target_include_directories(sonomesh_dep_opencv SYSTEM INTERFACE ${OPENCV_INCLUDE_DIR})
target_link_libraries(sonomesh_dep_opencv INTERFACE ${OPENCV_IMGPROC_LIB} ${OPENCV_CORE_LIB})
add_library(deps::opencv ALIAS sonomesh_dep_opencv)

# Teem (NRRD): Debian's TeemConfig.cmake is old-style; link the library directly.
find_path(TEEM_INCLUDE_DIR teem/nrrd.h REQUIRED)
find_library(TEEM_LIB teem REQUIRED)
add_library(sonomesh_dep_teem INTERFACE)
target_include_directories(sonomesh_dep_teem SYSTEM INTERFACE ${TEEM_INCLUDE_DIR})
target_link_libraries(sonomesh_dep_teem INTERFACE ${TEEM_LIB})
add_library(deps::teem ALIAS sonomesh_dep_teem)

# FFTW single precision with threads.
pkg_check_modules(FFTW3F REQUIRED IMPORTED_TARGET fftw3f)
find_library(FFTW3F_THREADS_LIB fftw3f_threads REQUIRED)
add_library(sonomesh_dep_fftw INTERFACE)
target_link_libraries(sonomesh_dep_fftw INTERFACE ${FFTW3F_THREADS_LIB} PkgConfig::FFTW3F Threads::Threads)
add_library(deps::fftw ALIAS sonomesh_dep_fftw)

# OpenVDB: Debian's FindOpenVDB.cmake insists on Boost.Iostreams headers that the library's own
# headers do not need, so the target is assembled here from the library, TBB and Imath.
find_path(OPENVDB_INCLUDE_DIR openvdb/openvdb.h REQUIRED)
find_library(OPENVDB_LIB openvdb REQUIRED)
find_package(TBB REQUIRED)
find_package(Imath REQUIRED CONFIG)
add_library(sonomesh_dep_openvdb INTERFACE)
target_include_directories(sonomesh_dep_openvdb SYSTEM INTERFACE ${OPENVDB_INCLUDE_DIR})
target_link_libraries(sonomesh_dep_openvdb INTERFACE ${OPENVDB_LIB} TBB::tbb Imath::Imath Threads::Threads)
add_library(deps::openvdb ALIAS sonomesh_dep_openvdb)

pkg_check_modules(LIBUSB REQUIRED IMPORTED_TARGET libusb-1.0)
add_library(deps::libusb ALIAS PkgConfig::LIBUSB)

find_package(CLI11 QUIET CONFIG)
if(NOT TARGET CLI11::CLI11)
  find_path(CLI11_INCLUDE_DIR CLI/CLI.hpp REQUIRED)
  add_library(sonomesh_dep_cli11 INTERFACE)
  target_include_directories(sonomesh_dep_cli11 SYSTEM INTERFACE ${CLI11_INCLUDE_DIR})
  add_library(CLI11::CLI11 ALIAS sonomesh_dep_cli11)
endif()
find_package(nlohmann_json 3 REQUIRED)
find_package(spdlog REQUIRED)
find_package(tomlplusplus REQUIRED)
pkg_check_modules(HTTPLIB REQUIRED IMPORTED_TARGET cpp-httplib)
add_library(deps::httplib ALIAS PkgConfig::HTTPLIB)

# OpenIGTLink 1.11 (3D Slicer's protocol): Debian's CMake config sets variables only, no target.
if(NOT TARGET deps::openigtlink)
  find_path(OPENIGTLINK_INCLUDE_DIR igtlMessageBase.h PATH_SUFFIXES openigtlink REQUIRED)
  find_library(OPENIGTLINK_LIB OpenIGTLink REQUIRED)
  add_library(deps::openigtlink INTERFACE IMPORTED GLOBAL)
  target_include_directories(deps::openigtlink SYSTEM INTERFACE ${OPENIGTLINK_INCLUDE_DIR})
  target_link_libraries(deps::openigtlink INTERFACE ${OPENIGTLINK_LIB})
endif()

find_package(GTest REQUIRED)
find_package(benchmark REQUIRED)
pkg_check_modules(UMOCKDEV REQUIRED IMPORTED_TARGET umockdev-1.0)
add_library(deps::umockdev ALIAS PkgConfig::UMOCKDEV)
find_program(UMOCKDEV_WRAPPER umockdev-wrapper REQUIRED)
