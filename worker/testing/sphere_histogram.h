// Test helper: chi-square tests of direction samplers (BSDFs, phase functions) against their
// densities. Directions are binned in (θ, φ) with θ uniform, so cells near the poles stay small.
// Expected counts integrate the density over each cell (dω = sin θ dθ dφ) with a midpoint rule
// refined per cell until two successive refinements agree to 1e-4 of the sample count, so
// narrow lobes are resolved where they are and smooth cells stay cheap. A sampler that fails
// (leaves the sphere) simply contributes no count: its density then integrates to less than 1
// and the test compares against that mass.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <functional>
#include <initializer_list>
#include <vector>

#include "services/spectral/sampled.h"
#include "worker/vecmath.h"

namespace prism::worker::testing {

inline constexpr int kThetaCells = 24;
inline constexpr int kPhiCells = 48;
inline constexpr int kCells = kThetaCells * kPhiCells;

inline int cell_of(const Vec3f& w) {
  float theta = std::acos(std::clamp(w.z, -1.0f, 1.0f));
  float phi = std::atan2(w.y, w.x);
  if (phi < 0) phi += 2 * kPi;
  int ti = std::min(kThetaCells - 1, int(theta / kPi * kThetaCells));
  int pi = std::min(kPhiCells - 1, int(phi / (2 * kPi) * kPhiCells));
  return ti * kPhiCells + pi;
}

// A spectrum with the given lane values (the rest 0), for BSDF parameters in tests.
inline spectral::SampledSpectrum spectrum_of(std::initializer_list<float> values) {
  spectral::SampledSpectrum s;
  int i = 0;
  for (float v : values) s[i++] = v;
  return s;
}

// A density per lane (lanes 0..lanes-1 of the returned spectrum).
using LaneDensity = std::function<spectral::SampledSpectrum(const Vec3f&)>;

using LaneSums = std::array<double, spectral::kMaxLanes>;

// The n x n midpoint rule over the (θ, φ) cell [θ0, θ0 + Δθ] x [φ0, φ0 + Δφ] of the unit
// sphere: calls point(w, weight) at each midpoint's direction w with weight sin θ dθ dφ, so the
// weighted sum of a density integrates it over the cell's solid angle.
template <typename Point>
void for_each_midpoint(double theta0, double cell_theta, double phi0, double cell_phi, int n,
                       Point&& point) {
  const double dtheta = cell_theta / n, dphi = cell_phi / n;
  for (int a = 0; a < n; ++a) {
    const double theta = theta0 + (a + 0.5) * dtheta;
    const double weight = std::sin(theta) * dtheta * dphi;
    for (int b = 0; b < n; ++b) {
      const double phi = phi0 + (b + 0.5) * dphi;
      point(Vec3f(float(std::sin(theta) * std::cos(phi)), float(std::sin(theta) * std::sin(phi)),
                  float(std::cos(theta))),
            weight);
    }
  }
}

// ∫ pdf dω over cell (ti, pi) for every lane with an n x n midpoint rule.
inline LaneSums integrate_cell(const LaneDensity& pdf, int lanes, int ti, int pi, int n) {
  LaneSums sum{};
  for_each_midpoint(ti * kPi / kThetaCells, kPi / kThetaCells, pi * 2 * kPi / kPhiCells,
                    2 * kPi / kPhiCells, n, [&](const Vec3f& w, double weight) {
                      const spectral::SampledSpectrum p = pdf(w);
                      for (int l = 0; l < lanes; ++l) sum[l] += p[l] * weight;
                    });
  return sum;
}

// Expected counts of every lane for `samples` draws: result[lane][cell].
inline std::vector<std::vector<double>> expected_counts(const LaneDensity& pdf, int lanes,
                                                        int samples) {
  std::vector<std::vector<double>> expected(lanes, std::vector<double>(kCells, 0.0));
  for (int ti = 0; ti < kThetaCells; ++ti) {
    for (int pi = 0; pi < kPhiCells; ++pi) {
      int n = 8;
      LaneSums coarse = integrate_cell(pdf, lanes, ti, pi, n);
      LaneSums fine = integrate_cell(pdf, lanes, ti, pi, 2 * n);
      while (n < 512) {
        double change = 0;
        for (int l = 0; l < lanes; ++l) change = std::max(change, std::abs(fine[l] - coarse[l]));
        if (change * samples < 1e-4 * samples + 0.05) break;
        n *= 2;
        coarse = fine;
        fine = integrate_cell(pdf, lanes, ti, pi, 2 * n);
      }
      for (int l = 0; l < lanes; ++l) expected[l][ti * kPhiCells + pi] = fine[l] * samples;
    }
  }
  return expected;
}

// One density (lane 0 only).
inline std::vector<double> expected_counts(const std::function<double(const Vec3f&)>& pdf,
                                           int samples) {
  return expected_counts([&](const Vec3f& w) { return spectral::SampledSpectrum(float(pdf(w))); },
                         1, samples)[0];
}

}  // namespace prism::worker::testing
