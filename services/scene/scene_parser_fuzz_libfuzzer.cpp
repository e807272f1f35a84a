// libFuzzer entry point (built only with PRISM_BUILD_FUZZERS and clang).
#include <cstddef>
#include <cstdint>

#include "services/scene/scene_parser_fuzz.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  return prism::scene::fuzz_parse(data, size);
}
