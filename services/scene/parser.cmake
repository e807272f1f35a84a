# prism_scene (prism::scene): the pbrt-v4 tokenizer, parser and scene description, on top of
# prism_scene_io (meshes, path confinement). Also the parser's fuzz target and corpus test.
set(PRISM_SCENE_PARSER_SOURCES
  ${CMAKE_CURRENT_LIST_DIR}/coordinate_range.cpp
  ${CMAKE_CURRENT_LIST_DIR}/loop_subdivision.cpp
  ${CMAKE_CURRENT_LIST_DIR}/parameters.cpp
  ${CMAKE_CURRENT_LIST_DIR}/parser.cpp
  ${CMAKE_CURRENT_LIST_DIR}/scene_description.cpp
  ${CMAKE_CURRENT_LIST_DIR}/scene_entities.cpp
  ${CMAKE_CURRENT_LIST_DIR}/scene_features.cpp
  ${CMAKE_CURRENT_LIST_DIR}/scene_loader.cpp
  ${CMAKE_CURRENT_LIST_DIR}/scene_summary.cpp
  ${CMAKE_CURRENT_LIST_DIR}/spectrum_param.cpp
  ${CMAKE_CURRENT_LIST_DIR}/tokenizer.cpp
  ${CMAKE_CURRENT_LIST_DIR}/transform.cpp
  ${CMAKE_CURRENT_LIST_DIR}/wavelength_dependence.cpp
)

add_library(prism_scene ${PRISM_SCENE_PARSER_SOURCES})
add_library(prism::scene ALIAS prism_scene)
target_include_directories(prism_scene PUBLIC ${PROJECT_SOURCE_DIR})
target_link_libraries(prism_scene
  PUBLIC prism_scene_io prism::base absl::status absl::statusor absl::strings
  PRIVATE prism::image prism_warnings
)

# fuzz_parse, shared by the corpus driver (always built and run by ctest) and libFuzzer.
add_library(prism_scene_parser_fuzz STATIC ${CMAKE_CURRENT_LIST_DIR}/scene_parser_fuzz.cpp)
target_link_libraries(prism_scene_parser_fuzz PUBLIC prism::scene PRIVATE prism_warnings)

add_executable(scene_parser_fuzz_driver ${CMAKE_CURRENT_LIST_DIR}/scene_parser_fuzz_driver.cpp)
target_link_libraries(scene_parser_fuzz_driver PRIVATE prism_scene_parser_fuzz prism_warnings)

if(PRISM_BUILD_FUZZERS AND CMAKE_CXX_COMPILER_ID MATCHES "Clang")
  # The parser is compiled again with coverage instrumentation and ASan.
  add_executable(scene_parser_fuzz
    ${CMAKE_CURRENT_LIST_DIR}/scene_parser_fuzz_libfuzzer.cpp
    ${CMAKE_CURRENT_LIST_DIR}/scene_parser_fuzz.cpp
    ${PRISM_SCENE_PARSER_SOURCES}
  )
  target_include_directories(scene_parser_fuzz PRIVATE ${PROJECT_SOURCE_DIR})
  target_compile_options(scene_parser_fuzz PRIVATE -fsanitize=fuzzer,address)
  target_link_options(scene_parser_fuzz PRIVATE -fsanitize=fuzzer,address)
  target_link_libraries(scene_parser_fuzz PRIVATE prism_scene_io prism::base absl::status absl::statusor
                                                  absl::strings prism_warnings)
endif()

if(PRISM_BUILD_TESTS)
  add_test(NAME scene_parser_fuzz_corpus
           COMMAND scene_parser_fuzz_driver ${CMAKE_CURRENT_LIST_DIR}/testdata/parser/fuzz_corpus)
  set_tests_properties(scene_parser_fuzz_corpus PROPERTIES LABELS unit)
endif()

prism_test(NAME scene_parser_test
  SOURCES
    ${CMAKE_CURRENT_LIST_DIR}/transform_test.cpp
    ${CMAKE_CURRENT_LIST_DIR}/tokenizer_test.cpp
    ${CMAKE_CURRENT_LIST_DIR}/parameters_test.cpp
    ${CMAKE_CURRENT_LIST_DIR}/parser_test.cpp
    ${CMAKE_CURRENT_LIST_DIR}/parser_errors_test.cpp
    ${CMAKE_CURRENT_LIST_DIR}/scene_loader_test.cpp
    ${CMAKE_CURRENT_LIST_DIR}/scene_summary_test.cpp
    ${CMAKE_CURRENT_LIST_DIR}/scene_features_test.cpp
  LIBS prism::scene
)

prism_test(NAME scene_loop_subdivision_test
  SOURCES ${CMAKE_CURRENT_LIST_DIR}/loop_subdivision_test.cpp
  LIBS prism::scene
)
