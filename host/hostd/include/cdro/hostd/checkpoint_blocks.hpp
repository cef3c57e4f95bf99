// checkpoint_blocks.hpp: the engine, movement and flight blocks of a checkpoint
// (checkpoint_layout.def's CDRO_CHECKPOINT_ENGINE_LIST, CDRO_CHECKPOINT_MOVEMENT_LIST and
// CDRO_CHECKPOINT_FLIGHT_LIST) as C++ structs, one per record, with the one writer and reader
// every record shares. The adapter (engine_adapter.cpp) only maps the engine's state to these
// structs and back; the bytes are the table's, and the Python codec
// (cdro_tools.codec.checkpoint) and docs/protocol.md read the same table.
//
// A record's struct has its fields in table order: F and R a value (F64 a double, stored as its
// bits), A a vector of at most max values (a u8 count), L a vector of the named record's struct,
// V a vector of values, Q a vector of n*n values, row by row (n: the size of V field `of`).
#pragma once

#include <cstdint>
#include <cstring>
#include <stdexcept>
#include <string>
#include <vector>

#include "cdro/checkpoint_layout.def"
#include "cdro/layout_kinds.h"
#include "cdro/service/checkpoint.hpp"

namespace cdro::hostd::blocks {

// ---- structs ------------------------------------------------------------------------------

#define CDRO_BLOCK_X_DECLARE(NAME, name, id, doc) struct name;
#define CDRO_BLOCK_X_MEMBER(KIND, field, unit, doc) CDRO_CTYPE_##KIND field{};
#define CDRO_BLOCK_X_RANGED_MEMBER(KIND, field, unit, lo, hi, doc) CDRO_CTYPE_##KIND field{};
#define CDRO_BLOCK_X_ARRAY_MEMBER(KIND, field, max, unit, lo, hi, doc) std::vector<CDRO_CTYPE_##KIND> field;
#define CDRO_BLOCK_X_LIST_MEMBER(NAME, field, doc) std::vector<NAME##_record> field;
#define CDRO_BLOCK_X_VECTOR_MEMBER(KIND, field, unit, doc) std::vector<CDRO_CTYPE_##KIND> field;
#define CDRO_BLOCK_X_SQUARE_MEMBER(KIND, field, of, unit, doc) std::vector<CDRO_CTYPE_##KIND> field;
#define CDRO_BLOCK_X_ALIAS(NAME, name, id, doc) using NAME##_record = name;
#define CDRO_BLOCK_X_STRUCT(NAME, name, id, doc)                                                                   \
    struct name {                                                                                                  \
        CDRO_BLOCK_FIELDS_##NAME(CDRO_BLOCK_X_MEMBER, CDRO_BLOCK_X_RANGED_MEMBER, CDRO_BLOCK_X_ARRAY_MEMBER,       \
                                 CDRO_BLOCK_X_LIST_MEMBER, CDRO_BLOCK_X_VECTOR_MEMBER, CDRO_BLOCK_X_SQUARE_MEMBER) \
    };

CDRO_CHECKPOINT_ENGINE_LIST(CDRO_BLOCK_X_DECLARE)
CDRO_CHECKPOINT_MOVEMENT_LIST(CDRO_BLOCK_X_DECLARE)
CDRO_CHECKPOINT_FLIGHT_LIST(CDRO_BLOCK_X_DECLARE)
CDRO_CHECKPOINT_OUTPUT_FRAME_LIST(CDRO_BLOCK_X_DECLARE)
CDRO_CHECKPOINT_ENGINE_LIST(CDRO_BLOCK_X_ALIAS)
CDRO_CHECKPOINT_MOVEMENT_LIST(CDRO_BLOCK_X_ALIAS)
CDRO_CHECKPOINT_FLIGHT_LIST(CDRO_BLOCK_X_ALIAS)
CDRO_CHECKPOINT_OUTPUT_FRAME_LIST(CDRO_BLOCK_X_ALIAS)
CDRO_CHECKPOINT_ENGINE_LIST(CDRO_BLOCK_X_STRUCT)
CDRO_CHECKPOINT_MOVEMENT_LIST(CDRO_BLOCK_X_STRUCT)
CDRO_CHECKPOINT_FLIGHT_LIST(CDRO_BLOCK_X_STRUCT)
CDRO_CHECKPOINT_OUTPUT_FRAME_LIST(CDRO_BLOCK_X_STRUCT)

// ---- bytes --------------------------------------------------------------------------------

