// The Embree device: built once in `main` (or a test) and passed down, never a global. Embree
// reports errors through a C callback; throwing through its C frames would be undefined, so the
// callback only records the first error (and counts the rest) inside this wrapper, and callers
// check `take_error()` after each commit or build step and turn it into an absl::Status.
#pragma once

#include <embree3/rtcore.h>

#include <atomic>
#include <mutex>
#include <string>

#include "absl/status/status.h"

namespace prism::worker {

class EmbreeDevice {
 public:
  // `config` is Embree's device configuration string, e.g. "threads=1" (empty: defaults).
  explicit EmbreeDevice(const std::string& config = "");
  ~EmbreeDevice();
  EmbreeDevice(const EmbreeDevice&) = delete;
  EmbreeDevice& operator=(const EmbreeDevice&) = delete;

  RTCDevice get() const { return device_; }
  bool valid() const { return device_ != nullptr; }

  // OK, or the first error Embree reported since the last call (with how many followed it),
  // and clears it.
  absl::Status take_error();

 private:
  static void on_error(void* self, RTCError code, const char* message);

  RTCDevice device_ = nullptr;
  std::mutex mutex_;
  std::string first_error_;
  int error_count_ = 0;
};

}  // namespace prism::worker
