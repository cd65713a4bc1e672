# The pipeline's speed (process_bench) and accuracy (accuracy_report) reports; scripts/results.sh
# runs both and writes docs/results.md. Included from bench/CMakeLists.txt.
if(TARGET sonomesh::daemon_core)
  add_executable(process_bench process_bench.cpp)
  target_link_libraries(process_bench PRIVATE sonomesh::daemon_core sonomesh::sim sonomesh_warnings)
  add_executable(accuracy_report accuracy_report.cpp)
  target_link_libraries(accuracy_report PRIVATE daemon_run sonomesh::sim sonomesh_warnings)
  sonomesh_module_internals(accuracy_report daemon)
endif()
if(TARGET sonomesh::daemon_core)  # breathing_bench: grid sizes and FFTW plans over a stream
  add_executable(breathing_bench breathing_bench.cpp)
  target_link_libraries(breathing_bench PRIVATE daemon_run sonomesh::sim sonomesh_warnings)
  sonomesh_module_internals(breathing_bench daemon)
  sonomesh_module_internals(breathing_bench reconstruct)
endif()
