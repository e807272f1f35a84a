#include "services/store/job_store.h"

#include <algorithm>
#include <limits>
#include <utility>

#include "absl/strings/str_cat.h"
#include "services/base/check.h"
#include "services/base/status.h"

namespace prism::store {
namespace {

// Migration i takes user_version i to i + 1. Never edit a released migration: append one.
constexpr std::string_view kMigrations[] = {
    R"sql(
CREATE TABLE counters (
  name TEXT PRIMARY KEY,
  value INTEGER NOT NULL
);
INSERT INTO counters (name, value) VALUES ('job', 0), ('worker', 0);
CREATE TABLE jobs (
  seq INTEGER PRIMARY KEY,
  id TEXT NOT NULL UNIQUE,
  client_token TEXT UNIQUE,
  spec BLOB NOT NULL,
  bundle_hash TEXT NOT NULL,
  state INTEGER NOT NULL,
  error TEXT NOT NULL DEFAULT '',
  submitted_ms INTEGER NOT NULL,
  started_ms INTEGER NOT NULL DEFAULT 0,
  finished_ms INTEGER NOT NULL DEFAULT 0,
  report_json TEXT NOT NULL DEFAULT '',
  tasks_total INTEGER NOT NULL DEFAULT 0,
  tasks_done INTEGER NOT NULL DEFAULT 0,
  samples_total INTEGER NOT NULL DEFAULT 0,
  samples_done INTEGER NOT NULL DEFAULT 0
);
CREATE INDEX jobs_by_state ON jobs (state, seq);
CREATE TABLE tasks (
  job_id TEXT NOT NULL REFERENCES jobs (id),
  task_index INTEGER NOT NULL,
  pass INTEGER NOT NULL,
  pass_index INTEGER NOT NULL,
  tile_index INTEGER NOT NULL,
  x0 INTEGER NOT NULL,
  y0 INTEGER NOT NULL,
  x1 INTEGER NOT NULL,
  y1 INTEGER NOT NULL,
  s0 INTEGER NOT NULL,
  s1 INTEGER NOT NULL,
  state INTEGER NOT NULL,
  attempts INTEGER NOT NULL DEFAULT 0,
  result_hash TEXT NOT NULL DEFAULT '',
  PRIMARY KEY (job_id, task_index)
) WITHOUT ROWID;
CREATE TABLE worker_failures (
  job_id TEXT NOT NULL REFERENCES jobs (id),
  worker_id TEXT NOT NULL,
  count INTEGER NOT NULL,
  PRIMARY KEY (job_id, worker_id)
) WITHOUT ROWID;
CREATE TABLE workers (
  seq INTEGER PRIMARY KEY,
  id TEXT NOT NULL UNIQUE,
  host TEXT NOT NULL,
  version TEXT NOT NULL,
  threads INTEGER NOT NULL,
  capabilities TEXT NOT NULL,
  last_seen_ms INTEGER NOT NULL
);
)sql",
    // Finding the other jobs that share a result blob before deleting it.
    R"sql(
CREATE INDEX tasks_by_result ON tasks (result_hash) WHERE result_hash != '';
)sql",
    // Results kept in the job's result pack (coordinator/result_pack.h) at an offset; -1: in
    // the blob store, as every result before this version.
    R"sql(
ALTER TABLE tasks ADD COLUMN result_offset INTEGER NOT NULL DEFAULT -1;
ALTER TABLE tasks ADD COLUMN result_size INTEGER NOT NULL DEFAULT 0;
)sql",
    // When a worker left cleanly (Leave), so that a restarted coordinator still lists it as
    // left, not lost; 0: it did not.
    R"sql(
ALTER TABLE workers ADD COLUMN left_ms INTEGER NOT NULL DEFAULT 0;
)sql",
    // The SHA-256 of the request a job was submitted with, so that a client token sent again
    // with another request is refused, not answered with the first job; '': submitted before.
    R"sql(
ALTER TABLE jobs ADD COLUMN request_sha256 TEXT NOT NULL DEFAULT '';
)sql",
};
static_assert(std::size(kMigrations) == JobStore::kSchemaVersion);

constexpr std::string_view kJobColumns =
    "id, client_token, spec, bundle_hash, state, error, submitted_ms, started_ms, finished_ms, "
    "report_json, tasks_total, tasks_done, samples_total, samples_done, request_sha256";

constexpr std::string_view kTaskColumns =
    "task_index, pass, pass_index, tile_index, x0, y0, x1, y1, s0, s1, state, attempts, "
    "result_hash";
// What a read returns: the inserted columns and where the result is kept.
constexpr std::string_view kTaskReadColumns =
    "task_index, pass, pass_index, tile_index, x0, y0, x1, y1, s0, s1, state, attempts, "
    "result_hash, result_offset, result_size";

constexpr std::string_view kWorkerColumns =
    "id, host, version, threads, capabilities, last_seen_ms, left_ms";

SqlValue text(std::string_view s) {
  return std::string(s);
}
SqlValue integer(std::int64_t v) {
  return v;
}
SqlValue optional_text(std::string_view s) {
  return s.empty() ? SqlValue(std::monostate{}) : SqlValue(std::string(s));
}

