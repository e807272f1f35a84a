// A SQLite database handle in WAL mode with prepared statements, for the coordinator's job
// store. Every statement runs through this class so failures come back as absl::Status with
// SQLite's message; nothing here throws. One Database is used by one thread at a time (the
// caller serialises access); WAL lets readers in other processes (inspection tools) coexist.
#pragma once

#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <unordered_map>
#include <variant>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"

struct sqlite3;
struct sqlite3_stmt;

namespace prism::store {

// Bytes to bind as a BLOB (a plain std::string binds as TEXT).
struct SqlBlob {
  std::string bytes;
};

// A bound parameter or a column value. Column values never hold SqlBlob: TEXT and BLOB columns
// both come back as std::string.
using SqlValue = std::variant<std::monostate, std::int64_t, double, std::string, SqlBlob>;

// One result row; blobs come back as std::string.
struct SqlRow {
  std::vector<SqlValue> values;
  std::int64_t integer(std::size_t i) const;
  double real(std::size_t i) const;
  const std::string& text(std::size_t i) const;
  bool is_null(std::size_t i) const;
};

class Database {
 public:
  // Opens or creates the file, switches to WAL with synchronous=FULL (a committed transaction
  // survives power loss) and enables foreign keys.
  static absl::StatusOr<Database> open(const std::filesystem::path& file);

  Database(Database&&) noexcept;
  Database& operator=(Database&&) noexcept;
  ~Database();

  // Runs one or more statements without parameters (schema, pragmas).
  absl::Status exec(std::string_view sql);

  // Runs one statement with positional parameters (?1, ?2, … or ?). std::string parameters are
  // bound as TEXT, SqlBlob as BLOB.
  absl::Status run(std::string_view sql, const std::vector<SqlValue>& params = {});
  absl::StatusOr<std::vector<SqlRow>> query(std::string_view sql,
                                            const std::vector<SqlValue>& params = {});

  // How a transaction's commit reaches the disk. kDurable: before transaction() returns
  // (synchronous=FULL, one fsync of the WAL per commit). kDeferred: the commit is in the WAL
  // (atomic, visible at once) but not yet synced; sync_wal() makes it durable, together with
  // every other commit made before it, so one sync can serve a group of commits
  // (group_commit.h). A durable commit also makes every earlier deferred one durable.
  enum class Commit { kDurable, kDeferred };

  // Runs `body` in a transaction: committed if it returns OK, rolled back otherwise.
  absl::Status transaction(const std::function<absl::Status()>& body,
                           Commit commit = Commit::kDurable);

  // fdatasync of the WAL file: every commit made before the call is durable when it returns.
  // Unlike the rest of this class it is thread-safe and needs no serialisation with the other
  // calls, so a caller can release its own lock while it syncs.
  absl::Status sync_wal() const;

  std::int64_t last_insert_rowid() const;
  std::int64_t changes() const;

 private:
  struct WalSync;

  Database(sqlite3* db, const std::filesystem::path& file);
  // The statement for `sql`, reset, with `params` bound: compiled once per text and kept
  // (statements_), since the store runs the same few statements for every task.
  absl::StatusOr<sqlite3_stmt*> prepare(std::string_view sql, const std::vector<SqlValue>& params);
  absl::Status error(std::string_view what) const;
  void close();

  sqlite3* db_ = nullptr;
  std::unordered_map<std::string, sqlite3_stmt*> statements_;  // by SQL text; reset after use
  std::unique_ptr<WalSync> wal_;  // owned apart so that it outlives moves of the Database
};

}  // namespace prism::store
