// Access to tests/golden/vectors.json, the vectors shared with the Python tests.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "cdro/frames.h"

namespace golden {

const nlohmann::json &vectors();
std::vector<uint8_t> fromHex(const std::string &hex);
std::string toHex(const uint8_t *data, size_t len);
inline std::string toHex(const std::vector<uint8_t> &bytes) { return toHex(bytes.data(), bytes.size()); }
std::string readFile(const std::string &path);

// A frame from a golden entry's "type", "sequence" and "fields" (fields by the names of
// frame_layout.def), and back; both generated from the layout table, like the codec itself.
cdro_frame_t frameFromJson(const nlohmann::json &entry);
nlohmann::json fieldsToJson(const cdro_frame_t &frame);
uint8_t frameTypeId(const std::string &name);

} // namespace golden
