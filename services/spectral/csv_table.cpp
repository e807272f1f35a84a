#include "services/spectral/csv_table.h"

#include <cmath>

#include "absl/strings/ascii.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "services/base/check.h"
#include "services/spectral/absl_string_view.h"

namespace prism::spectral {

int CsvTable::column_index(std::string_view name) const {
  for (size_t i = 0; i < columns_.size(); ++i) {
    if (columns_[i] == name) return static_cast<int>(i);
  }
  return -1;
}

const std::string& CsvTable::cell(int row, int column) const {
  PRISM_CHECK(row >= 0 && row < row_count() && column >= 0 && column < column_count());
  return rows_[static_cast<size_t>(row)][static_cast<size_t>(column)];
}

absl::StatusOr<std::vector<double>> CsvTable::numeric_column(int column, bool allow_empty) const {
  PRISM_CHECK(column >= 0 && column < column_count());
  std::vector<double> out;
  out.reserve(rows_.size());
  for (size_t r = 0; r < rows_.size(); ++r) {
    const std::string& text = rows_[r][static_cast<size_t>(column)];
    if (text.empty() && allow_empty) {
      out.push_back(std::nan(""));
      continue;
    }
    double v = 0.0;
    if (!absl::SimpleAtod(text, &v) || !std::isfinite(v)) {
      return absl::InvalidArgumentError(absl::StrCat(source_, ":", lines_[r], ": column '",
                                                     columns_[static_cast<size_t>(column)], "': '",
                                                     text, "' is not a finite number"));
    }
    out.push_back(v);
  }
  return out;
}

absl::StatusOr<std::vector<double>> CsvTable::numeric_column(std::string_view name,
                                                             bool allow_empty) const {
  const int c = column_index(name);
  if (c < 0) {
    return absl::InvalidArgumentError(
        absl::StrCat(source_, ": no column named '", to_absl(name), "' in the header"));
  }
  return numeric_column(c, allow_empty);
}

absl::StatusOr<CsvTable> parse_csv_table(std::string_view text, std::string_view source_name) {
  CsvTable table;
  table.source_ = std::string(source_name);
  int line_number = 0;
  bool have_header = false;
  for (absl::string_view line : absl::StrSplit(to_absl(text), '\n')) {
    ++line_number;
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    const absl::string_view stripped = absl::StripAsciiWhitespace(line);
    if (stripped.empty() || stripped.front() == '#') continue;
    if (stripped.find('"') != absl::string_view::npos) {
      return absl::InvalidArgumentError(
          absl::StrCat(to_absl(source_name), ":", line_number,
                       ": quoted cells are not supported; remove the '\"'"));
    }
    std::vector<std::string> cells;
    for (absl::string_view cell : absl::StrSplit(stripped, ',')) {
      cells.emplace_back(absl::StripAsciiWhitespace(cell));
    }
    if (!have_header) {
      for (size_t i = 0; i < cells.size(); ++i) {
        if (cells[i].empty()) {
          return absl::InvalidArgumentError(absl::StrCat(to_absl(source_name), ":", line_number,
                                                         ": header column ", i + 1, " is empty"));
        }
        for (size_t j = 0; j < i; ++j) {
          if (cells[j] == cells[i]) {
            return absl::InvalidArgumentError(absl::StrCat(to_absl(source_name), ":", line_number,
                                                           ": duplicate column name '", cells[i],
                                                           "'"));
          }
        }
      }
      table.columns_ = std::move(cells);
      have_header = true;
      continue;
    }
    if (cells.size() != table.columns_.size()) {
      return absl::InvalidArgumentError(absl::StrCat(to_absl(source_name), ":", line_number,
                                                     ": expected ", table.columns_.size(),
                                                     " cells, found ", cells.size()));
    }
    table.rows_.push_back(std::move(cells));
    table.lines_.push_back(line_number);
  }
  if (!have_header) {
    return absl::InvalidArgumentError(absl::StrCat(to_absl(source_name), ": no header line"));
  }
  if (table.rows_.empty()) {
    return absl::InvalidArgumentError(
        absl::StrCat(to_absl(source_name), ": no data rows after the header"));
  }
  return table;
}

}  // namespace prism::spectral
