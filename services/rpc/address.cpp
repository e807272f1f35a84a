#include "services/rpc/address.h"

#include <cstdint>

#include "absl/strings/ascii.h"
#include "absl/strings/str_cat.h"

namespace prism::rpc {

absl::Status check_address(std::string_view address_in, std::string_view flag_in,
                           bool allow_port_zero) {
  const absl::string_view address(address_in.data(), address_in.size());
  const absl::string_view flag(flag_in.data(), flag_in.size());
  // A gRPC scheme ("unix:/run/p.sock", "dns:///h:1", "ipv4:1.2.3.4:5"): letters, then ':', with
  // no digit or '.' before it (which a host name would have before its port).
  const std::size_t colon = address.rfind(':');
  const std::size_t first_colon = address.find(':');
  if (first_colon != absl::string_view::npos && first_colon > 0) {
    const absl::string_view scheme = address.substr(0, first_colon);
    bool letters = true;
    for (char c : scheme) letters = letters && (absl::ascii_isalpha(c) || c == '-');
    if (letters && (scheme == "unix" || scheme == "unix-abstract" || scheme == "dns" ||
                    scheme == "ipv4" || scheme == "ipv6" || scheme == "vsock")) {
      return absl::OkStatus();
    }
  }
  auto bad = [&](absl::string_view why) {
    return absl::InvalidArgumentError(absl::StrCat(flag, " '", address, "': ", why));
  };
  if (colon == absl::string_view::npos || colon == 0) {
    return bad("want HOST:PORT (e.g. 127.0.0.1:7070)");
  }
  const absl::string_view port = address.substr(colon + 1);
  if (port.empty() || port.size() > 5) return bad("the port is not a number in 1..65535");
  std::uint32_t value = 0;
  for (char c : port) {
    if (!absl::ascii_isdigit(c)) return bad("the port is not a number in 1..65535");
    value = value * 10 + std::uint32_t(c - '0');
  }
  if (value > 65535 || (value == 0 && !allow_port_zero)) {
    return bad(allow_port_zero ? "the port is not a number in 0..65535 (0: any free port)"
                               : "the port is not a number in 1..65535");
  }
  return absl::OkStatus();
}

bool is_loopback_address(std::string_view address) {
  if (address.starts_with("unix:") || address.starts_with("unix-abstract:")) return true;
  if (address.starts_with("ipv4:")) address.remove_prefix(5);
  if (address.starts_with("ipv6:")) address.remove_prefix(5);
  std::string_view host = address;
  if (host.starts_with('[')) {
    const std::size_t close = host.find(']');
    host = close == std::string_view::npos ? host.substr(1) : host.substr(1, close - 1);
  } else if (const std::size_t colon = host.rfind(':'); colon != std::string_view::npos) {
    host = host.substr(0, colon);
  }
  return host == "localhost" || host == "::1" || host.starts_with("127.");
}

}  // namespace prism::rpc
