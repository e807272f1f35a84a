// Test support: a GoogleTest fixture for tests that build render scenes, with the built-in
// spectrum library and an Embree device made once per test suite (both are costly to make and
// read-only afterwards).
#pragma once

#include <gtest/gtest.h>

#include "services/spectral/named_spectra.h"
#include "worker/embree_device.h"

namespace prism::worker::testing {

class TracerTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    library_ = new spectral::SpectrumLibrary(*spectral::SpectrumLibrary::load_builtin());
    device_ = new EmbreeDevice();
  }
  static void TearDownTestSuite() {
    delete device_;
    delete library_;
    device_ = nullptr;
    library_ = nullptr;
  }

  static inline spectral::SpectrumLibrary* library_ = nullptr;
  static inline EmbreeDevice* device_ = nullptr;
};

}  // namespace prism::worker::testing
