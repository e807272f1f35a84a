#include "worker/embree_device.h"

#include "absl/strings/str_cat.h"

namespace prism::worker {
namespace {

const char* error_name(RTCError code) {
  switch (code) {
    case RTC_ERROR_NONE: return "none";
    case RTC_ERROR_UNKNOWN: return "unknown error";
    case RTC_ERROR_INVALID_ARGUMENT: return "invalid argument";
    case RTC_ERROR_INVALID_OPERATION: return "invalid operation";
    case RTC_ERROR_OUT_OF_MEMORY: return "out of memory";
    case RTC_ERROR_UNSUPPORTED_CPU: return "unsupported CPU";
    case RTC_ERROR_CANCELLED: return "cancelled";
  }
  return "unrecognised error";
}

}  // namespace

EmbreeDevice::EmbreeDevice(const std::string& config) {
  device_ = rtcNewDevice(config.empty() ? nullptr : config.c_str());
  if (device_ == nullptr) {
    first_error_ = absl::StrCat("cannot create an Embree device: ", error_name(rtcGetDeviceError(nullptr)));
    error_count_ = 1;
    return;
  }
  rtcSetDeviceErrorFunction(device_, &EmbreeDevice::on_error, this);
}

EmbreeDevice::~EmbreeDevice() {
  if (device_ != nullptr) rtcReleaseDevice(device_);
}

void EmbreeDevice::on_error(void* self, RTCError code, const char* message) {
  auto* device = static_cast<EmbreeDevice*>(self);
  std::lock_guard<std::mutex> lock(device->mutex_);
  if (device->error_count_++ == 0) {
    device->first_error_ = absl::StrCat("embree: ", error_name(code), message ? ": " : "",
                                        message ? message : "");
  }
}

absl::Status EmbreeDevice::take_error() {
  std::lock_guard<std::mutex> lock(mutex_);
  if (error_count_ == 0) return absl::OkStatus();
  std::string text = first_error_;
  if (error_count_ > 1) absl::StrAppend(&text, " (and ", error_count_ - 1, " more)");
  first_error_.clear();
  error_count_ = 0;
  return absl::InternalError(text);
}

}  // namespace prism::worker