std::string in_quotes(std::string_view s) {
  return absl::StrCat("'", std::string(s), "'");
}

absl::Status job_not_found(std::string_view job_id) {
  return absl::NotFoundError(absl::StrCat("no job ", in_quotes(job_id)));
}

JobRecord job_from_row(const SqlRow& row) {
  JobRecord job;
  job.id = row.text(0);
  job.client_token = row.is_null(1) ? std::string() : row.text(1);
  job.spec = row.text(2);
  job.bundle_hash = row.text(3);
  job.state = static_cast<JobState>(row.integer(4));
  job.error = row.text(5);
  job.submitted_ms = row.integer(6);
  job.started_ms = row.integer(7);
  job.finished_ms = row.integer(8);
  job.report_json = row.text(9);
  job.progress.tasks_total = static_cast<std::uint64_t>(row.integer(10));
  job.progress.tasks_done = static_cast<std::uint64_t>(row.integer(11));
  job.progress.samples_total = static_cast<std::uint64_t>(row.integer(12));
  job.progress.samples_done = static_cast<std::uint64_t>(row.integer(13));
  job.request_hash = row.text(14);
  return job;
}

TaskRecord task_from_row(const SqlRow& row) {
  TaskRecord task;
  task.index = static_cast<int>(row.integer(0));
  task.pass = static_cast<TaskPass>(row.integer(1));
  task.pass_index = static_cast<int>(row.integer(2));
  task.tile_index = static_cast<int>(row.integer(3));
  task.rect = {static_cast<int>(row.integer(4)), static_cast<int>(row.integer(5)),
               static_cast<int>(row.integer(6)), static_cast<int>(row.integer(7))};
  task.samples = {static_cast<std::uint64_t>(row.integer(8)),
                  static_cast<std::uint64_t>(row.integer(9))};
  task.state = static_cast<TaskState>(row.integer(10));
  task.attempts = static_cast<int>(row.integer(11));
  task.result_hash = row.text(12);
  task.result_offset = row.integer(13);
  task.result_size = static_cast<std::uint64_t>(row.integer(14));
  return task;
}

std::string join_capabilities(const std::vector<std::string>& capabilities) {
  std::string joined;
  for (const auto& c : capabilities) {
    if (!joined.empty()) joined += '\n';
    joined += c;
  }
  return joined;
}

std::vector<std::string> split_capabilities(const std::string& joined) {
  std::vector<std::string> capabilities;
  std::size_t start = 0;
  while (start < joined.size()) {
    std::size_t end = joined.find('\n', start);
    if (end == std::string::npos) end = joined.size();
    capabilities.push_back(joined.substr(start, end - start));
    start = end + 1;
  }
  return capabilities;
}

WorkerRecord worker_from_row(const SqlRow& row) {
  WorkerRecord worker;
  worker.id = row.text(0);
  worker.host = row.text(1);
  worker.version = row.text(2);
  worker.threads = static_cast<int>(row.integer(3));
  worker.capabilities = split_capabilities(row.text(4));
  worker.last_seen_ms = row.integer(5);
  worker.left_ms = row.integer(6);
  return worker;
}

std::uint64_t task_samples(const TaskRecord& task) {
  return static_cast<std::uint64_t>(task.rect.area()) * task.samples.count();
}

absl::Status validate_tasks(std::span<const TaskRecord> tasks, int first_index) {
  for (std::size_t i = 0; i < tasks.size(); ++i) {
    const TaskRecord& t = tasks[i];
    const std::string where = absl::StrCat("task ", first_index + static_cast<int>(i));
    if (t.index != first_index + static_cast<int>(i)) {
      return absl::InvalidArgumentError(
          absl::StrCat(where, " has index ", t.index, ": tasks must be numbered consecutively"));
    }
    if (t.pass != TaskPass::kPrepass && t.pass != TaskPass::kFinal) {
      return absl::InvalidArgumentError(
          absl::StrCat(where, ": unknown pass ", static_cast<int>(t.pass)));
    }
    if (t.pass_index < 0 || t.tile_index < 0) {
      return absl::InvalidArgumentError(absl::StrCat(where, ": negative pass or tile index"));
    }
    if (!t.rect.valid() || t.rect.empty()) {
      return absl::InvalidArgumentError(
          absl::StrCat(where, ": tile ", image::to_string(t.rect), " is empty or reversed"));
    }
    if (t.samples.count() == 0 ||
        t.samples.s1 > static_cast<std::uint64_t>(std::numeric_limits<std::int64_t>::max())) {
      return absl::InvalidArgumentError(absl::StrCat(where, ": sample range [", t.samples.s0, ",",
                                                     t.samples.s1, ") is empty or out of range"));
    }
    if (t.state != TaskState::kPending || t.attempts != 0 || !t.result_hash.empty()) {
      return absl::InvalidArgumentError(
          absl::StrCat(where, ": a new task must be pending, without attempts or result"));
    }
  }
  return absl::OkStatus();
}

