// FrameIntake: decoding with resynchronisation, counters, capture of every chunk, sequence
// checks, device resets, node-id policy, incompatible devices. Nothing invalid reaches the
// consumer, and the counters say what happened.
#include <random>

#include <gtest/gtest.h>

#include "cdro/crc.h"
#include "cdro/service/capture.hpp"
#include "cdro/service/intake.hpp"
#include "support.hpp"

using namespace cdro::service;
using cdro::test::encode;
using cdro::test::helloFrame;
using cdro::test::rangeFrame;

namespace {

struct Observer final : IntakeObserver {
    std::vector<uint8_t> frame_types;
    std::vector<DeviceResetReason> resets;
    std::vector<std::string> incompatible;
    void onDeviceFrame(const cdro_frame_t &f, int64_t) override { frame_types.push_back(f.type); }
    void onDeviceReset(DeviceResetReason r, int64_t) override { resets.push_back(r); }
    void onIncompatible(const std::string &m) override { incompatible.push_back(m); }
};

// The nodes the frames below name, as nodes.ids: the device's list is known.
const std::vector<uint16_t> kListedNodes = {0x6000, 0x6069, 0x6A11, 0x6A2C};

struct Fixture {
    explicit Fixture(UnknownNodePolicy policy = UnknownNodePolicy::Learn, std::vector<uint16_t> ids = kListedNodes)
    {
        NodesConfig nodes;
        nodes.ids = std::move(ids);
        nodes.unknown = policy;
        intake = std::make_unique<FrameIntake>(nodes, 100.0, counters, clock);
        intake->setConsumer(&consumer);
        intake->setObserver(&observer);
    }
    void feed(const std::vector<uint8_t> &bytes, int64_t t_us = 1'700'000'000'000'000)
    {
        intake->push(bytes.data(), bytes.size(), t_us);
    }
    ServiceCounters counters;
    ManualClock clock;
    cdro::test::RecordingConsumer consumer;
    Observer observer;
    std::unique_ptr<FrameIntake> intake;
};

uint64_t rejectedSum(const ServiceCounters &c)
{
    return c.cobs_errors + c.short_errors + c.crc_errors + c.version_errors + c.type_errors + c.length_errors +
           c.value_errors + c.too_long_errors;
}

} // namespace

TEST(Intake, GoodFramesReachTheConsumerWithTheirEventTime)
{
    Fixture f;
    f.feed(encode(helloFrame(0, 100)), 1000);
    f.feed(encode(rangeFrame(1, 200, 0x6000, 0x6069, 4235)), 2000);
    ASSERT_EQ(f.consumer.received.size(), 2U);
    EXPECT_EQ(f.consumer.received[0].kind, "hello");
    EXPECT_EQ(f.consumer.received[1].kind, "range");
    EXPECT_EQ(f.consumer.received[1].frame.as.range.distance_mm, 4235U);
    EXPECT_EQ(f.consumer.received[1].context.host_unix_us, 2000);
    EXPECT_EQ(f.consumer.received[1].context.sequence, 1);
    EXPECT_EQ(f.counters.frames_ok, 2U);
    EXPECT_EQ(f.counters.frames_delivered, 2U);
    EXPECT_EQ(f.counters.chunks_rejected, 0U);
}

TEST(Intake, FramesSplitAcrossReadsAndExtraDelimitersDecode)
{
    Fixture f;
    std::vector<uint8_t> bytes = {0, 0};
    for (uint16_t s = 0; s < 20; ++s) {
        const auto frame = encode(rangeFrame(s, 100U * s, 0x6000, 0x6069, 1000U + s));
        bytes.insert(bytes.end(), frame.begin(), frame.end());
        bytes.push_back(0);
    }
    for (size_t i = 0; i < bytes.size(); i += 3) {
        f.feed(std::vector<uint8_t>(bytes.begin() + static_cast<long>(i),
                                    bytes.begin() + static_cast<long>(std::min(bytes.size(), i + 3))));
    }
    EXPECT_EQ(f.consumer.count("range"), 20U);
    EXPECT_EQ(f.counters.chunks_rejected, 0U);
    EXPECT_EQ(f.counters.sequence_gaps, 0U);
}

TEST(Intake, AbsurdValuesAreCountedAndNeverDelivered)
{
    Fixture f;
    f.feed(encode(rangeFrame(0, 10, 0x6000, 0x6069, 1000)));
    f.feed(encode(rangeFrame(1, 20, 0x6000, 0x6069, CDRO_MAX_DISTANCE_MM + 1))); // beyond 200 m
    f.feed(encode(rangeFrame(2, 30, 0x6069, 0x6069, 1000)));                     // to itself
    f.feed(encode(rangeFrame(3, 40, 0, 0x6069, 1000)));                          // node id 0
    cdro_frame_t motion{};
    motion.type = CDRO_FRAME_MOTION;
    motion.sequence = 4;
    motion.as.motion = {50, 0x6069, 7, 1000, 10, 0}; // moving = 7
    f.feed(encode(motion));
    f.feed(encode(rangeFrame(5, 60, 0x6000, 0x6069, 2000)));
    EXPECT_EQ(f.counters.value_errors, 4U);
    ASSERT_EQ(f.consumer.count("range"), 2U);
    for (const auto &r : f.consumer.received) {
        EXPECT_LE(r.frame.as.range.distance_mm, CDRO_MAX_DISTANCE_MM);
    }
    // The rejected frames were frames the device sent: the gap says so.
    EXPECT_EQ(f.counters.frames_lost, 4U);
}

TEST(Intake, GarbageAndBitFlipsResynchroniseAndAddUp)
{
    const uint32_t seed = cdro::test::testSeed("GarbageAndBitFlipsResynchroniseAndAddUp");
    std::mt19937 rng(seed);
    Fixture f;
    std::vector<uint8_t> stream;
    size_t good_sent = 0;
    for (uint16_t s = 0; s < 2000; ++s) {
        std::vector<uint8_t> frame = encode(rangeFrame(s, 10U * s, 0x6000, 0x6069, 1000U + s));
        const auto dice = static_cast<uint32_t>(rng() % 10);
        if (dice == 0) {
            frame[rng() % (frame.size() - 1)] ^= static_cast<uint8_t>(1U << (rng() % 8)); // a bit flip
        } else if (dice == 1) {
            frame.resize(frame.size() / 2); // cut in half: runs into the next frame
        } else if (dice == 2) {
            for (int i = 0; i < 1 + static_cast<int>(rng() % 40); ++i) {
                stream.push_back(static_cast<uint8_t>(rng())); // garbage between frames
            }
            ++good_sent;
        } else {
            ++good_sent;
        }
        stream.insert(stream.end(), frame.begin(), frame.end());
    }
    stream.push_back(0);
    f.feed(stream);
    const ServiceCounters &c = f.counters;
    EXPECT_EQ(c.chunks_rejected, rejectedSum(c));
    EXPECT_GT(c.chunks_rejected, 100U);
    EXPECT_GT(c.crc_errors + c.cobs_errors + c.short_errors + c.length_errors, 0U);
    // Every delivered range is one the device sent, unchanged.
    for (const auto &r : f.consumer.received) {
        ASSERT_EQ(r.kind, "range");
        EXPECT_EQ(r.frame.as.range.distance_mm, 1000U + r.context.sequence);
    }
    // Garbage and a flipped bit cost at most the frame they hit and the one they ran into.
    EXPECT_GE(f.consumer.count("range") + 2 * (2000 - good_sent) + 400, 2000U);
    EXPECT_EQ(c.frames_ok, f.consumer.count("range") + c.duplicate_frames);
}

TEST(Intake, EveryChunkIsCapturedGoodAndBad)
{
    cdro::test::TempDir dir;
    ServiceCounters counters;
    CaptureConfig config;
    config.path = dir.file("c.cdrocap");
    CaptureWriter capture(config, "test", counters);
    capture.open(5);
    Fixture f;
    f.intake->setCapture(&capture);
    std::vector<uint8_t> stream = encode(rangeFrame(0, 1, 0x6000, 0x6069, 1000));
    const std::vector<uint8_t> garbage = {1, 2, 3, 4, 5, 0};
    stream.insert(stream.end(), garbage.begin(), garbage.end());
    const auto second = encode(rangeFrame(1, 2, 0x6000, 0x6069, 1001));
    stream.insert(stream.end(), second.begin(), second.end() - 4); // cut: ends with the stream
    f.feed(stream, 777);
    f.intake->endOfStream(888);
    capture.close();

    CaptureReader reader(config.path);
    std::vector<CaptureRecord> records;
    CaptureRecord record;
    while (reader.next(record)) {
        records.push_back(record);
    }
    ASSERT_EQ(records.size(), 3U);
    EXPECT_EQ(records[0].data.size(), stream.size() - garbage.size() - (second.size() - 4) - 1);
    EXPECT_EQ(records[0].host_time_us, 777);
    EXPECT_EQ(records[1].data, std::vector<uint8_t>({1, 2, 3, 4, 5}));
    EXPECT_EQ(records[2].host_time_us, 888);
    EXPECT_EQ(f.counters.chunks_rejected, 2U);
    EXPECT_EQ(f.consumer.count("range"), 1U);
}

TEST(Intake, DuplicatesAndGapsAreCounted)
{
    Fixture f;
    for (const uint16_t s : std::initializer_list<uint16_t>{10, 11, 11, 12, 15, 16, 16, 20}) {
        f.feed(encode(rangeFrame(s, 100U * s, 0x6000, 0x6069, 1000U + s)));
    }
    EXPECT_EQ(f.counters.duplicate_frames, 2U);
    EXPECT_EQ(f.counters.sequence_gaps, 2U);
    EXPECT_EQ(f.counters.frames_lost, 2U + 3U);
    EXPECT_EQ(f.consumer.count("range"), 6U);
    EXPECT_EQ(f.counters.device_resets, 0U);
}

TEST(Intake, SequenceWrapIsNotAGap)
{
    Fixture f;
    f.feed(encode(rangeFrame(65534, 100, 0x6000, 0x6069, 1)));
    f.feed(encode(rangeFrame(65535, 200, 0x6000, 0x6069, 2)));
    f.feed(encode(rangeFrame(0, 300, 0x6000, 0x6069, 3)));
    EXPECT_EQ(f.counters.sequence_gaps, 0U);
    EXPECT_EQ(f.counters.device_resets, 0U);
}

TEST(Intake, ResetsAreDetectedByBootHelloTimeAndUnexpectedHello)
{
    Fixture f;
    f.feed(encode(helloFrame(0, 50)));
    f.feed(encode(rangeFrame(1, 5000, 0x6000, 0x6069, 1000)));
    f.feed(encode(rangeFrame(2, 6000, 0x6000, 0x6069, 1000)));
    EXPECT_EQ(f.counters.device_resets, 0U); // the first HELLO is expected
    f.feed(encode(helloFrame(0, 40)));       // firmware reset: boot HELLO
    EXPECT_EQ(f.counters.device_resets, 1U);
    f.feed(encode(rangeFrame(1, 900, 0x6000, 0x6069, 1000)));
    f.feed(encode(rangeFrame(2, 100, 0x6000, 0x6069, 1000))); // time back 800 ms: jitter, no reset
    EXPECT_EQ(f.counters.device_resets, 1U);
    f.feed(encode(rangeFrame(3, 60000, 0x6000, 0x6069, 1000)));
    f.feed(encode(rangeFrame(4, 20, 0x6000, 0x6069, 1000))); // time went back a minute
    EXPECT_EQ(f.counters.device_resets, 2U);
    f.intake->noteSentFrame(CDRO_FRAME_HELLO_REQUEST);
    f.feed(encode(helloFrame(5, 30))); // requested: no reset
    EXPECT_EQ(f.counters.device_resets, 2U);
    f.feed(encode(helloFrame(6, 40))); // not requested, not at boot
    EXPECT_EQ(f.counters.device_resets, 3U);
    ASSERT_EQ(f.observer.resets.size(), 3U);
    EXPECT_EQ(f.observer.resets[0], DeviceResetReason::SequenceRestart);
    EXPECT_EQ(f.observer.resets[1], DeviceResetReason::TimeBackwards);
    EXPECT_EQ(f.observer.resets[2], DeviceResetReason::UnexpectedHello);
    EXPECT_EQ(f.consumer.count("reset"), 3U);
    EXPECT_EQ(f.counters.duplicate_frames, 0U);
}

// A slow link answers two HELLO_REQUESTs late, one after the other. Both HELLOs
// were asked for: neither is a reset. A third, unasked, is.
TEST(Intake, EveryOutstandingHelloRequestMakesOneHelloExpected)
{
    Fixture f;
    f.feed(encode(helloFrame(0, 50)));
    f.feed(encode(rangeFrame(1, 5000, 0x6000, 0x6069, 1000)));
    f.intake->noteSentFrame(CDRO_FRAME_HELLO_REQUEST);
    f.intake->noteSentFrame(CDRO_FRAME_HELLO_REQUEST);
    f.feed(encode(rangeFrame(2, 6000, 0x6000, 0x6069, 1000)));
    f.feed(encode(helloFrame(3, 6100)));
    f.feed(encode(rangeFrame(4, 6200, 0x6000, 0x6069, 1000)));
    f.feed(encode(helloFrame(5, 6300)));
    EXPECT_EQ(f.counters.device_resets, 0U);
    EXPECT_TRUE(f.observer.resets.empty());
    f.feed(encode(helloFrame(6, 6400)));
    EXPECT_EQ(f.counters.device_resets, 1U);
}

TEST(Intake, DeviceTimeWrapAfter49DaysIsNotAReset)
{
    Fixture f;
    f.feed(encode(rangeFrame(1, UINT32_MAX - 10, 0x6000, 0x6069, 1000)));
    f.feed(encode(rangeFrame(2, 30, 0x6000, 0x6069, 1000)));
    EXPECT_EQ(f.counters.device_resets, 0U);
}

TEST(Intake, UnknownNodesAreLearnedOrRejectedByPolicy)
{
    // Policy learn, no node list known yet (nodes.ids empty, no NODE_LIST): an id becomes a
    // node once it has been seen in kFramesToConfirmNode frames; the frames before are dropped.
    Fixture learn(UnknownNodePolicy::Learn, {});
    learn.feed(encode(helloFrame(0, 5, 0x6000))); // the own node becomes known
    for (uint16_t s = 1; s <= FrameIntake::kFramesToConfirmNode; ++s) {
        learn.feed(encode(rangeFrame(s, 10U * s, 0x6000, 0x6A11, 1000)));
    }
    learn.feed(encode(rangeFrame(10, 100, 0x6000, 0x6A11, 1000)));
    EXPECT_EQ(learn.counters.nodes_learned, 1U);
    EXPECT_EQ(learn.counters.unknown_node_frames, FrameIntake::kFramesToConfirmNode);
    EXPECT_EQ(learn.counters.frames_rejected_unknown_node, FrameIntake::kFramesToConfirmNode - 1U);
    EXPECT_EQ(learn.consumer.count("range"), 2U); // the confirming frame and the next

    Fixture reject(UnknownNodePolicy::Reject, {0x6069});
    reject.feed(encode(helloFrame(0, 5, 0x6000))); // the own node becomes known
    reject.feed(encode(rangeFrame(1, 10, 0x6000, 0x6069, 1000)));
    reject.feed(encode(rangeFrame(2, 20, 0x6069, 0x6A11, 1000))); // 0x6A11 unknown
    EXPECT_EQ(reject.counters.frames_rejected_unknown_node, 1U);
    EXPECT_EQ(reject.consumer.count("range"), 1U);
    cdro_frame_t list{};
    list.type = CDRO_FRAME_NODE_LIST;
    list.sequence = 3;
    list.as.node_list.source = CDRO_NODE_SOURCE_HOST;
    list.as.node_list.node_ids_count = 1;
    list.as.node_list.node_ids[0] = 0x6A11;
    reject.feed(encode(list)); // now listed by the device
    reject.feed(encode(rangeFrame(4, 30, 0x6069, 0x6A11, 1000)));
    EXPECT_EQ(reject.consumer.count("range"), 2U);
    EXPECT_EQ(reject.counters.nodes_learned, 0U);
}

// Frames whose CRC passes with a corrupted node id (the proxy's phantom ids) must
// not create nodes. Once the device's node list is known (nodes.ids, or a NODE_LIST), an id
// outside it is rejected under the default policy too, however often it comes.
TEST(Intake, IdsOutsideTheDevicesNodeListAreRejectedEvenWhenLearning)
{
    Fixture configured(UnknownNodePolicy::Learn, {0x6069, 0x6A11});
    configured.feed(encode(helloFrame(0, 5, 0x6000)));
    configured.feed(encode(rangeFrame(1, 10, 0x6000, 0x6069, 1000)));
    for (uint16_t s = 2; s < 12; ++s) {
        configured.feed(encode(rangeFrame(s, 10U * s, 0x6000, 0x7B3D, 1000))); // a phantom, 10 times
    }
    EXPECT_EQ(configured.counters.nodes_learned, 0U);
    EXPECT_EQ(configured.counters.frames_rejected_unknown_node, 10U);
    EXPECT_EQ(configured.counters.unknown_node_frames, 10U);
    EXPECT_EQ(configured.consumer.count("range"), 1U);
    EXPECT_EQ(configured.intake->knownNodes().count(0x7B3D), 0U);

    Fixture listed(UnknownNodePolicy::Learn, {});
    listed.feed(encode(helloFrame(0, 5, 0x6000)));
    cdro_frame_t list{};
    list.type = CDRO_FRAME_NODE_LIST;
    list.sequence = 1;
    list.as.node_list.source = CDRO_NODE_SOURCE_DISCOVERY;
    list.as.node_list.node_ids_count = 1;
    list.as.node_list.node_ids[0] = 0x6069;
    listed.feed(encode(list));
    for (uint16_t s = 2; s < 8; ++s) {
        listed.feed(encode(rangeFrame(s, 10U * s, 0x6000, 0x1234, 1000)));
    }
    listed.feed(encode(rangeFrame(8, 80, 0x6000, 0x6069, 1000)));
    EXPECT_EQ(listed.counters.nodes_learned, 0U);
    EXPECT_EQ(listed.counters.frames_rejected_unknown_node, 6U);
    EXPECT_EQ(listed.consumer.count("range"), 1U);
}

TEST(Intake, ScatteredPhantomIdsNeverBecomeNodesBeforeTheListIsKnown)
{
    // Every phantom is another random id: none is seen often enough to be confirmed.
    Fixture f(UnknownNodePolicy::Learn, {});
    f.feed(encode(helloFrame(0, 5, 0x6000)));
    for (uint16_t s = 1; s <= 200; ++s) {
        f.feed(encode(rangeFrame(s, 10U * s, 0x6000, static_cast<uint16_t>(0x7000 + s), 1000)));
    }
    EXPECT_EQ(f.counters.nodes_learned, 0U);
    EXPECT_EQ(f.counters.frames_rejected_unknown_node, 200U);
    EXPECT_EQ(f.consumer.count("range"), 0U);
}

TEST(Intake, IncompatibleHelloNamesBothVersionsAndStopsData)
{
    Fixture f;
    cdro_frame_t hello = helloFrame(0, 5);
    hello.as.hello.protocol_version = CDRO_PROTOCOL_VERSION + 1;
    hello.as.hello.layout_hash = 0x1234;
    f.feed(encode(hello));
    ASSERT_EQ(f.observer.incompatible.size(), 1U);
    const std::string &message = f.observer.incompatible[0];
    EXPECT_NE(message.find("protocol version " + std::to_string(CDRO_PROTOCOL_VERSION + 1)), std::string::npos)
        << message;
    EXPECT_NE(message.find("0x1234"), std::string::npos) << message;
    EXPECT_NE(message.find("protocol version " + std::to_string(CDRO_PROTOCOL_VERSION)), std::string::npos) << message;
    EXPECT_NE(message.find("0x4D0F"), std::string::npos) << message;
    f.feed(encode(rangeFrame(1, 10, 0x6000, 0x6069, 1000)));
    EXPECT_EQ(f.consumer.count("range"), 0U);
    EXPECT_EQ(f.counters.frames_dropped_incompatible, 1U);
    EXPECT_TRUE(f.intake->incompatible());
    f.feed(encode(helloFrame(0, 5))); // reflashed: compatible again
    f.feed(encode(rangeFrame(1, 10, 0x6000, 0x6069, 1000)));
    EXPECT_FALSE(f.intake->incompatible());
    EXPECT_EQ(f.consumer.count("range"), 1U);
}

namespace {
// A good frame re-encoded with another protocol version in its header (and a CRC that fits).
std::vector<uint8_t> withHeaderVersion(const cdro_frame_t &frame, uint8_t version)
{
    std::vector<uint8_t> raw = encode(frame);
    uint8_t plain[CDRO_MAX_RAW_FRAME];
    const long n = cdro_cobs_decode(raw.data(), raw.size() - 1, plain, sizeof plain);
    EXPECT_GT(n, 0);
    plain[0] = version;
    const uint16_t crc = cdro_crc16(plain, static_cast<size_t>(n) - 2);
    plain[n - 2] = static_cast<uint8_t>(crc & 0xFF);
    plain[n - 1] = static_cast<uint8_t>(crc >> 8);
    uint8_t wire[CDRO_MAX_ENCODED_FRAME];
    const size_t m = cdro_cobs_encode(plain, static_cast<size_t>(n), wire, sizeof wire);
    std::vector<uint8_t> bytes(wire, wire + m);
    bytes.push_back(0);
    return bytes;
}
} // namespace

TEST(Intake, FramesOfAnotherProtocolVersionInARowMarkTheDeviceIncompatible)
{
    Fixture f;
    for (uint16_t s = 0; s < FrameIntake::kVersionErrorsForIncompatible; ++s) {
        EXPECT_TRUE(f.observer.incompatible.empty()) << s;
        f.feed(withHeaderVersion(rangeFrame(s, 10U * s, 0x6000, 0x6069, 1000), CDRO_PROTOCOL_VERSION + 1));
    }
    EXPECT_EQ(f.counters.version_errors, FrameIntake::kVersionErrorsForIncompatible);
    ASSERT_EQ(f.observer.incompatible.size(), 1U);
    EXPECT_NE(f.observer.incompatible[0].find("protocol version " + std::to_string(CDRO_PROTOCOL_VERSION + 1)),
              std::string::npos);
    EXPECT_NE(f.observer.incompatible[0].find("protocol version " + std::to_string(CDRO_PROTOCOL_VERSION)),
              std::string::npos);
}

// One frame with a valid checksum claiming another version (a corruption the CRC missed) must
// not mark the device incompatible for good: every data frame after it would be dropped.
TEST(Intake, StrayFramesOfAnotherVersionAreCountedAndLockNothingOut)
{
    Fixture f;
    f.feed(encode(helloFrame(0, 5)));
    uint16_t s = 1;
    for (int round = 0; round < 50; ++round) {
        f.feed(encode(rangeFrame(s, 10U * s, 0x6000, 0x6069, 1000)));
        ++s;
        // Fewer in a row than it takes, between good frames, again and again.
        for (uint16_t k = 0; k + 1U < FrameIntake::kVersionErrorsForIncompatible; ++k) {
            f.feed(withHeaderVersion(rangeFrame(s, 10U * s, 0x6000, 0x6069, 1000), CDRO_PROTOCOL_VERSION + 1));
            ++s;
        }
    }
    EXPECT_TRUE(f.observer.incompatible.empty());
    EXPECT_FALSE(f.intake->incompatible());
    EXPECT_EQ(f.counters.version_errors, 50U * (FrameIntake::kVersionErrorsForIncompatible - 1U));
    EXPECT_EQ(f.counters.frames_dropped_incompatible, 0U);
    EXPECT_EQ(f.consumer.count("range"), 50U);
}

TEST(Intake, HostFrameTypesFromTheDeviceAreDropped)
{
    Fixture f;
    cdro_frame_t start{};
    start.type = CDRO_FRAME_START;
    f.feed(encode(start));
    EXPECT_EQ(f.counters.unexpected_frames, 1U);
    EXPECT_TRUE(f.consumer.received.empty());
}
