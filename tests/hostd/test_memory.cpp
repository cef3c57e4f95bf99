// The processes that run the engine give large freed buffers back to the system (memory.hpp):
// after a large block has been freed, the next large one is still mapped on its own, not carved
// out of the heap where its pages would stay resident once freed.
#include <cstddef>
#include <vector>

#include <gtest/gtest.h>

#include "cdro/hostd/memory.hpp"

#if defined(__GLIBC__) && !defined(CDRO_TEST_SANITIZED)
#include <malloc.h>
#endif

namespace {

TEST(Memory, ALargeBufferIsMappedOnItsOwnEvenAfterALargerOneWasFreed)
{
#if defined(__GLIBC__) && !defined(CDRO_TEST_SANITIZED)
    cdro::hostd::returnLargeBuffersToTheSystem();
    constexpr std::size_t kFreedBytes = 8U << 20U;
    constexpr std::size_t kNextBytes = 4U << 20U;
    {
        // Left to itself, glibc would raise its mmap threshold to this block's size when it is freed.
        std::vector<char> freed(kFreedBytes, 1);
        ASSERT_EQ(freed.back(), 1);
    }
    const std::size_t mapped_before = mallinfo2().hblkhd;
    std::vector<char> next(kNextBytes, 1);
    const std::size_t mapped_after = mallinfo2().hblkhd;
    EXPECT_GE(mapped_after - mapped_before, kNextBytes) << "the 4 MiB buffer came from the heap";
    EXPECT_EQ(next.front(), 1);
#else
    GTEST_SKIP() << "glibc's malloc only (the sanitizers bring their own)";
#endif
}

} // namespace