std::string placeholders(std::size_t n) {
  std::string s;
  for (std::size_t i = 0; i < n; ++i) s += i == 0 ? "?" : ", ?";
  return s;
}

}  // namespace

std::string to_string(JobState state) {
  switch (state) {
    case JobState::kQueued:
      return "QUEUED";
    case JobState::kPrepass:
      return "PREPASS";
    case JobState::kRendering:
      return "RENDERING";
    case JobState::kFinalising:
      return "FINALISING";
    case JobState::kDone:
      return "DONE";
    case JobState::kFailed:
      return "FAILED";
    case JobState::kCancelled:
      return "CANCELLED";
  }
  return absl::StrCat("UNKNOWN(", static_cast<int>(state), ")");
}

bool is_terminal(JobState state) {
  return state == JobState::kDone || state == JobState::kFailed || state == JobState::kCancelled;
}

bool gives_up_client_token(JobState state) {
  return state == JobState::kFailed || state == JobState::kCancelled;
}

bool is_valid_transition(JobState from, JobState to) {
  if (is_terminal(from) || from == to) return false;
  if (to == JobState::kFailed || to == JobState::kCancelled) return true;
  switch (from) {
    case JobState::kQueued:
      return to == JobState::kPrepass || to == JobState::kRendering;
    case JobState::kPrepass:
      return to == JobState::kRendering;
    case JobState::kRendering:
      return to == JobState::kFinalising;
    case JobState::kFinalising:
      return to == JobState::kDone;
    default:
      return false;
  }
}

absl::StatusOr<JobStore> JobStore::open(const std::filesystem::path& file) {
  auto db = Database::open(file);
  if (!db.ok()) {
    return absl::FailedPreconditionError(
        absl::StrCat("cannot open job store ", file.string(), ": ", db.status().message()));
  }
  JobStore store(std::move(*db));
  PRISM_RETURN_IF_ERROR(store.migrate(file));
  return store;
}

absl::Status JobStore::migrate(const std::filesystem::path& file) {
  auto version_of = [&]() -> absl::StatusOr<int> {
    PRISM_ASSIGN_OR_RETURN(auto rows, db_.query("PRAGMA user_version"));
    PRISM_CHECK(rows.size() == 1);
    return static_cast<int>(rows[0].integer(0));
  };
  PRISM_ASSIGN_OR_RETURN(int version, version_of());
  if (version > kSchemaVersion) {
    return absl::FailedPreconditionError(
        absl::StrCat("job store ", file.string(), " has schema version ", version,
                     " but this build reads up to ", kSchemaVersion,
                     ": run a newer prism-coordinator or use another data dir"));
  }
  if (version < 0) {
    return absl::FailedPreconditionError(
        absl::StrCat("job store ", file.string(), " has an invalid schema version ", version));
  }
  for (int from = version; from < kSchemaVersion; ++from) {
    auto status = db_.transaction([&]() -> absl::Status {
      // Another process may have migrated between our read and taking the write lock.
      PRISM_ASSIGN_OR_RETURN(int current, version_of());
      if (current != from) return absl::OkStatus();
      PRISM_RETURN_IF_ERROR(db_.exec(kMigrations[from]));
      return db_.exec(absl::StrCat("PRAGMA user_version = ", from + 1));
    });
    if (!status.ok()) {
      return absl::Status(
          status.code(), absl::StrCat("migrating job store ", file.string(), " from version ", from,
                                      " to ", from + 1, ": ", status.message()));
    }
  }
  return absl::OkStatus();
}

absl::StatusOr<std::string> JobStore::allocate_id(std::string_view counter,
                                                  std::string_view prefix) {
  PRISM_ASSIGN_OR_RETURN(
      auto rows, db_.query("UPDATE counters SET value = value + 1 WHERE name = ? RETURNING value",
                           {text(counter)}));
  PRISM_CHECK(rows.size() == 1);
  std::string digits = std::to_string(rows[0].integer(0));
  if (digits.size() < 6) digits.insert(0, 6 - digits.size(), '0');
  return absl::StrCat(std::string(prefix), digits);
}

absl::StatusOr<std::vector<JobRecord>> JobStore::query_jobs(std::string_view where_and_order,
                                                            const std::vector<SqlValue>& params) {
  PRISM_ASSIGN_OR_RETURN(auto rows,
                         db_.query(absl::StrCat("SELECT ", std::string(kJobColumns), " FROM jobs ",
                                                std::string(where_and_order)),
                                   params));
  std::vector<JobRecord> jobs;
  jobs.reserve(rows.size());
  for (const auto& row : rows) jobs.push_back(job_from_row(row));
  return jobs;
}

absl::StatusOr<JobRecord> JobStore::get_job_row(std::string_view job_id) {
  PRISM_ASSIGN_OR_RETURN(auto jobs, query_jobs("WHERE id = ?", {text(job_id)}));
  if (jobs.empty()) return job_not_found(job_id);
  return std::move(jobs[0]);
}

