// Checking a gRPC address before gRPC sees it. gRPC reads the port of "host:port" as a number and
// wraps it into 16 bits, so "127.0.0.1:99999" became port 34463 on both the client and the
// server side without a word.
#pragma once

#include <string_view>

#include "absl/status/status.h"

namespace prism::rpc {

// INVALID_ARGUMENT, naming `flag`, unless `address` is HOST:PORT (HOST may be a bracketed IPv6
// address) with PORT a decimal number in 1..65535, or 0 too with `allow_port_zero` (a server's
// "any free port"). Targets with a gRPC scheme (unix:, dns:, ipv4:, ipv6:, ...) are left to gRPC.
absl::Status check_address(std::string_view address, std::string_view flag, bool allow_port_zero);

// True when `address` (HOST:PORT, a bracketed IPv6 HOST, or a gRPC ipv4:/unix: target) is on the
// loopback interface (127.0.0.0/8, ::1, localhost) or a Unix socket: reachable from this machine
// only. An address without a port is taken as a host.
bool is_loopback_address(std::string_view address);

}  // namespace prism::rpc
