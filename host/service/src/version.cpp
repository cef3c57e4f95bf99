#include "cdro/service/version.hpp"

#include <cstdio>

#include "cdro/frames.h"
#include "cdro/sog_layout.h"

#ifndef CDRO_VERSION
#error "CDRO_VERSION is defined by host/service/CMakeLists.txt from the project version"
#endif

namespace cdro::service {

const char *releaseVersion() { return CDRO_VERSION; }

std::string versionText(const std::string &program)
{
    char text[128];
    std::snprintf(text, sizeof text, " %s (protocol %d, frame layout 0x%04X, checkpoint layout 0x%04X)", CDRO_VERSION,
                  CDRO_PROTOCOL_VERSION, static_cast<unsigned>(CDRO_LAYOUT_HASH),
                  static_cast<unsigned>(CDRO_SOG_LAYOUT_HASH));
    return program + text;
}

} // namespace cdro::service
