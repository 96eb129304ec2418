// The process-wide caps on library thread pools (oneTBB, OpenImageIO, OpenEXR), shared by every
// `proden` command and the daemon's in-process tests: `--threads N`, or one thread in a
// ThreadSanitizer build.
#pragma once

#include <OpenImageIO/imageio.h>
#include <tbb/global_control.h>

#include <cstddef>
#include <memory>

namespace proden {

// A ThreadSanitizer build (PRODEN_TSAN) runs the libraries' parallel work on the thread that asks
// for it. Debian's libtbb, libOpenImageIO and libIlmThread are not instrumented, so TSan cannot
// see the hand-over between a caller and their pool workers and would report each as a race.
// With no pool workers, TSan checks everything proden's own threads (daemon workers, HTTP,
// watcher, SSE) share, and no pool needs a suppression (tests/tsan.supp). Races between tiles of
// one frame are the tiled-equals-whole tests' business (docs/pipeline.md), so that build leaves
// the denoisers, mixers and t-test uninstrumented (pipeline/CMakeLists.txt).
#ifdef PRODEN_TSAN_BUILD
inline constexpr bool kSerialLibraries = true;
#else
inline constexpr bool kSerialLibraries = false;
#endif

// The TBB cap to hold for the life of the process: `requested` threads (0 = all cores), one in a
// TSan build (which also turns OpenImageIO's and OpenEXR's pools off); nullptr when nothing is
// capped.
inline std::unique_ptr<tbb::global_control> limit_threads(int requested) {
  if (kSerialLibraries) {
    OIIO::attribute("threads", 1);       // OpenImageIO's own pool: the caller only
    OIIO::attribute("exr_threads", -1);  // OpenEXR's IlmThread pool: none
  }
  const std::size_t n =
      kSerialLibraries ? 1 : static_cast<std::size_t>(requested > 0 ? requested : 0);
  if (n == 0) return nullptr;
  return std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism, n);
}

}  // namespace proden
