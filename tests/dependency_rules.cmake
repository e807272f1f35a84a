# The layering on the #include lines (cmake/dependency_rules.cmake has the link-level half):
#   services/ includes nothing from worker/, coordinator/ or client/;
#   worker/ includes nothing from coordinator/ or client/;
#   coordinator/ includes nothing from client/, and from worker/ only in the in-process
#   LocalRender (local_render.*) and the tests (and test fixtures) that compare with it.
# Run as: cmake -DSOURCE_DIR=<repo> -P tests/dependency_rules.cmake (ctest: dependency_rules).
if(NOT SOURCE_DIR)
  message(FATAL_ERROR "pass -DSOURCE_DIR=<the repository>")
endif()

set(violations "")
function(check folder pattern allowed_regex)
  set(found "${violations}")
  file(GLOB_RECURSE files RELATIVE ${SOURCE_DIR} ${SOURCE_DIR}/${folder}/*.h
       ${SOURCE_DIR}/${folder}/*.cpp)
  foreach(file IN LISTS files)
    if(allowed_regex AND file MATCHES "${allowed_regex}")
      continue()
    endif()
    file(STRINGS ${SOURCE_DIR}/${file} lines REGEX "^[ \t]*#[ \t]*include[ \t]+\"${pattern}")
    foreach(line IN LISTS lines)
      string(STRIP "${line}" line)
      string(APPEND found "\n  ${file}: ${line}")
    endforeach()
  endforeach()
  set(violations "${found}" PARENT_SCOPE)
endfunction()

check(services "(worker|coordinator|client)/" "")
check(worker "(coordinator|client)/" "")
check(coordinator "client/" "")
check(coordinator "worker/" "(^coordinator/local_render|_test\\.cpp$|_fixture\\.h$)")

if(violations)
  message(FATAL_ERROR "includes against the layering (tests/dependency_rules.cmake):${violations}")
endif()
message(STATUS "the include graph keeps the layering")
