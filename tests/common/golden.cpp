#include "golden.hpp"

#include <fstream>
#include <sstream>
#include <stdexcept>

namespace golden {

std::string readFile(const std::string &path)
{
    std::ifstream in(path, std::ios::binary);
    if (!in) {
        throw std::runtime_error("cannot open " + path);
    }
    std::ostringstream out;
    out << in.rdbuf();
    return out.str();
}

const nlohmann::json &vectors()
{
    static const nlohmann::json parsed =
        nlohmann::json::parse(readFile(std::string(CDRO_GOLDEN_DIR) + "/vectors.json"));
    return parsed;
}

std::vector<uint8_t> fromHex(const std::string &hex)
{
    std::vector<uint8_t> bytes;
    for (size_t i = 0; i + 1 < hex.size(); i += 2) {
        bytes.push_back(static_cast<uint8_t>(std::stoul(hex.substr(i, 2), nullptr, 16)));
    }
    return bytes;
}

std::string toHex(const uint8_t *data, size_t len)
{
    static const char digits[] = "0123456789abcdef";
    std::string out;
    for (size_t i = 0; i < len; ++i) {
        out += digits[data[i] >> 4];
        out += digits[data[i] & 0x0F];
    }
    return out;
}

uint8_t frameTypeId(const std::string &name)
{
#define GOLDEN_X_ID(NAME, lower, id, doc) \
    if (name == #NAME) {                  \
        return id;                        \
    }
    CDRO_FRAME_LIST(GOLDEN_X_ID)
    CDRO_EMPTY_FRAME_LIST(GOLDEN_X_ID)
#undef GOLDEN_X_ID
    throw std::runtime_error("unknown frame type " + name);
}

#define GOLDEN_X_FILL(KIND, field, unit, doc) m.field = static_cast<CDRO_CTYPE_##KIND>(j.at(#field).get<int64_t>());
#define GOLDEN_X_FILL_RANGED(KIND, field, unit, lo, hi, doc) GOLDEN_X_FILL(KIND, field, unit, doc)
#define GOLDEN_X_FILL_ARRAY(KIND, field, max, unit, lo, hi, doc)                  \
    {                                                                             \
        const auto &items = j.at(#field);                                         \
        m.field##_count = static_cast<uint8_t>(items.size());                     \
        for (size_t i = 0; i < items.size() && i < (max); ++i) {                  \
            m.field[i] = static_cast<CDRO_CTYPE_##KIND>(items[i].get<int64_t>()); \
        }                                                                         \
    }
#define GOLDEN_X_TO(KIND, field, unit, doc) out[#field] = static_cast<int64_t>(m.field);
#define GOLDEN_X_TO_RANGED(KIND, field, unit, lo, hi, doc) GOLDEN_X_TO(KIND, field, unit, doc)
#define GOLDEN_X_TO_ARRAY(KIND, field, max, unit, lo, hi, doc) \
    {                                                          \
        auto items = nlohmann::json::array();                  \
        for (size_t i = 0; i < m.field##_count; ++i) {         \
            items.push_back(static_cast<int64_t>(m.field[i])); \
        }                                                      \
        out[#field] = items;                                   \
    }

cdro_frame_t frameFromJson(const nlohmann::json &entry)
{
    cdro_frame_t frame{};
    frame.type = frameTypeId(entry.at("type").get<std::string>());
    frame.sequence = entry.at("sequence").get<uint16_t>();
    frame.version = CDRO_PROTOCOL_VERSION;
    const nlohmann::json j = entry.contains("fields") ? entry.at("fields") : nlohmann::json::object();
    switch (frame.type) {
#define GOLDEN_X_CASE(NAME, lower, id, doc)                                                 \
    case id: {                                                                              \
        auto &m = frame.as.lower;                                                           \
        CDRO_FIELDS_##NAME(GOLDEN_X_FILL, GOLDEN_X_FILL_RANGED, GOLDEN_X_FILL_ARRAY) break; \
    }
        CDRO_FRAME_LIST(GOLDEN_X_CASE)
#undef GOLDEN_X_CASE
    default: break;
    }
    return frame;
}

nlohmann::json fieldsToJson(const cdro_frame_t &frame)
{
    nlohmann::json out = nlohmann::json::object();
    switch (frame.type) {
#define GOLDEN_X_CASE(NAME, lower, id, doc)                                           \
    case id: {                                                                        \
        const auto &m = frame.as.lower;                                               \
        CDRO_FIELDS_##NAME(GOLDEN_X_TO, GOLDEN_X_TO_RANGED, GOLDEN_X_TO_ARRAY) break; \
    }
        CDRO_FRAME_LIST(GOLDEN_X_CASE)
#undef GOLDEN_X_CASE
    default: break;
    }
    return out;
}

} // namespace golden
