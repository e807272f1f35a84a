#include "services/store/database.h"

#include <fcntl.h>
#include <sqlite3.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <mutex>

#include "absl/strings/str_cat.h"
#include "services/base/check.h"
#include "services/base/status.h"

namespace prism::store {

std::int64_t SqlRow::integer(std::size_t i) const {
  PRISM_CHECK(i < values.size() && std::holds_alternative<std::int64_t>(values[i]));
  return std::get<std::int64_t>(values[i]);
}

double SqlRow::real(std::size_t i) const {
  PRISM_CHECK(i < values.size());
  if (auto* v = std::get_if<std::int64_t>(&values[i])) return static_cast<double>(*v);
  PRISM_CHECK(std::holds_alternative<double>(values[i]));
  return std::get<double>(values[i]);
}

const std::string& SqlRow::text(std::size_t i) const {
  PRISM_CHECK(i < values.size() && std::holds_alternative<std::string>(values[i]));
  return std::get<std::string>(values[i]);
}

bool SqlRow::is_null(std::size_t i) const {
  PRISM_CHECK(i < values.size());
  return std::holds_alternative<std::monostate>(values[i]);
}

absl::StatusOr<Database> Database::open(const std::filesystem::path& file) {
  sqlite3* db = nullptr;
  int rc = sqlite3_open_v2(
      file.c_str(), &db, SQLITE_OPEN_READWRITE | SQLITE_OPEN_CREATE | SQLITE_OPEN_NOMUTEX, nullptr);
  if (rc != SQLITE_OK) {
    std::string message = db ? sqlite3_errmsg(db) : sqlite3_errstr(rc);
    sqlite3_close(db);
    return absl::FailedPreconditionError(
        absl::StrCat("cannot open database ", file.string(), ": ", message));
  }
  Database database(db, file);
  sqlite3_busy_timeout(db, 5000);
  auto status =
      database.exec("PRAGMA journal_mode=WAL; PRAGMA synchronous=FULL; PRAGMA foreign_keys=ON;");
  if (!status.ok()) return status;
  return database;
}

// The WAL file's descriptor, opened at the first sync (the file exists once anything has been
// committed) and kept: fdatasync on any descriptor flushes the file's dirty pages, SQLite's own
// writes included. The file keeps its inode while the connection is open (a checkpoint rewinds
// it, never replaces it).
struct Database::WalSync {
  explicit WalSync(std::filesystem::path path) : path(std::move(path)) {}
  ~WalSync() {
    if (fd >= 0) ::close(fd);
  }

  absl::Status sync() {
    std::lock_guard<std::mutex> lock(mutex);
    if (fd < 0) {
      fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
      if (fd < 0) {
        return absl::InternalError(
            absl::StrCat("cannot open ", path.string(), " to sync it: ", std::strerror(errno)));
      }
    }
    if (::fdatasync(fd) != 0) {
      return absl::InternalError(
          absl::StrCat("cannot sync ", path.string(), ": ", std::strerror(errno)));
    }
    return absl::OkStatus();
  }

