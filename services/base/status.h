// Error values. Prism reports untrusted input and environment failures as absl::Status /
// absl::StatusOr<T> (which gRPC already brings); services/rpc maps them to gRPC codes at the edge.
// PRISM_RETURN_IF_ERROR and PRISM_ASSIGN_OR_RETURN keep call sites short.
#pragma once

#include "absl/status/status.h"
#include "absl/status/statusor.h"

#define PRISM_STATUS_CONCAT_INNER(a, b) a##b
#define PRISM_STATUS_CONCAT(a, b) PRISM_STATUS_CONCAT_INNER(a, b)

#define PRISM_RETURN_IF_ERROR(expr)                   \
  do {                                                \
    ::absl::Status prism_status_ = (expr);            \
    if (!prism_status_.ok()) return prism_status_;    \
  } while (false)

#define PRISM_ASSIGN_OR_RETURN_IMPL(tmp, lhs, expr) \
  auto tmp = (expr);                                \
  if (!tmp.ok()) return std::move(tmp).status();   \
  lhs = std::move(tmp).value()

#define PRISM_ASSIGN_OR_RETURN(lhs, expr) \
  PRISM_ASSIGN_OR_RETURN_IMPL(PRISM_STATUS_CONCAT(prism_statusor_, __LINE__), lhs, expr)
