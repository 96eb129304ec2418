// The pipeline's element-wise passes over a frame's planes, split into parallel chunks: each
// element is written by one task, with the same arithmetic as one serial loop.
#pragma once

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <cstddef>

namespace proden {

// body(begin, end) over [0, n), in chunks of at least `grain` elements.
template <class F>
void parallel_chunks(std::size_t n, std::size_t grain, F&& body) {
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, grain),
                    [&](const tbb::blocked_range<std::size_t>& r) { body(r.begin(), r.end()); });
}

}  // namespace proden
