// The fuzz entry point of the scene parser: parses arbitrary bytes as a scene file from
// memory, with a small fixed in-memory scene root (an include file, an OBJ and a PLY mesh, a
// spectrum table) so Include, mesh and table references are exercised without touching the
// disk. Checks the parser's contract on every input: it never crashes, every error message
// starts with `file:line:column: `, and a successful parse can be summarised. A broken
// contract aborts (PRISM_CHECK), which the fuzzer reports.
#pragma once

#include <cstddef>
#include <cstdint>

namespace prism::scene {

int fuzz_parse(const std::uint8_t* data, std::size_t size);

}  // namespace prism::scene
