#include "services/rpc/address.h"

#include <gtest/gtest.h>

namespace prism::rpc {
namespace {

TEST(AddressTest, PortsOutsideSixteenBitsAreRefusedNotWrapped) {
  for (const char* good :
       {"127.0.0.1:7070", "localhost:1", "coordinator.farm:65535", "[::1]:7070", "[::]:80",
        "unix:/run/prism.sock", "dns:///farm:7070", "ipv4:10.0.0.1:7070"}) {
    EXPECT_TRUE(check_address(good, "--coordinator", false).ok()) << good;
  }
  EXPECT_TRUE(check_address("127.0.0.1:0", "--listen", true).ok());
  const struct {
    const char* address;
    bool zero;
    const char* message;
  } bad[] = {
      {"127.0.0.1:99999", false,
       "--coordinator '127.0.0.1:99999': the port is not a number in 1..65535"},
      {"127.0.0.1:65536", true,
       "--listen '127.0.0.1:65536': the port is not a number in 0..65535 (0: any free port)"},
      {"127.0.0.1:0", false, "--coordinator '127.0.0.1:0': the port is not a number in 1..65535"},
      {"127.0.0.1:-1", false, "--coordinator '127.0.0.1:-1': the port is not a number in 1..65535"},
      {"127.0.0.1:80x", false,
       "--coordinator '127.0.0.1:80x': the port is not a number in 1..65535"},
      {"127.0.0.1:", false, "--coordinator '127.0.0.1:': the port is not a number in 1..65535"},
      {"127.0.0.1", false, "--coordinator '127.0.0.1': want HOST:PORT (e.g. 127.0.0.1:7070)"},
      {"127.0.0.1:0000070000", false,
       "--coordinator '127.0.0.1:0000070000': the port is not a number in 1..65535"},
  };
  for (const auto& c : bad) {
    const absl::Status s = check_address(c.address, c.zero ? "--listen" : "--coordinator", c.zero);
    EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument) << c.address;
    EXPECT_EQ(std::string(s.message()), c.message);
  }
}

TEST(AddressTest, LoopbackAddressesAreThoseOnlyThisMachineReaches) {
  for (const char* local : {"127.0.0.1:7070", "127.8.9.10:1", "localhost:80", "[::1]:7070",
                            "unix:/run/prism.sock", "unix-abstract:prism", "ipv4:127.0.0.1:7"}) {
    EXPECT_TRUE(is_loopback_address(local)) << local;
  }
  for (const char* remote : {"0.0.0.0:7070", "[::]:7070", "10.0.0.2:7070", "farm.example:7070",
                             "128.0.0.1:1", "[2001:db8::1]:80", "ipv4:10.1.1.1:7"}) {
    EXPECT_FALSE(is_loopback_address(remote)) << remote;
  }
}

}  // namespace
}  // namespace prism::rpc