class BlockWriter {
public:
    void value(uint8_t v) { bytes_.push_back(v); }
    void value(uint16_t v) { put(v, 2); }
    void value(uint32_t v) { put(v, 4); }
    void value(uint64_t v) { put(v, 8); }
    void value(double v)
    {
        uint64_t bits = 0;
        std::memcpy(&bits, &v, sizeof bits);
        put(bits, 8);
    }
    std::vector<uint8_t> take() { return std::move(bytes_); }

private:
    void put(uint64_t v, size_t size)
    {
        for (size_t i = 0; i < size; ++i) {
            bytes_.push_back(static_cast<uint8_t>(v >> (8U * i)));
        }
    }
    std::vector<uint8_t> bytes_;
};

class BlockReader {
public:
    // Far more than any block holds: a bigger count is damage, refused before anything is
    // allocated for it.
    static constexpr uint32_t kMaxCount = CDRO_CHECKPOINT_MAX_LIST_COUNT;

    BlockReader(const std::vector<uint8_t> &bytes, const char *block) : bytes_(bytes), block_(block) {}
    void value(uint8_t &v) { v = static_cast<uint8_t>(get(1)); }
    void value(uint16_t &v) { v = static_cast<uint16_t>(get(2)); }
    void value(uint32_t &v) { v = static_cast<uint32_t>(get(4)); }
    void value(uint64_t &v) { v = get(8); }
    void value(double &v)
    {
        const uint64_t bits = get(8);
        std::memcpy(&v, &bits, sizeof v);
    }
    uint32_t count(const char *what)
    {
        const auto n = static_cast<uint32_t>(get(4));
        if (n > kMaxCount) {
            fail(std::string("gives ") + what + " a count of " + std::to_string(n));
        }
        return n;
    }
    void inRange(uint64_t v, uint64_t lo, uint64_t hi, const char *what) const
    {
        if (v < lo || v > hi) {
            fail(std::string("has ") + what + " " + std::to_string(v) + ", outside " + std::to_string(lo) + ".." +
                 std::to_string(hi));
        }
    }
    bool done() const { return position_ == bytes_.size(); }
    [[noreturn]] void fail(const std::string &what) const
    {
        throw service::CheckpointError(std::string("the checkpoint's ") + block_ + " block " + what);
    }

private:
    uint64_t get(size_t size)
    {
        if (position_ + size > bytes_.size()) {
            throw service::CheckpointError(std::string("the ") + block_ + " block of the checkpoint is cut short");
        }
        uint64_t v = 0;
        for (size_t i = 0; i < size; ++i) {
            v |= static_cast<uint64_t>(bytes_[position_ + i]) << (8U * i);
        }
        position_ += size;
        return v;
    }
    const std::vector<uint8_t> &bytes_;
    const char *block_;
    size_t position_ = 0;
};

// ---- one writer and one reader per record, from the table -------------------------------------

#define CDRO_BLOCK_X_DECLARE_CODEC(NAME, name, id, doc) \
    inline void write(BlockWriter &out, const name &r); \
    inline void read(BlockReader &in, name &r);

CDRO_CHECKPOINT_ENGINE_LIST(CDRO_BLOCK_X_DECLARE_CODEC)
CDRO_CHECKPOINT_MOVEMENT_LIST(CDRO_BLOCK_X_DECLARE_CODEC)
CDRO_CHECKPOINT_FLIGHT_LIST(CDRO_BLOCK_X_DECLARE_CODEC)
CDRO_CHECKPOINT_OUTPUT_FRAME_LIST(CDRO_BLOCK_X_DECLARE_CODEC)

// The count before an A (u8, at most its max) or an L or V (u32).
template <typename Count, typename T>
void writeCount(BlockWriter &out, const std::vector<T> &values, size_t most, const char *what)
{
    if (values.size() > most) {
        throw std::length_error(std::string("checkpoint block: ") + what + " holds " + std::to_string(values.size()) +
                                " values, the table allows " + std::to_string(most));
    }
    out.value(static_cast<Count>(values.size()));
}