  std::mutex mutex;  // guards fd's opening
  std::filesystem::path path;
  int fd = -1;
};

Database::Database(sqlite3* db, const std::filesystem::path& file)
    : db_(db), wal_(std::make_unique<WalSync>(file.string() + "-wal")) {}

Database::Database(Database&& other) noexcept
    : db_(other.db_), statements_(std::move(other.statements_)), wal_(std::move(other.wal_)) {
  other.db_ = nullptr;
  other.statements_.clear();
}

Database& Database::operator=(Database&& other) noexcept {
  if (this != &other) {
    close();
    db_ = other.db_;
    statements_ = std::move(other.statements_);
    wal_ = std::move(other.wal_);
    other.db_ = nullptr;
    other.statements_.clear();
  }
  return *this;
}

Database::~Database() {
  close();
}

void Database::close() {
  for (auto& [sql, stmt] : statements_) sqlite3_finalize(stmt);
  statements_.clear();
  sqlite3_close(db_);
  db_ = nullptr;
}

absl::Status Database::error(std::string_view what) const {
  return absl::InternalError(
      absl::StrCat("sqlite: ", std::string(what), ": ", sqlite3_errmsg(db_)));
}

absl::Status Database::exec(std::string_view sql) {
  std::string text(sql);
  char* message = nullptr;
  if (sqlite3_exec(db_, text.c_str(), nullptr, nullptr, &message) != SQLITE_OK) {
    auto status = absl::InternalError(absl::StrCat("sqlite: ", message ? message : "error"));
    sqlite3_free(message);
    return status;
  }
  return absl::OkStatus();
}

absl::StatusOr<sqlite3_stmt*> Database::prepare(std::string_view sql,
                                                const std::vector<SqlValue>& params) {
  sqlite3_stmt* stmt = nullptr;
  auto cached = statements_.find(std::string(sql));
  if (cached != statements_.end()) {
    stmt = cached->second;
    sqlite3_reset(stmt);
    sqlite3_clear_bindings(stmt);
  } else {
    // The store's statements are a fixed set of texts; should some caller make texts without
    // end, the kept ones are let go (none is in use between calls) rather than grow forever.
    constexpr std::size_t kMaxKeptStatements = 256;
    if (statements_.size() >= kMaxKeptStatements) {
      for (auto& [text, kept] : statements_) sqlite3_finalize(kept);
      statements_.clear();
    }
    if (sqlite3_prepare_v3(db_, sql.data(), static_cast<int>(sql.size()), SQLITE_PREPARE_PERSISTENT,
                           &stmt, nullptr) != SQLITE_OK) {
      return error(absl::StrCat("prepare '", std::string(sql.substr(0, 60)), "'"));
    }
    if (stmt == nullptr) {  // only whitespace or a comment
      return absl::InvalidArgumentError(
          absl::StrCat("sqlite: no statement in '", std::string(sql.substr(0, 60)), "'"));
    }
    statements_.emplace(std::string(sql), stmt);
  }
  for (std::size_t i = 0; i < params.size(); ++i) {
    int index = static_cast<int>(i) + 1;
    int rc = std::visit(
        [&](const auto& v) -> int {
          using T = std::decay_t<decltype(v)>;
          if constexpr (std::is_same_v<T, std::monostate>) {
            return sqlite3_bind_null(stmt, index);
          } else if constexpr (std::is_same_v<T, std::int64_t>) {
            return sqlite3_bind_int64(stmt, index, v);
          } else if constexpr (std::is_same_v<T, double>) {
            return sqlite3_bind_double(stmt, index, v);
          } else if constexpr (std::is_same_v<T, std::string>) {
            return sqlite3_bind_text64(stmt, index, v.data(), v.size(), SQLITE_TRANSIENT,
                                       SQLITE_UTF8);
          } else {
            return sqlite3_bind_blob64(stmt, index, v.bytes.data(), v.bytes.size(),
                                       SQLITE_TRANSIENT);
          }
        },
        params[i]);
    if (rc != SQLITE_OK) {
      absl::Status status = error("bind");
      sqlite3_clear_bindings(stmt);
      return status;
    }
  }
  return stmt;
}

absl::Status Database::run(std::string_view sql, const std::vector<SqlValue>& params) {
  auto rows = query(sql, params);
  return rows.status();
}

absl::StatusOr<std::vector<SqlRow>> Database::query(std::string_view sql,
                                                    const std::vector<SqlValue>& params) {
  auto stmt = prepare(sql, params);
  if (!stmt.ok()) return stmt.status();
  std::vector<SqlRow> rows;
  while (true) {
    int rc = sqlite3_step(*stmt);
    if (rc == SQLITE_DONE) break;
    if (rc != SQLITE_ROW) {
      auto status = error(absl::StrCat("step '", std::string(sql.substr(0, 60)), "'"));
      sqlite3_reset(*stmt);
      return status;
    }
    SqlRow row;
    int columns = sqlite3_column_count(*stmt);
    row.values.reserve(columns);
    for (int c = 0; c < columns; ++c) {
      switch (sqlite3_column_type(*stmt, c)) {
        case SQLITE_INTEGER:
          row.values.emplace_back(static_cast<std::int64_t>(sqlite3_column_int64(*stmt, c)));
          break;
        case SQLITE_FLOAT:
          row.values.emplace_back(sqlite3_column_double(*stmt, c));
          break;
        case SQLITE_NULL:
          row.values.emplace_back(std::monostate{});
          break;
        default: {
          const void* data = sqlite3_column_blob(*stmt, c);
          int size = sqlite3_column_bytes(*stmt, c);
          row.values.emplace_back(std::string(static_cast<const char*>(data), size));
        }
      }
    }
    rows.push_back(std::move(row));
  }
  // Reset at once: a statement left stepping would hold its read transaction open.
  sqlite3_reset(*stmt);
  return rows;
}

absl::Status Database::transaction(const std::function<absl::Status()>& body, Commit commit) {
  // synchronous=NORMAL in WAL mode: the commit is appended to the WAL without a sync (still
  // atomic, never corrupting); make_durable syncs it.
  if (commit == Commit::kDeferred) PRISM_RETURN_IF_ERROR(run("PRAGMA synchronous=NORMAL"));
  absl::Status status = run("BEGIN IMMEDIATE");
  if (status.ok()) {
    status = body();
    if (status.ok()) status = run("COMMIT");
    if (!status.ok()) (void)run("ROLLBACK");
  }
  if (commit == Commit::kDeferred) {
    absl::Status restored = run("PRAGMA synchronous=FULL");
    if (status.ok()) status = restored;
  }
  return status;
}

absl::Status Database::sync_wal() const {
  return wal_->sync();
}

std::int64_t Database::last_insert_rowid() const {
  return sqlite3_last_insert_rowid(db_);
}

std::int64_t Database::changes() const {
  return sqlite3_changes64(db_);
}

}  // namespace prism::store
