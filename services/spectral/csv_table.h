// A parsed comma-separated table: one header line naming the columns, then rows with exactly as
// many cells. Blank lines and lines starting with '#' are skipped; cells are trimmed of spaces;
// quoting is not supported (none of our data needs it, and a '"' is reported as an error rather
// than mis-split). Every row remembers its 1-based line number so later errors (a cell that is
// not a number) can point at the offending line of the user's file.
#pragma once

#include <string>
#include <string_view>
#include <vector>

#include "absl/status/statusor.h"

namespace prism::spectral {

class CsvTable {
 public:
  const std::string& source_name() const { return source_; }
  const std::vector<std::string>& columns() const { return columns_; }
  int column_count() const { return static_cast<int>(columns_.size()); }
  int row_count() const { return static_cast<int>(rows_.size()); }

  // Index of the column named `name`, or -1.
  int column_index(std::string_view name) const;
  const std::string& cell(int row, int column) const;
  int line_of_row(int row) const { return lines_[static_cast<size_t>(row)]; }

  // The column as numbers. INVALID_ARGUMENT naming source, line and column for a cell that is
  // not a finite number; empty cells are errors unless allow_empty, which gives NaN for them.
  absl::StatusOr<std::vector<double>> numeric_column(int column, bool allow_empty = false) const;
  absl::StatusOr<std::vector<double>> numeric_column(std::string_view name,
                                                     bool allow_empty = false) const;

 private:
  friend absl::StatusOr<CsvTable> parse_csv_table(std::string_view text,
                                                  std::string_view source_name);
  std::string source_;
  std::vector<std::string> columns_;
  std::vector<std::vector<std::string>> rows_;
  std::vector<int> lines_;
};

// Parses `text`; `source_name` (a file name, say) prefixes every error message. INVALID_ARGUMENT
// for: no header, an empty or duplicate column name, a row with the wrong number of cells, a
// quote character, or no data rows.
absl::StatusOr<CsvTable> parse_csv_table(std::string_view text, std::string_view source_name);

}  // namespace prism::spectral
