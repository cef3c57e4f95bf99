#include "cdro/hostd/memory.hpp"

#if __has_include(<malloc.h>)
#include <malloc.h>
#endif

namespace cdro::hostd {

void returnLargeBuffersToTheSystem()
{
#if defined(M_MMAP_THRESHOLD) && defined(__GLIBC__)
    // Setting it at all turns off glibc's dynamic adjustment of the threshold.
    constexpr int kMmapThresholdBytes = 128 * 1024;
    mallopt(M_MMAP_THRESHOLD, kMmapThresholdBytes);
#endif
}

} // namespace cdro::hostd