absl::Status JobStore::insert_tasks(std::string_view job_id, std::span<const TaskRecord> tasks,
                                    int first_index) {
  PRISM_RETURN_IF_ERROR(validate_tasks(tasks, first_index));
  const std::string sql = absl::StrCat("INSERT INTO tasks (job_id, ", std::string(kTaskColumns),
                                       ") VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, 0, '')");
  std::uint64_t samples = 0;
  for (const TaskRecord& t : tasks) {
    PRISM_RETURN_IF_ERROR(db_.run(
        sql,
        {text(job_id), integer(t.index), integer(static_cast<int>(t.pass)), integer(t.pass_index),
         integer(t.tile_index), integer(t.rect.x0), integer(t.rect.y0), integer(t.rect.x1),
         integer(t.rect.y1), integer(static_cast<std::int64_t>(t.samples.s0)),
         integer(static_cast<std::int64_t>(t.samples.s1)),
         integer(static_cast<int>(TaskState::kPending))}));
    samples += task_samples(t);
  }
  return db_.run(
      "UPDATE jobs SET tasks_total = tasks_total + ?, samples_total = samples_total + ? "
      "WHERE id = ?",
      {integer(static_cast<std::int64_t>(tasks.size())),
       integer(static_cast<std::int64_t>(samples)), text(job_id)});
}

absl::StatusOr<CreateJobResult> JobStore::create_job(JobRecord job,
                                                     std::span<const TaskRecord> tasks) {
  // Validate before taking the write lock; insert_tasks checks again inside the transaction.
  PRISM_RETURN_IF_ERROR(validate_tasks(tasks, 0));
  CreateJobResult result;
  auto status = db_.transaction([&]() -> absl::Status {
    if (!job.client_token.empty()) {
      PRISM_ASSIGN_OR_RETURN(auto existing,
                             query_jobs("WHERE client_token = ?", {text(job.client_token)}));
      if (!existing.empty() && !gives_up_client_token(existing[0].state)) {
        result.job = std::move(existing[0]);
        result.existed = true;
        return absl::OkStatus();
      }
      if (!existing.empty()) {
        PRISM_RETURN_IF_ERROR(
            db_.run("UPDATE jobs SET client_token = NULL WHERE id = ?", {text(existing[0].id)}));
      }
    }
    PRISM_ASSIGN_OR_RETURN(job.id, allocate_id("job", "j-"));
    job.state = JobState::kQueued;
    job.error.clear();
    job.started_ms = 0;
    job.finished_ms = 0;
    job.report_json.clear();
    PRISM_RETURN_IF_ERROR(db_.run(
        "INSERT INTO jobs (id, client_token, spec, bundle_hash, state, submitted_ms, "
        "request_sha256) VALUES (?, ?, ?, ?, ?, ?, ?)",
        {text(job.id), optional_text(job.client_token), SqlBlob{job.spec}, text(job.bundle_hash),
         integer(static_cast<int>(job.state)), integer(job.submitted_ms), text(job.request_hash)}));
    PRISM_RETURN_IF_ERROR(insert_tasks(job.id, tasks, 0));
    PRISM_ASSIGN_OR_RETURN(result.job, get_job_row(job.id));
    return absl::OkStatus();
  });
  if (!status.ok()) return status;
  return result;
}

absl::Status JobStore::add_tasks(std::string_view job_id, std::span<const TaskRecord> tasks,
                                 Database::Commit commit) {
  return db_.transaction(
      [&]() -> absl::Status {
        PRISM_ASSIGN_OR_RETURN(JobRecord job, get_job_row(job_id));
        if (is_terminal(job.state)) {
          return absl::FailedPreconditionError(absl::StrCat(
              "job ", in_quotes(job_id), " is ", to_string(job.state), ": no tasks can be added"));
        }
        return insert_tasks(job_id, tasks, static_cast<int>(job.progress.tasks_total));
      },
      commit);
}

absl::StatusOr<JobRecord> JobStore::get_job(std::string_view job_id) {
  return get_job_row(job_id);
}

absl::StatusOr<JobRecord> JobStore::find_by_client_token(std::string_view client_token) {
  if (client_token.empty()) return absl::InvalidArgumentError("empty client token");
  PRISM_ASSIGN_OR_RETURN(auto jobs, query_jobs("WHERE client_token = ?", {text(client_token)}));
  if (jobs.empty()) {
    return absl::NotFoundError(absl::StrCat("no job with client token ", in_quotes(client_token)));
  }
  return std::move(jobs[0]);
}

absl::StatusOr<std::vector<JobRecord>> JobStore::list_jobs(std::size_t limit,
                                                           std::span<const JobState> states) {
  std::vector<SqlValue> params;
  std::string clause;
  if (!states.empty()) {
    clause = absl::StrCat("WHERE state IN (", placeholders(states.size()), ") ");
    for (JobState s : states) params.push_back(integer(static_cast<int>(s)));
  }
  clause += "ORDER BY seq DESC";
  if (limit > 0) {
    clause += " LIMIT ?";
    params.push_back(integer(static_cast<std::int64_t>(
        std::min<std::size_t>(limit, std::numeric_limits<std::int64_t>::max()))));
  }
  return query_jobs(clause, params);
}

