// Test support: a fresh self-signed certificate for "localhost" and 127.0.0.1 (an EC P-256 key,
// valid for an hour, usable as its own CA), for tests of TLS on loopback.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

namespace prism::testing {

// Writes the certificate and its private key as PEM files; fails the current test on error.
// `extra_ips`: more IPv4 addresses the certificate names (servers reached across namespaces).
void make_self_signed(const std::filesystem::path& cert_path, const std::filesystem::path& key_path,
                      const std::vector<std::string>& extra_ips = {});

}  // namespace prism::testing
