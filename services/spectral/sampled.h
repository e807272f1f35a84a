// Per-path wavelength samples and the spectral values that travel with them (pbrt-v4's
// SampledWavelengths / SampledSpectrum). A path carries C lanes (1..kMaxLanes): lane 0 is the
// hero wavelength that drives path sampling (docs/estimators.md §2), each lane has a wavelength in
// nm, the density p(λ) it was drawn with (per nm) and a live flag. A SampledSpectrum is a plain
// fixed-size array of kMaxLanes floats with elementwise arithmetic over all of them; lanes at
// or beyond C are ignored by readers (sample() and pdf_spectrum() leave them 0). Both are
// trivially copyable values: nothing here allocates.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>

#include "services/base/check.h"

namespace prism::spectral {

inline constexpr int kMaxLanes = 8;
inline constexpr int kDefaultLanes = 4;

class SampledSpectrum {
 public:
  constexpr SampledSpectrum() = default;
  // Every one of the kMaxLanes lanes set to c.
  constexpr explicit SampledSpectrum(float c) { v_.fill(c); }

  float& operator[](int i) { return v_[static_cast<size_t>(i)]; }
  float operator[](int i) const { return v_[static_cast<size_t>(i)]; }
  const std::array<float, kMaxLanes>& values() const { return v_; }

  SampledSpectrum& operator+=(const SampledSpectrum& o) {
    for (int i = 0; i < kMaxLanes; ++i) v_[i] += o.v_[i];
    return *this;
  }
  SampledSpectrum& operator-=(const SampledSpectrum& o) {
    for (int i = 0; i < kMaxLanes; ++i) v_[i] -= o.v_[i];
    return *this;
  }
  SampledSpectrum& operator*=(const SampledSpectrum& o) {
    for (int i = 0; i < kMaxLanes; ++i) v_[i] *= o.v_[i];
    return *this;
  }
  // IEEE division in every lane: a zero divisor lane gives ±inf or NaN. Divide by spectra whose
  // unused lanes are 0 (such as pdfs) with safe_div instead.
  SampledSpectrum& operator/=(const SampledSpectrum& o) {
    for (int i = 0; i < kMaxLanes; ++i) v_[i] /= o.v_[i];
    return *this;
  }
  SampledSpectrum& operator+=(float s) {
    for (float& x : v_) x += s;
    return *this;
  }
  SampledSpectrum& operator-=(float s) {
    for (float& x : v_) x -= s;
    return *this;
  }
  SampledSpectrum& operator*=(float s) {
    for (float& x : v_) x *= s;
    return *this;
  }
  SampledSpectrum& operator/=(float s) {
    const float inv = 1.0f / s;
    for (float& x : v_) x *= inv;
    return *this;
  }

  friend SampledSpectrum operator+(SampledSpectrum a, const SampledSpectrum& b) { return a += b; }
  friend SampledSpectrum operator-(SampledSpectrum a, const SampledSpectrum& b) { return a -= b; }
  friend SampledSpectrum operator*(SampledSpectrum a, const SampledSpectrum& b) { return a *= b; }
  friend SampledSpectrum operator/(SampledSpectrum a, const SampledSpectrum& b) { return a /= b; }
  friend SampledSpectrum operator+(SampledSpectrum a, float s) { return a += s; }
  friend SampledSpectrum operator-(SampledSpectrum a, float s) { return a -= s; }
  friend SampledSpectrum operator*(SampledSpectrum a, float s) { return a *= s; }
  friend SampledSpectrum operator/(SampledSpectrum a, float s) { return a /= s; }
  friend SampledSpectrum operator+(float s, SampledSpectrum a) { return a += s; }
  friend SampledSpectrum operator*(float s, SampledSpectrum a) { return a *= s; }
  friend SampledSpectrum operator-(float s, const SampledSpectrum& a) {
    return SampledSpectrum(s) - a;
  }
  friend SampledSpectrum operator/(float s, const SampledSpectrum& a) {
    return SampledSpectrum(s) / a;
  }
  friend SampledSpectrum operator-(SampledSpectrum a) {
    for (float& x : a.v_) x = -x;
    return a;
  }
  friend bool operator==(const SampledSpectrum&, const SampledSpectrum&) = default;

  // True when every one of the kMaxLanes lanes is exactly 0.
  bool is_zero() const {
    for (float x : v_) {
      if (x != 0.0f) return false;
    }
    return true;
  }
  // True when any lane is NaN or infinite.
  bool has_non_finite() const {
    for (float x : v_) {
      if (!std::isfinite(x)) return true;
    }
    return false;
  }

