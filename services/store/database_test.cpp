#include "services/store/database.h"

#include <gtest/gtest.h>

namespace prism::store {
namespace {

namespace fs = std::filesystem;

class DatabaseTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("prism_db_" + std::to_string(::getpid()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path dir_;
};

TEST_F(DatabaseTest, UsesWalAndRoundTripsValues) {
  auto db = Database::open(dir_ / "jobs.db");
  ASSERT_TRUE(db.ok()) << db.status();
  auto mode = db->query("PRAGMA journal_mode");
  ASSERT_TRUE(mode.ok());
  EXPECT_EQ((*mode)[0].text(0), "wal");
  ASSERT_TRUE(db->exec("CREATE TABLE t (id INTEGER PRIMARY KEY, x REAL, s BLOB, n TEXT)").ok());
  std::string bytes("a\0b", 3);
  ASSERT_TRUE(
      db->run("INSERT INTO t (x, s, n) VALUES (?, ?, ?)", {2.5, SqlBlob{bytes}, std::monostate{}})
          .ok());
  EXPECT_EQ(db->last_insert_rowid(), 1);
  auto rows = db->query("SELECT id, x, s, n FROM t WHERE id = ?", {std::int64_t{1}});
  ASSERT_TRUE(rows.ok());
  ASSERT_EQ(rows->size(), 1u);
  EXPECT_EQ((*rows)[0].integer(0), 1);
  EXPECT_EQ((*rows)[0].real(1), 2.5);
  EXPECT_EQ((*rows)[0].text(2), bytes);
  EXPECT_TRUE((*rows)[0].is_null(3));
  // Strings bind as TEXT, blobs as BLOB.
  auto types =
      db->query("SELECT typeof(s), typeof(?), typeof(?) FROM t", {std::string("x"), SqlBlob{"y"}});
  ASSERT_TRUE(types.ok());
  EXPECT_EQ((*types)[0].text(0), "blob");
  EXPECT_EQ((*types)[0].text(1), "text");
  EXPECT_EQ((*types)[0].text(2), "blob");
}

TEST_F(DatabaseTest, TransactionRollsBackOnError) {
  auto db = Database::open(dir_ / "jobs.db");
  ASSERT_TRUE(db.ok());
  ASSERT_TRUE(db->exec("CREATE TABLE t (id INTEGER PRIMARY KEY)").ok());
  auto status = db->transaction([&] {
    EXPECT_TRUE(db->run("INSERT INTO t (id) VALUES (1)").ok());
    return absl::AbortedError("planner refused");
  });
  EXPECT_EQ(status.code(), absl::StatusCode::kAborted);
  EXPECT_TRUE(db->query("SELECT * FROM t")->empty());
  ASSERT_TRUE(db->transaction([&] { return db->run("INSERT INTO t (id) VALUES (2)"); }).ok());
  EXPECT_EQ(db->query("SELECT * FROM t")->size(), 1u);
}

TEST_F(DatabaseTest, ErrorsCarrySqliteMessage) {
  auto db = Database::open(dir_ / "jobs.db");
  ASSERT_TRUE(db.ok());
  auto rows = db->query("SELECT * FROM missing_table");
  ASSERT_FALSE(rows.ok());
  EXPECT_NE(rows.status().message().find("no such table"), std::string::npos);
  auto bad = Database::open(dir_ / "no" / "such" / "dir" / "x.db");
  EXPECT_EQ(bad.status().code(), absl::StatusCode::kFailedPrecondition);
}

// Statements are compiled once per text and kept: reused with other parameters, after an
// error and across a schema change; a kept statement holds no read open once its query has
// returned (another connection's checkpoint is not blocked by it).
TEST_F(DatabaseTest, KeptStatementsRebindAndHoldNothingOpen) {
  auto db = Database::open(dir_ / "jobs.db");
  ASSERT_TRUE(db.ok()) << db.status();
  ASSERT_TRUE(db->exec("CREATE TABLE t (x INTEGER UNIQUE)").ok());
  const char* insert = "INSERT INTO t (x) VALUES (?)";
  for (std::int64_t x : {1, 2, 3}) ASSERT_TRUE(db->run(insert, {x}).ok());
  EXPECT_FALSE(db->run(insert, {std::int64_t{2}}).ok());  // UNIQUE
  ASSERT_TRUE(db->run(insert, {std::int64_t{4}}).ok());   // the same statement after its error
  const char* select = "SELECT x FROM t WHERE x >= ? ORDER BY x";
  EXPECT_EQ(db->query(select, {std::int64_t{2}})->size(), 3u);
  EXPECT_EQ(db->query(select, {std::int64_t{4}})->size(), 1u);
  // Another connection checkpoints the whole WAL: no kept statement is still reading.
  auto other = Database::open(dir_ / "jobs.db");
  ASSERT_TRUE(other.ok()) << other.status();
  auto checkpoint = other->query("PRAGMA wal_checkpoint(TRUNCATE)");
  ASSERT_TRUE(checkpoint.ok()) << checkpoint.status();
  EXPECT_EQ((*checkpoint)[0].integer(0), 0) << "a reader blocked the checkpoint";
  // A schema change: the kept statement is compiled again by SQLite.
  ASSERT_TRUE(db->exec("ALTER TABLE t ADD COLUMN y INTEGER DEFAULT 7").ok());
  auto rows = db->query("SELECT * FROM t WHERE x >= ? ORDER BY x", {std::int64_t{4}});
  ASSERT_TRUE(rows.ok()) << rows.status();
  ASSERT_EQ(rows->size(), 1u);
  EXPECT_EQ((*rows)[0].integer(1), 7);
  EXPECT_EQ(db->query(select, {std::int64_t{1}})->size(), 4u);
  // More texts than are kept: every one still runs, and the first again afterwards.
  for (int i = 0; i < 600; ++i) {
    auto value = db->query("SELECT " + std::to_string(i));
    ASSERT_TRUE(value.ok()) << value.status();
    EXPECT_EQ((*value)[0].integer(0), i);
  }
  EXPECT_EQ(db->query(select, {std::int64_t{1}})->size(), 4u);
}

TEST_F(DatabaseTest, DeferredCommitsAreVisibleAtOnceAndTheConnectionSyncsOthersAgain) {
  auto db = Database::open(dir_ / "jobs.db");
  ASSERT_TRUE(db.ok()) << db.status();
  ASSERT_TRUE(db->exec("CREATE TABLE t (id INTEGER PRIMARY KEY)").ok());
  for (int i = 1; i <= 3; ++i) {
    ASSERT_TRUE(
        db->transaction([&] { return db->run("INSERT INTO t (id) VALUES (?)", {std::int64_t{i}}); },
                        Database::Commit::kDeferred)
            .ok());
  }
  // The connection is back to syncing every other commit (FULL is 2).
  EXPECT_EQ((*db->query("PRAGMA synchronous"))[0].integer(0), 2);
  // Committed: another connection reads them before any sync.
  auto other = Database::open(dir_ / "jobs.db");
  ASSERT_TRUE(other.ok());
  EXPECT_EQ(other->query("SELECT id FROM t")->size(), 3u);
  EXPECT_TRUE(db->sync_wal().ok());
  // So is a rolled-back deferred transaction's connection.
  EXPECT_FALSE(
      db->transaction([] { return absl::AbortedError("no"); }, Database::Commit::kDeferred).ok());
  EXPECT_EQ((*db->query("PRAGMA synchronous"))[0].integer(0), 2);
  // A moved database syncs the same file.
  Database moved = *std::move(db);
  EXPECT_TRUE(moved.sync_wal().ok());
  // A WAL that cannot be opened is an error that names it.
  auto fresh = Database::open(dir_ / "fresh.db");
  ASSERT_TRUE(fresh.ok());
  fs::remove(dir_ / "fresh.db-wal");
  const absl::Status missing = fresh->sync_wal();
  EXPECT_EQ(missing.code(), absl::StatusCode::kInternal);
  EXPECT_NE(missing.message().find("fresh.db-wal"), std::string::npos) << missing;
}

}  // namespace
}  // namespace prism::store
