# Module boundaries the build enforces. Each module folder NAME is one library whose users see
# only its public headers NAME/*.h: they are staged as links in build/include/NAME/public/NAME/,
# the PUBLIC include directory. The module itself sees its whole folder (NAME/internal/...)
# through build/include/NAME/private, a PRIVATE one. So a module that includes another's header
# without linking it, or anyone's internal header, does not compile.

# Stages FOLDER's public headers and its private link once per configure (a folder such as
# daemon/ holds more than one library).
function(sonomesh_stage_module folder)
  get_property(staged GLOBAL PROPERTY sonomesh_staged_${folder})
  if(staged)
    return()
  endif()
  set_property(GLOBAL PROPERTY sonomesh_staged_${folder} TRUE)
  set(src ${PROJECT_SOURCE_DIR}/${folder})
  set(stage ${PROJECT_BINARY_DIR}/include/${folder})
  file(REMOVE_RECURSE ${stage})
  file(MAKE_DIRECTORY ${stage}/public/${folder} ${stage}/private)
  file(GLOB headers CONFIGURE_DEPENDS RELATIVE ${src} ${src}/*.h)
  foreach(header ${headers})
    file(CREATE_LINK ${src}/${header} ${stage}/public/${folder}/${header} SYMBOLIC)
  endforeach()
  file(CREATE_LINK ${src} ${stage}/private/${folder} SYMBOLIC)
endfunction()

# sonomesh_module(TARGET FOLDER): the include structure of library TARGET in folder FOLDER.
function(sonomesh_module target folder)
  sonomesh_stage_module(${folder})
  set(stage ${PROJECT_BINARY_DIR}/include/${folder})
  target_include_directories(${target} PUBLIC ${stage}/public PRIVATE ${stage}/private)
endfunction()

# sonomesh_module_internals(TARGET FOLDER): TARGET (the module's own executables, its tests, a
# benchmark) may include FOLDER's internal headers.
function(sonomesh_module_internals target folder)
  sonomesh_stage_module(${folder})
  target_include_directories(${target} PRIVATE ${PROJECT_BINARY_DIR}/include/${folder}/private)
endfunction()

# sonomesh_helper_folder(TARGET SCOPE FOLDER): TARGET may include "FOLDER/x.h" from a folder of
# test or fuzz helpers (tests/hil, fuzz) that is no library; SCOPE is PUBLIC or PRIVATE.
function(sonomesh_helper_folder target scope folder)
  string(REPLACE "/" "+" key ${folder})
  set(stage ${PROJECT_BINARY_DIR}/include/helpers/${key})
  get_filename_component(parent ${stage}/${folder} DIRECTORY)
  file(MAKE_DIRECTORY ${parent})
  if(NOT EXISTS ${stage}/${folder})
    file(CREATE_LINK ${PROJECT_SOURCE_DIR}/${folder} ${stage}/${folder} SYMBOLIC)
  endif()
  target_include_directories(${target} ${scope} ${stage})
endfunction()
