# prism_scene_io (prism::scene_io): mesh files (PLY, OBJ), path confinement, scene bundles.
find_package(tinyobjloader REQUIRED CONFIG)

add_library(prism_scene_io
  ${CMAKE_CURRENT_LIST_DIR}/bundle.cpp
  ${CMAKE_CURRENT_LIST_DIR}/mesh_obj.cpp
  ${CMAKE_CURRENT_LIST_DIR}/mesh_ply.cpp
  ${CMAKE_CURRENT_LIST_DIR}/path_guard.cpp
)
add_library(prism::scene_io ALIAS prism_scene_io)
target_include_directories(prism_scene_io PUBLIC ${PROJECT_SOURCE_DIR})
target_link_libraries(prism_scene_io
  PUBLIC prism::base absl::status absl::statusor absl::strings
  PRIVATE tinyobjloader::tinyobjloader absl::flat_hash_map absl::flat_hash_set
          absl::hash prism_warnings
)

prism_test(NAME scene_io_test
  SOURCES
    ${CMAKE_CURRENT_LIST_DIR}/mesh_test.cpp
    ${CMAKE_CURRENT_LIST_DIR}/mesh_ply_test.cpp
    ${CMAKE_CURRENT_LIST_DIR}/mesh_obj_test.cpp
    ${CMAKE_CURRENT_LIST_DIR}/path_guard_test.cpp
    ${CMAKE_CURRENT_LIST_DIR}/bundle_test.cpp
  LIBS prism::scene_io
)