absl::StatusOr<JobRecord> JobStore::set_job_state(std::string_view job_id, JobState to,
                                                  std::int64_t now_ms, std::string_view error) {
  JobRecord result;
  auto status = db_.transaction([&]() -> absl::Status {
    PRISM_ASSIGN_OR_RETURN(JobRecord job, get_job_row(job_id));
    if (job.state == to) {
      result = std::move(job);
      return absl::OkStatus();
    }
    if (!is_valid_transition(job.state, to)) {
      return absl::FailedPreconditionError(absl::StrCat("job ", in_quotes(job_id),
                                                        " cannot go from ", to_string(job.state),
                                                        " to ", to_string(to)));
    }
    if (to == JobState::kDone && job.progress.tasks_done != job.progress.tasks_total) {
      return absl::FailedPreconditionError(
          absl::StrCat("job ", in_quotes(job_id), " cannot be DONE with ",
                       job.progress.tasks_total - job.progress.tasks_done, " of ",
                       job.progress.tasks_total, " tasks pending"));
    }
    if (job.state == JobState::kQueued && job.started_ms == 0 && !is_terminal(to)) {
      job.started_ms = now_ms;
    }
    if (is_terminal(to)) job.finished_ms = now_ms;
    if (!error.empty()) job.error = std::string(error);
    job.state = to;
    PRISM_RETURN_IF_ERROR(
        db_.run("UPDATE jobs SET state = ?, error = ?, started_ms = ?, finished_ms = ? "
                "WHERE id = ?",
                {integer(static_cast<int>(job.state)), text(job.error), integer(job.started_ms),
                 integer(job.finished_ms), text(job_id)}));
    result = std::move(job);
    return absl::OkStatus();
  });
  if (!status.ok()) return status;
  return result;
}

absl::Status JobStore::set_report(std::string_view job_id, std::string_view report_json) {
  PRISM_RETURN_IF_ERROR(
      db_.run("UPDATE jobs SET report_json = ? WHERE id = ?", {text(report_json), text(job_id)}));
  if (db_.changes() == 0) return job_not_found(job_id);
  return absl::OkStatus();
}

absl::StatusOr<std::vector<TaskRecord>> JobStore::query_tasks(std::string_view job_id,
                                                              bool pending_only) {
  std::string sql =
      absl::StrCat("SELECT ", std::string(kTaskReadColumns), " FROM tasks WHERE job_id = ?");
  std::vector<SqlValue> params = {text(job_id)};
  if (pending_only) {
    sql += " AND state = ?";
    params.push_back(integer(static_cast<int>(TaskState::kPending)));
  }
  sql += " ORDER BY task_index";
  PRISM_ASSIGN_OR_RETURN(auto rows, db_.query(sql, params));
  // No rows is either a job with nothing (left) to do or an unknown id.
  if (rows.empty()) PRISM_RETURN_IF_ERROR(get_job_row(job_id).status());
  std::vector<TaskRecord> tasks;
  tasks.reserve(rows.size());
  for (const auto& row : rows) tasks.push_back(task_from_row(row));
  return tasks;
}

absl::StatusOr<std::vector<TaskRecord>> JobStore::tasks_of(std::string_view job_id) {
  return query_tasks(job_id, false);
}

absl::StatusOr<std::vector<std::string>> JobStore::unshared_results(std::string_view job_id) {
  PRISM_RETURN_IF_ERROR(get_job_row(job_id).status());
  PRISM_ASSIGN_OR_RETURN(
      auto rows,
      db_.query(
          absl::StrCat("SELECT DISTINCT t.result_hash FROM tasks t WHERE t.job_id = ?1 AND "
                       "t.result_hash != '' AND t.result_offset < 0 AND NOT EXISTS (SELECT 1 FROM "
                       "tasks u JOIN jobs j ON "
                       "j.id = u.job_id WHERE u.result_hash = t.result_hash AND u.job_id != ?1 AND "
                       "j.state NOT IN (",
                       static_cast<int>(JobState::kDone), ", ", static_cast<int>(JobState::kFailed),
                       ", ", static_cast<int>(JobState::kCancelled), ")) ORDER BY t.result_hash"),
          {text(job_id)}));
  std::vector<std::string> hashes;
  hashes.reserve(rows.size());
  for (const auto& row : rows) hashes.push_back(row.text(0));
  return hashes;
}

absl::StatusOr<std::vector<TaskRecord>> JobStore::pending_tasks(std::string_view job_id) {
  return query_tasks(job_id, true);
}

