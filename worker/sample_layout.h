// The sample-dimension layout every camera-path integrator reads its numbers from, so that each
// decision of each bounce always reads the same dimensions of the pixel sample's stream
// (sampler.h), and a gradient base path is drawn exactly like a `uniform` path (its offsets
// consume no numbers of their own). Pairs start on even dimensions, where the padded Sobol
// sampler is a 2D net. Changing a value changes every image's bytes.
#pragma once

#include <cstdint>

namespace prism::worker::layout {

inline constexpr std::uint32_t kDimFilm = 0;  // 2D
inline constexpr std::uint32_t kDimLens = 2;  // 2D
inline constexpr std::uint32_t kDimWavelength = 4;
inline constexpr std::uint32_t kDimBounce = 6;  // first dimension of bounce 0
inline constexpr std::uint32_t kDimsPerBounce = 12;
// Within a bounce, from kDimBounce + depth · kDimsPerBounce:
inline constexpr std::uint32_t kLightPosition = 0;  // 2D
inline constexpr std::uint32_t kLightChoice = 2;
inline constexpr std::uint32_t kLightExtra = 3;        // read with kLightChoice as one pair
inline constexpr std::uint32_t kScatterDirection = 4;  // 2D
inline constexpr std::uint32_t kScatterLobe = 6;
inline constexpr std::uint32_t kRoulette = 7;  // read with kScatterLobe as one pair
inline constexpr std::uint32_t kFreeFlight = 8;
// Free flights after crossing medium boundaries within one bounce each need fresh numbers.
inline constexpr std::uint32_t kDimCrossings = 1u << 16;
inline constexpr std::uint32_t kCrossingsPerBounce = 64;

// Light paths (light_tracer.h), from their own stream (pass kLightPathPass):
namespace light {
inline constexpr std::uint32_t kWavelength = 0;
inline constexpr std::uint32_t kChoice = 1;    // which light
inline constexpr std::uint32_t kPosition = 2;  // 2D: the point on it
inline constexpr std::uint32_t kTriangle = 4;  // an area light's triangle
inline constexpr std::uint32_t kSide = 5;      // a two-sided light's side
inline constexpr std::uint32_t kEmission = 6;  // 2D: the emitted direction
inline constexpr std::uint32_t kBounce = 8;    // first dimension of bounce 0
inline constexpr std::uint32_t kDimsPerBounce = 4;
// Within a bounce: the scattered direction (2D) at 0, the lobe at 2, Russian roulette at 3.
// Segment i's free flight through a medium at kFreeFlight + i (a medium vertex takes its
// bounce's dimensions: the phase function's direction at 0, Russian roulette at 3).
inline constexpr std::uint32_t kFreeFlight = 1u << 15;
// A thin lens: connection i's lens point (2D) at kLensConnect + 2i.
inline constexpr std::uint32_t kLensConnect = 1u << 16;
}  // namespace light

}  // namespace prism::worker::layout
