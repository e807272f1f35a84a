// The spectral data files (data/*.csv) compiled into the library. CMake generates the table from
// the CSVs at configure time, so a binary never reads a data directory at run time. Paths are
// relative to data/ ("cmf/cie1931_2deg_xyz_cmf_360_830_1nm.csv"); texts are the files' bytes.
#pragma once

#include <span>
#include <string_view>

namespace prism::spectral {

struct EmbeddedFile {
  std::string_view path;
  std::string_view text;
};

// Every embedded file, in a fixed order. The storage is static and immutable.
std::span<const EmbeddedFile> embedded_files();

// The text of the embedded file at `path` (relative to data/). Aborts if it is not embedded: the
// set of files is fixed at build time, so asking for a missing one is a bug.
std::string_view embedded_file(std::string_view path);

}  // namespace prism::spectral
