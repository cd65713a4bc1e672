# Sanitizer and fuzzing builds (scripts/test.sh sets these; the normal build leaves them empty).
#   SONOMESH_SANITIZE=address,undefined  every target compiled and linked with those sanitizers;
#                                        UBSan halts on the first report so a test fails on it.
#   SONOMESH_FUZZ=ON                     (clang only) our code gets libFuzzer's coverage hooks and
#                                        fuzz/ adds one libFuzzer executable per parser.
# Assertions stay on in both: Release here is -O2 without NDEBUG (top-level CMakeLists.txt).
set(SONOMESH_SANITIZE "" CACHE STRING "Comma-separated -fsanitize= list, e.g. address,undefined")
option(SONOMESH_FUZZ "Build the libFuzzer targets in fuzz/ (needs clang)" OFF)

if(SONOMESH_SANITIZE)
  add_compile_options(-fsanitize=${SONOMESH_SANITIZE} -fno-omit-frame-pointer -g1)
  add_link_options(-fsanitize=${SONOMESH_SANITIZE})
  if(SONOMESH_SANITIZE MATCHES "undefined")
    add_compile_options(-fno-sanitize-recover=undefined)
    # One UBSan check off in TBB's headers, for the code compiled against OpenVDB (the only user
    # of TBB's concurrent_hash_map); the reason is in the file.
    target_compile_options(sonomesh_dep_openvdb INTERFACE
                           -fsanitize-ignorelist=${PROJECT_SOURCE_DIR}/cmake/ubsan_ignorelist.txt)
  endif()
endif()

if(SONOMESH_FUZZ)
  if(NOT CMAKE_CXX_COMPILER_ID STREQUAL "Clang")
    message(FATAL_ERROR "SONOMESH_FUZZ needs clang (CXX=clang++ CC=clang); got ${CMAKE_CXX_COMPILER_ID}")
  endif()
  # Coverage feedback for our libraries; only the fuzz executables link libFuzzer's main.
  add_compile_options(-fsanitize=fuzzer-no-link)
endif()
