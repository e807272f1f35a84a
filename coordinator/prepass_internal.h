// Helpers the prepass's two source files share (prepass.cpp: schedule, guide, table and moment
// images, the filter; prepass_tables.cpp: learning and choosing the tables). Internal to them.
#pragma once

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <string>

#include "absl/status/status.h"
#include "absl/strings/str_cat.h"
#include "services/image/tile.h"

namespace prism::coordinator::prepass_internal {

// INVALID_ARGUMENT naming `what` unless 1 <= width, height <= image::kMaxImageSide.
inline absl::Status check_size(int width, int height, const std::string& what) {
  if (width < 1 || height < 1 || width > image::kMaxImageSide || height > image::kMaxImageSide) {
    return absl::InvalidArgumentError(absl::StrCat(what, " must be 1 to ", image::kMaxImageSide,
                                                   " pixels on each side, got ", width, "x",
                                                   height));
  }
  return absl::OkStatus();
}

// Rows in parallel; grain 1 row because a row is already thousands of pixel operations.
template <typename RowFn>
inline void for_each_row(int height, const RowFn& row_fn) {
  tbb::parallel_for(tbb::blocked_range<int>(0, height, 1),
                    [&](const tbb::blocked_range<int>& rows) { row_fn(rows.begin(), rows.end()); });
}

}  // namespace prism::coordinator::prepass_internal
