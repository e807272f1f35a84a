// The equal-time evaluation the benchmark programs share is `prism bench`'s (client/evaluation.h);
// this header names it in the benchmarks' namespace.
#pragma once

#include "client/compare_command.h"
#include "client/evaluation.h"
#include "tests/bench/bench_common.h"

namespace prism::bench {

using client::parse_crop;
using evaluation::cached_reference;
using evaluation::ConvergencePoint;
using evaluation::error_at_time;
using evaluation::parse_spp_list;
using evaluation::process_cpu_seconds;
using evaluation::Reference;
using evaluation::timed_render;
using evaluation::TimedRender;

}  // namespace prism::bench
