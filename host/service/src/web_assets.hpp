// web_assets.hpp: the live map's page, embedded at build time from host/service/web/.
#pragma once

#include <cstddef>
#include <vector>

namespace cdro::service {

struct WebAsset {
    const char *path; // "/index.html"
    const char *data;
    size_t size; // bytes
};

const std::vector<WebAsset> &webAssets();

} // namespace cdro::service