absl::Status JobStore::skip_tasks(std::string_view job_id, int first, int last) {
  return db_.transaction([&]() -> absl::Status {
    PRISM_ASSIGN_OR_RETURN(JobRecord job, get_job_row(job_id));
    if (first < 0 || last < first || std::uint64_t(last) > job.progress.tasks_total) {
      return absl::InvalidArgumentError(absl::StrCat("job ", in_quotes(job_id), " has tasks 0..",
                                                     job.progress.tasks_total, "; cannot skip ",
                                                     first, "..", last));
    }
    if (job.state == JobState::kFailed || job.state == JobState::kCancelled) {
      return absl::FailedPreconditionError(absl::StrCat(
          "job ", in_quotes(job_id), " is ", to_string(job.state), ": no tasks are skipped"));
    }
    PRISM_ASSIGN_OR_RETURN(
        auto rows, db_.query(absl::StrCat("SELECT ", std::string(kTaskReadColumns),
                                          " FROM tasks WHERE job_id = ? AND task_index >= ? AND "
                                          "task_index < ? ORDER BY task_index"),
                             {text(job_id), integer(first), integer(last)}));
    std::uint64_t tasks = 0, samples = 0;
    for (const auto& row : rows) {
      const TaskRecord task = task_from_row(row);
      if (task.state == TaskState::kDone) {
        return absl::FailedPreconditionError(absl::StrCat(
            "job ", in_quotes(job_id), " task ", task.index, " is done: it cannot be skipped"));
      }
      if (task.state == TaskState::kSkipped) continue;
      ++tasks;
      samples += task_samples(task);
    }
    if (tasks == 0) return absl::OkStatus();
    PRISM_RETURN_IF_ERROR(
        db_.run("UPDATE tasks SET state = ? WHERE job_id = ? AND task_index >= ? AND "
                "task_index < ? AND state = ?",
                {integer(static_cast<int>(TaskState::kSkipped)), text(job_id), integer(first),
                 integer(last), integer(static_cast<int>(TaskState::kPending))}));
    return db_.run(
        "UPDATE jobs SET tasks_done = tasks_done + ?, samples_done = samples_done + ? "
        "WHERE id = ?",
        {integer(static_cast<std::int64_t>(tasks)), integer(static_cast<std::int64_t>(samples)),
         text(job_id)});
  });
}

absl::StatusOr<bool> JobStore::mark_task_done(std::string_view job_id, int task_index,
                                              std::string_view result_hash,
                                              ResultLocation location) {
  if (result_hash.empty()) {
    return absl::InvalidArgumentError(
        absl::StrCat("job ", in_quotes(job_id), " task ", task_index, ": empty result hash"));
  }
  bool newly_done = false;
  auto status = db_.transaction(
      [&]() -> absl::Status {
        PRISM_ASSIGN_OR_RETURN(JobRecord job, get_job_row(job_id));
        PRISM_ASSIGN_OR_RETURN(
            auto rows, db_.query(absl::StrCat("SELECT ", std::string(kTaskReadColumns),
                                              " FROM tasks WHERE job_id = ? AND task_index = ?"),
                                 {text(job_id), integer(task_index)}));
        if (rows.empty()) {
          return absl::NotFoundError(absl::StrCat("job ", in_quotes(job_id), " has no task ",
                                                  task_index, " (it has ", job.progress.tasks_total,
                                                  ")"));
        }
        TaskRecord task = task_from_row(rows[0]);
        if (task.state == TaskState::kDone) {
          if (task.result_hash == result_hash) return absl::OkStatus();
          return absl::DataLossError(absl::StrCat(
              "job ", in_quotes(job_id), " task ", task_index, " is already done with result ",
              task.result_hash, " but a result with hash ", std::string(result_hash),
              " arrived: renders are deterministic, so one of them is corrupt"));
        }
        if (job.state == JobState::kFailed || job.state == JobState::kCancelled) {
          return absl::FailedPreconditionError(
              absl::StrCat("job ", in_quotes(job_id), " is ", to_string(job.state),
                           ": result for task ", task_index, " refused"));
        }
        PRISM_RETURN_IF_ERROR(db_.run(
            "UPDATE tasks SET state = ?, result_hash = ?, result_offset = ?, result_size = ? "
            "WHERE job_id = ? AND task_index = ?",
            {integer(static_cast<int>(TaskState::kDone)), text(result_hash),
             integer(location.offset), integer(static_cast<std::int64_t>(location.size)),
             text(job_id), integer(task_index)}));
        PRISM_RETURN_IF_ERROR(
            db_.run("UPDATE jobs SET tasks_done = tasks_done + 1, samples_done = samples_done + ? "
                    "WHERE id = ?",
                    {integer(static_cast<std::int64_t>(task_samples(task))), text(job_id)}));
        newly_done = true;
        return absl::OkStatus();
      },
      Database::Commit::kDeferred);
  if (!status.ok()) return status;
  return newly_done;
}

absl::Status JobStore::reopen_task(std::string_view job_id, int task_index) {
  return db_.transaction([&]() -> absl::Status {
    PRISM_RETURN_IF_ERROR(get_job_row(job_id).status());
    PRISM_ASSIGN_OR_RETURN(
        auto rows, db_.query(absl::StrCat("SELECT ", std::string(kTaskReadColumns),
                                          " FROM tasks WHERE job_id = ? AND task_index = ?"),
                             {text(job_id), integer(task_index)}));
    if (rows.empty()) {
      return absl::NotFoundError(
          absl::StrCat("job ", in_quotes(job_id), " has no task ", task_index));
    }
    const TaskRecord task = task_from_row(rows[0]);
    if (task.state != TaskState::kDone) return absl::OkStatus();
    PRISM_RETURN_IF_ERROR(db_.run(
        "UPDATE tasks SET state = ?, result_hash = '', result_offset = -1, "
        "result_size = 0 WHERE job_id = ? AND task_index = ?",
        {integer(static_cast<int>(TaskState::kPending)), text(job_id), integer(task_index)}));
    return db_.run(
        "UPDATE jobs SET tasks_done = tasks_done - 1, samples_done = samples_done - ? "
        "WHERE id = ?",
        {integer(static_cast<std::int64_t>(task_samples(task))), text(job_id)});
  });
}