  // Reductions over the first `lanes` lanes (1..kMaxLanes), i.e. the path's C.
  float max_value(int lanes) const {
    PRISM_CHECK(lanes >= 1 && lanes <= kMaxLanes);
    float m = v_[0];
    for (int i = 1; i < lanes; ++i) m = std::max(m, v_[i]);
    return m;
  }
  float min_value(int lanes) const {
    PRISM_CHECK(lanes >= 1 && lanes <= kMaxLanes);
    float m = v_[0];
    for (int i = 1; i < lanes; ++i) m = std::min(m, v_[i]);
    return m;
  }
  float average(int lanes) const {
    PRISM_CHECK(lanes >= 1 && lanes <= kMaxLanes);
    float s = 0.0f;
    for (int i = 0; i < lanes; ++i) s += v_[i];
    return s / static_cast<float>(lanes);
  }

 private:
  std::array<float, kMaxLanes> v_{};
};

// a / b per lane, with 0 wherever b is 0 (so unused and terminated lanes stay 0).
inline SampledSpectrum safe_div(const SampledSpectrum& a, const SampledSpectrum& b) {
  SampledSpectrum r;
  for (int i = 0; i < kMaxLanes; ++i) r[i] = b[i] != 0.0f ? a[i] / b[i] : 0.0f;
  return r;
}
inline SampledSpectrum exp(const SampledSpectrum& s) {
  SampledSpectrum r;
  for (int i = 0; i < kMaxLanes; ++i) r[i] = std::exp(s[i]);
  return r;
}
// Square root per lane, of max(x, 0): rounding can push a true 0 slightly negative.
inline SampledSpectrum sqrt(const SampledSpectrum& s) {
  SampledSpectrum r;
  for (int i = 0; i < kMaxLanes; ++i) r[i] = std::sqrt(std::max(s[i], 0.0f));
  return r;
}
inline SampledSpectrum clamp(const SampledSpectrum& s, float lo, float hi) {
  SampledSpectrum r;
  for (int i = 0; i < kMaxLanes; ++i) r[i] = std::clamp(s[i], lo, hi);
  return r;
}
inline SampledSpectrum min(const SampledSpectrum& a, const SampledSpectrum& b) {
  SampledSpectrum r;
  for (int i = 0; i < kMaxLanes; ++i) r[i] = std::min(a[i], b[i]);
  return r;
}
inline SampledSpectrum max(const SampledSpectrum& a, const SampledSpectrum& b) {
  SampledSpectrum r;
  for (int i = 0; i < kMaxLanes; ++i) r[i] = std::max(a[i], b[i]);
  return r;
}

class SampledWavelengths {
 public:
  // `lanes` lanes (1..kMaxLanes), all at 0 nm with pdf 0 and live; fill them with set().
  explicit SampledWavelengths(int lanes = kDefaultLanes) : count_(lanes) {
    PRISM_CHECK(lanes >= 1 && lanes <= kMaxLanes);
    live_.fill(false);
    for (int i = 0; i < lanes; ++i) live_[i] = true;
  }

  // Lane `lane` (< count()) gets wavelength lambda_nm and density pdf (per nm, >= 0).
  void set(int lane, float lambda_nm, float pdf) {
    PRISM_CHECK(lane >= 0 && lane < count_);
    lambda_[lane] = lambda_nm;
    pdf_[lane] = pdf;
  }

  int count() const { return count_; }
  float lambda(int lane) const { return lambda_[lane]; }
  float pdf(int lane) const { return pdf_[lane]; }
  bool live(int lane) const { return live_[lane]; }
  float hero() const { return lambda_[0]; }  // nm
  int live_count() const {
    int n = 0;
    for (int i = 0; i < count_; ++i) n += live_[i] ? 1 : 0;
    return n;
  }
  bool secondary_terminated() const { return live_count() == 1; }

  // Keeps only the hero lane live: used at a specular dispersive event, where the other lanes'
  // path densities are zero (docs/estimators.md §2). Lane pdfs are left as they are, because the
  // estimator's Σ_k p(x̄|λ_k) already drops the terminated lanes' terms.
  void terminate_secondary() {
    for (int i = 1; i < kMaxLanes; ++i) live_[i] = false;
  }

  // Per-lane densities as a spectrum, 0 in lanes beyond count().
  SampledSpectrum pdf_spectrum() const {
    SampledSpectrum s;
    for (int i = 0; i < count_; ++i) s[i] = pdf_[i];
    return s;
  }
  // 1 in live lanes, 0 elsewhere: multiply a contribution by it to drop terminated lanes.
  SampledSpectrum live_mask() const {
    SampledSpectrum s;
    for (int i = 0; i < count_; ++i) s[i] = live_[i] ? 1.0f : 0.0f;
    return s;
  }

 private:
  int count_;
  std::array<float, kMaxLanes> lambda_{};
  std::array<float, kMaxLanes> pdf_{};
  std::array<bool, kMaxLanes> live_{};
};

}  // namespace prism::spectral
