// yaml_section.hpp: one section of cdro-hostd's YAML configuration (a map), read key by key
// with types and ranges, and a final check that every key in it was known, so that a typo is
// an error naming the file, line, key and the keys that exist, never a silent default. Shared
// by the service's sections (config.cpp) and the engine's (host/hostd/src/engine_config.cpp).
#pragma once

#include <cmath>
#include <cstdint>
#include <set>
#include <sstream>
#include <string>
#include <type_traits>
#include <vector>

#include <yaml-cpp/yaml.h>

#include "cdro/frames.h"
#include "cdro/service/config.hpp"

namespace cdro::service {

// "file:line" of a node (or the file alone when yaml-cpp has no position).
inline std::string where(const YAML::Node &node, const std::string &origin)
{
    const YAML::Mark mark = node.Mark();
    if (mark.line < 0) {
        return origin;
    }
    return origin + ":" + std::to_string(mark.line + 1);
}

// One section (a YAML map): typed reads by key, and a final check that every key was known.
class Section {
public:
    Section(const YAML::Node &node, std::string name, std::string origin)
        : node_(node), name_(std::move(name)), origin_(std::move(origin))
    {
        if (node_ && !node_.IsNull() && !node_.IsMap()) {
            throw ConfigError(where(node_, origin_) + ": section '" + name_ + "' must be a map of keys");
        }
    }

    // Integers are read as int64 and floats as double, then range-checked, so that a small
    // type never wraps (yaml-cpp would read uint8_t as a character).
    template <typename T> void read(const char *key, T &value, T minimum, T maximum)
    {
        using Wide = std::conditional_t<std::is_floating_point_v<T>, double, int64_t>;
        const YAML::Node item = lookup(key);
        if (!item) {
            return;
        }
        Wide parsed{};
        try {
            parsed = item.as<Wide>();
        } catch (const YAML::Exception &) {
            fail(item, key,
                 std::string("expected ") + (std::is_floating_point_v<T> ? "a number" : "an integer") + ", got '" +
                     scalarText(item) + "'");
        }
        if constexpr (std::is_floating_point_v<T>) {
            if (!std::isfinite(parsed)) {
                fail(item, key, "must be a finite number");
            }
        }
        if (parsed < static_cast<Wide>(minimum) || parsed > static_cast<Wide>(maximum)) {
            std::ostringstream message;
            message << "must be between " << static_cast<Wide>(minimum) << " and " << static_cast<Wide>(maximum)
                    << ", got " << parsed;
            fail(item, key, message.str());
        }
        value = static_cast<T>(parsed);
    }

    void readString(const char *key, std::string &value)
    {
        const YAML::Node item = lookup(key);
        if (!item) {
            return;
        }
        if (item.IsNull()) {
            value.clear();
            return;
        }
        if (!item.IsScalar()) {
            fail(item, key, "expected a string");
        }
        value = item.Scalar();
    }

    void readBool(const char *key, bool &value)
    {
        const YAML::Node item = lookup(key);
        if (!item) {
            return;
        }
        try {
            value = item.as<bool>();
        } catch (const YAML::Exception &) {
            fail(item, key, "expected true or false, got '" + scalarText(item) + "'");
        }
    }

    // A nested section (a map under this one), registered as a known key.
    YAML::Node child(const char *key) { return lookup(key); }
    const std::string &name() const { return name_; }
    const std::string &origin() const { return origin_; }

    void readIds(const char *key, std::vector<uint16_t> &ids)
    {
        const YAML::Node item = lookup(key);
        if (!item) {
            return;
        }
        ids.clear();
        if (item.IsNull()) {
            return;
        }
        if (!item.IsSequence()) {
            fail(item, key, "expected a list of node ids, e.g. [0x6069, 0x6A11]");
        }
        std::set<uint16_t> seen;
        for (const YAML::Node &element : item) {
            int64_t id = 0;
            try {
                id = element.as<int64_t>();
            } catch (const YAML::Exception &) {
                fail(element, key, "node id '" + scalarText(element) + "' is not an integer");
            }
            if (id < 1 || id > 65535) {
                fail(element, key, "node id " + std::to_string(id) + " is outside 1..65535");
            }
            if (!seen.insert(static_cast<uint16_t>(id)).second) {
                fail(element, key, "node id " + std::to_string(id) + " is listed twice");
            }
            ids.push_back(static_cast<uint16_t>(id));
        }
        if (ids.size() > CDRO_MAX_NODES) {
            fail(item, key,
                 std::to_string(ids.size()) + " ids, the protocol carries at most " + std::to_string(CDRO_MAX_NODES));
        }
    }

    // A string key with a fixed set of values; returns the index of the value.
    void readChoice(const char *key, const std::vector<std::string> &choices, size_t &index)
    {
        std::string text;
        if (!lookup(key)) {
            return;
        }
        readString(key, text);
        for (size_t i = 0; i < choices.size(); ++i) {
            if (choices[i] == text) {
                index = i;
                return;
            }
        }
        std::string allowed;
        for (const std::string &choice : choices) {
            allowed += (allowed.empty() ? "" : ", ") + choice;
        }
        fail(lookup(key), key, "'" + text + "' is not one of: " + allowed);
    }

    // Every key of the section must have been read by name.
    void rejectUnknownKeys() const
    {
        if (!node_ || !node_.IsMap()) {
            return;
        }
        for (const auto &entry : node_) {
            const std::string key = entry.first.as<std::string>();
            if (known_.count(key) == 0) {
                std::string allowed;
                for (const std::string &name : known_) {
                    allowed += (allowed.empty() ? "" : ", ") + name;
                }
                throw ConfigError(where(entry.first, origin_) + ": unknown key '" + key + "' in section '" + name_ +
                                  "' (known keys: " + allowed + ")");
            }
        }
    }

private:
    YAML::Node lookup(const char *key)
    {
        known_.insert(key);
        if (!node_ || !node_.IsMap()) {
            return YAML::Node(YAML::NodeType::Undefined);
        }
        for (const auto &entry : node_) {
            if (entry.first.as<std::string>() == key) {
                return entry.second;
            }
        }
        return YAML::Node(YAML::NodeType::Undefined);
    }

    static std::string scalarText(const YAML::Node &item)
    {
        return item.IsScalar() ? item.Scalar() : std::string("(not a scalar)");
    }

    [[noreturn]] void fail(const YAML::Node &item, const char *key, const std::string &why) const
    {
        throw ConfigError(where(item, origin_) + ": " + name_ + "." + key + ": " + why);
    }

    YAML::Node node_;
    std::string name_;
    std::string origin_;
    std::set<std::string> known_;
};

// Every top-level key of a configuration document must be one of `sections`, so that a typo in
// a section's name ("htpp:") is an error naming the file, the line and the sections that exist
// rather than a whole section silently left at its defaults. Only the program that knows every
// layer's sections can call it (cdro-hostd: the service's and the engine's).
inline void rejectUnknownSections(const YAML::Node &root, const std::string &origin,
                                  const std::vector<std::string> &sections)
{
    if (!root || !root.IsMap()) {
        return;
    }
    for (const auto &entry : root) {
        const std::string name = entry.first.IsScalar() ? entry.first.Scalar() : std::string("(not a name)");
        bool known = false;
        for (const std::string &section : sections) {
            known = known || section == name;
        }
        if (!known) {
            std::string allowed;
            for (const std::string &section : sections) {
                allowed += (allowed.empty() ? "" : ", ") + section;
            }
            throw ConfigError(where(entry.first, origin) + ": unknown section '" + name +
                              "' (known sections: " + allowed + ")");
        }
    }
}

} // namespace cdro::service