absl::StatusOr<int> JobStore::record_attempt(std::string_view job_id, int task_index) {
  int attempts = 0;
  auto status = db_.transaction(
      [&]() -> absl::Status {
        PRISM_RETURN_IF_ERROR(get_job_row(job_id).status());
        PRISM_ASSIGN_OR_RETURN(auto rows,
                               db_.query("UPDATE tasks SET attempts = attempts + 1 "
                                         "WHERE job_id = ? AND task_index = ? RETURNING attempts",
                                         {text(job_id), integer(task_index)}));
        if (rows.empty()) {
          return absl::NotFoundError(
              absl::StrCat("job ", in_quotes(job_id), " has no task ", task_index));
        }
        attempts = static_cast<int>(rows[0].integer(0));
        return absl::OkStatus();
      },
      Database::Commit::kDeferred);
  if (!status.ok()) return status;
  return attempts;
}

absl::StatusOr<int> JobStore::record_worker_failure(std::string_view job_id,
                                                    std::string_view worker_id) {
  if (worker_id.empty()) return absl::InvalidArgumentError("empty worker id");
  int count = 0;
  auto status = db_.transaction([&]() -> absl::Status {
    PRISM_RETURN_IF_ERROR(get_job_row(job_id).status());
    PRISM_ASSIGN_OR_RETURN(
        auto rows, db_.query("INSERT INTO worker_failures (job_id, worker_id, count) "
                             "VALUES (?, ?, 1) "
                             "ON CONFLICT (job_id, worker_id) DO UPDATE SET count = count + 1 "
                             "RETURNING count",
                             {text(job_id), text(worker_id)}));
    PRISM_CHECK(rows.size() == 1);
    count = static_cast<int>(rows[0].integer(0));
    return absl::OkStatus();
  });
  if (!status.ok()) return status;
  return count;
}

absl::StatusOr<std::map<std::string, int>> JobStore::worker_failures(std::string_view job_id) {
  PRISM_ASSIGN_OR_RETURN(auto rows, db_.query("SELECT worker_id, count FROM worker_failures "
                                              "WHERE job_id = ?",
                                              {text(job_id)}));
  if (rows.empty()) PRISM_RETURN_IF_ERROR(get_job_row(job_id).status());
  std::map<std::string, int> failures;
  for (const auto& row : rows) failures[row.text(0)] = static_cast<int>(row.integer(1));
  return failures;
}

absl::StatusOr<JobProgress> JobStore::progress(std::string_view job_id) {
  PRISM_ASSIGN_OR_RETURN(JobRecord job, get_job_row(job_id));
  return job.progress;
}

absl::StatusOr<JobStore::TileCounts> JobStore::final_tile_counts(std::string_view job_id) {
  PRISM_ASSIGN_OR_RETURN(
      auto rows,
      db_.query("SELECT COUNT(*), COALESCE(SUM(pending = 0), 0) FROM (SELECT tile_index, "
                "SUM(state = ?) AS pending FROM tasks WHERE job_id = ? AND pass = ? "
                "GROUP BY tile_index)",
                {integer(static_cast<int>(TaskState::kPending)), text(job_id),
                 integer(static_cast<int>(TaskPass::kFinal))}));
  PRISM_CHECK(rows.size() == 1);
  return TileCounts{.done = rows[0].integer(1), .total = rows[0].integer(0)};
}

absl::StatusOr<std::vector<int>> JobStore::done_final_tiles(std::string_view job_id) {
  PRISM_ASSIGN_OR_RETURN(
      auto rows, db_.query("SELECT tile_index FROM tasks WHERE job_id = ? AND pass = ? "
                           "GROUP BY tile_index HAVING SUM(state = ?) = 0 ORDER BY tile_index",
                           {text(job_id), integer(static_cast<int>(TaskPass::kFinal)),
                            integer(static_cast<int>(TaskState::kPending))}));
  std::vector<int> tiles;
  tiles.reserve(rows.size());
  for (const auto& row : rows) tiles.push_back(static_cast<int>(row.integer(0)));
  return tiles;
}

absl::StatusOr<std::map<JobState, std::int64_t>> JobStore::count_jobs_by_state() {
  PRISM_ASSIGN_OR_RETURN(
      auto rows, db_.query("SELECT state, COUNT(*) FROM jobs GROUP BY state ORDER BY state"));
  std::map<JobState, std::int64_t> counts;
  for (const auto& row : rows) counts[static_cast<JobState>(row.integer(0))] = row.integer(1);
  return counts;
}