#define CDRO_BLOCK_X_WRITE(KIND, field, unit, doc) out.value(r.field);
#define CDRO_BLOCK_X_RANGED_WRITE(KIND, field, unit, lo, hi, doc) out.value(r.field);
#define CDRO_BLOCK_X_ARRAY_WRITE(KIND, field, max, unit, lo, hi, doc) \
    writeCount<uint8_t>(out, r.field, max, #field);                   \
    for (const auto &v : r.field) {                                   \
        out.value(v);                                                 \
    }
#define CDRO_BLOCK_X_LIST_WRITE(NAME, field, doc)                       \
    writeCount<uint32_t>(out, r.field, BlockReader::kMaxCount, #field); \
    for (const auto &v : r.field) {                                     \
        write(out, v);                                                  \
    }
#define CDRO_BLOCK_X_VECTOR_WRITE(KIND, field, unit, doc)               \
    writeCount<uint32_t>(out, r.field, BlockReader::kMaxCount, #field); \
    for (const auto &v : r.field) {                                     \
        out.value(v);                                                   \
    }
#define CDRO_BLOCK_X_SQUARE_WRITE(KIND, field, of, unit, doc)                                        \
    if (r.field.size() != r.of.size() * r.of.size()) {                                               \
        throw std::length_error("checkpoint block: " #field " is not the square of " #of "'s size"); \
    }                                                                                                \
    for (const auto &v : r.field) {                                                                  \
        out.value(v);                                                                                \
    }

#define CDRO_BLOCK_X_READ(KIND, field, unit, doc) in.value(r.field);
#define CDRO_BLOCK_X_RANGED_READ(KIND, field, unit, lo, hi, doc) \
    in.value(r.field);                                           \
    in.inRange(r.field, lo, hi, #field);
#define CDRO_BLOCK_X_ARRAY_READ(KIND, field, max, unit, lo, hi, doc) \
    {                                                                \
        uint8_t n = 0;                                               \
        in.value(n);                                                 \
        r.field.resize(n);                                           \
        for (auto &v : r.field) {                                    \
            in.value(v);                                             \
        }                                                            \
    }
#define CDRO_BLOCK_X_LIST_READ(NAME, field, doc)             \
    for (uint32_t i = 0, n = in.count(#field); i < n; ++i) { \
        r.field.emplace_back();                              \
        read(in, r.field.back());                            \
    }
#define CDRO_BLOCK_X_VECTOR_READ(KIND, field, unit, doc)     \
    for (uint32_t i = 0, n = in.count(#field); i < n; ++i) { \
        in.value(r.field.emplace_back());                    \
    }
#define CDRO_BLOCK_X_SQUARE_READ(KIND, field, of, unit, doc) \
    r.field.resize(r.of.size() * r.of.size());               \
    for (auto &v : r.field) {                                \
        in.value(v);                                         \
    }

#define CDRO_BLOCK_X_DEFINE_CODEC(NAME, name, id, doc)                                                          \
    inline void write(BlockWriter &out, const name &r)                                                          \
    {                                                                                                           \
        CDRO_BLOCK_FIELDS_##NAME(CDRO_BLOCK_X_WRITE, CDRO_BLOCK_X_RANGED_WRITE, CDRO_BLOCK_X_ARRAY_WRITE,       \
                                 CDRO_BLOCK_X_LIST_WRITE, CDRO_BLOCK_X_VECTOR_WRITE, CDRO_BLOCK_X_SQUARE_WRITE) \
    }                                                                                                           \
    inline void read(BlockReader &in, name &r)                                                                  \
    {                                                                                                           \
        CDRO_BLOCK_FIELDS_##NAME(CDRO_BLOCK_X_READ, CDRO_BLOCK_X_RANGED_READ, CDRO_BLOCK_X_ARRAY_READ,          \
                                 CDRO_BLOCK_X_LIST_READ, CDRO_BLOCK_X_VECTOR_READ, CDRO_BLOCK_X_SQUARE_READ)    \
    }

CDRO_CHECKPOINT_ENGINE_LIST(CDRO_BLOCK_X_DEFINE_CODEC)
CDRO_CHECKPOINT_MOVEMENT_LIST(CDRO_BLOCK_X_DEFINE_CODEC)
CDRO_CHECKPOINT_FLIGHT_LIST(CDRO_BLOCK_X_DEFINE_CODEC)
CDRO_CHECKPOINT_OUTPUT_FRAME_LIST(CDRO_BLOCK_X_DEFINE_CODEC)

// A whole block: its bytes, and back. decode refuses another version (the first byte), a block
// cut short, a count past BlockReader::kMaxCount, a value outside its R range and bytes after
// the end, each with a CheckpointError saying so.
template <typename Block> std::vector<uint8_t> encode(const Block &block)
{
    BlockWriter out;
    write(out, block);
    return out.take();
}

template <typename Block> Block decode(const std::vector<uint8_t> &bytes, const char *name, uint8_t version)
{
    if (bytes.empty() || bytes[0] != version) {
        throw service::CheckpointError(std::string("the checkpoint's ") + name + " block is of another version");
    }
    BlockReader in(bytes, name);
    Block block;
    read(in, block);
    if (!in.done()) {
        in.fail("has bytes after its end");
    }
    return block;
}

} // namespace cdro::hostd::blocks