absl::StatusOr<std::vector<JobRecord>> JobStore::jobs_to_resume() {
  return query_jobs(
      "WHERE state NOT IN (?, ?, ?) ORDER BY seq ASC",
      {integer(static_cast<int>(JobState::kDone)), integer(static_cast<int>(JobState::kFailed)),
       integer(static_cast<int>(JobState::kCancelled))});
}

absl::StatusOr<WorkerRecord> JobStore::register_worker(WorkerRecord record) {
  for (const auto& c : record.capabilities) {
    bool printable =
        std::all_of(c.begin(), c.end(), [](char ch) { return ch >= 0x20 && ch < 0x7f; });
    if (c.empty() || !printable) {
      return absl::InvalidArgumentError(
          absl::StrCat("worker capability ", in_quotes(c), " is empty or not printable ASCII"));
    }
  }
  if (record.threads < 0) {
    return absl::InvalidArgumentError(absl::StrCat("worker threads ", record.threads, " < 0"));
  }
  WorkerRecord stored;
  auto status = db_.transaction([&]() -> absl::Status {
    if (record.id.empty()) {
      PRISM_ASSIGN_OR_RETURN(record.id, allocate_id("worker", "w-"));
    }
    PRISM_RETURN_IF_ERROR(db_.run(
        absl::StrCat("INSERT INTO workers (", std::string(kWorkerColumns),
                     ") VALUES (?, ?, ?, ?, "
                     "?, ?, ?) "
                     "ON CONFLICT (id) DO UPDATE SET host = excluded.host, "
                     "version = excluded.version, threads = excluded.threads, "
                     "capabilities = excluded.capabilities, last_seen_ms = excluded.last_seen_ms, "
                     "left_ms = excluded.left_ms"),
        {text(record.id), text(record.host), text(record.version), integer(record.threads),
         text(join_capabilities(record.capabilities)), integer(record.last_seen_ms),
         integer(record.left_ms)}));
    stored = record;
    return absl::OkStatus();
  });
  if (!status.ok()) return status;
  return stored;
}

absl::Status JobStore::touch_worker(std::string_view worker_id, std::int64_t now_ms) {
  return db_.transaction(
      [&]() -> absl::Status {
        PRISM_RETURN_IF_ERROR(db_.run("UPDATE workers SET last_seen_ms = ? WHERE id = ?",
                                      {integer(now_ms), text(worker_id)}));
        if (db_.changes() == 0) {
          return absl::NotFoundError(absl::StrCat("no worker ", in_quotes(worker_id)));
        }
        return absl::OkStatus();
      },
      Database::Commit::kDeferred);
}

absl::Status JobStore::mark_worker_left(std::string_view worker_id, std::int64_t now_ms) {
  return db_.transaction([&]() -> absl::Status {
    PRISM_RETURN_IF_ERROR(db_.run("UPDATE workers SET left_ms = ?, last_seen_ms = ? WHERE id = ?",
                                  {integer(now_ms), integer(now_ms), text(worker_id)}));
    if (db_.changes() == 0) {
      return absl::NotFoundError(absl::StrCat("no worker ", in_quotes(worker_id)));
    }
    return absl::OkStatus();
  });
}

absl::StatusOr<int> JobStore::forget_workers(std::int64_t seen_before_ms,
                                             const std::vector<std::string>& keep) {
  int forgotten = 0;
  auto status = db_.transaction([&]() -> absl::Status {
    PRISM_ASSIGN_OR_RETURN(auto rows, db_.query("SELECT id FROM workers WHERE last_seen_ms < ?",
                                                {integer(seen_before_ms)}));
    for (const auto& row : rows) {
      const std::string id = row.text(0);
      if (std::find(keep.begin(), keep.end(), id) != keep.end()) continue;
      PRISM_RETURN_IF_ERROR(db_.run("DELETE FROM workers WHERE id = ?", {text(id)}));
      ++forgotten;
    }
    return absl::OkStatus();
  });
  if (!status.ok()) return status;
  return forgotten;
}

absl::StatusOr<WorkerRecord> JobStore::get_worker(std::string_view worker_id) {
  PRISM_ASSIGN_OR_RETURN(auto rows, db_.query(absl::StrCat("SELECT ", std::string(kWorkerColumns),
                                                           " FROM workers WHERE id = ?"),
                                              {text(worker_id)}));
  if (rows.empty()) return absl::NotFoundError(absl::StrCat("no worker ", in_quotes(worker_id)));
  return worker_from_row(rows[0]);
}

absl::StatusOr<std::vector<WorkerRecord>> JobStore::list_workers() {
  PRISM_ASSIGN_OR_RETURN(auto rows, db_.query(absl::StrCat("SELECT ", std::string(kWorkerColumns),
                                                           " FROM workers ORDER BY seq")));
  std::vector<WorkerRecord> workers;
  workers.reserve(rows.size());
  for (const auto& row : rows) workers.push_back(worker_from_row(row));
  return workers;
}

}  // namespace prism::store
