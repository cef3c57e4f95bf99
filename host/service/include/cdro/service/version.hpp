// version.hpp: what `--version` prints, here and in every Python tool (tools/cdro_tools/cli.py
// prints the same words): the release, the serial protocol version and the layout hashes of the
// frames and checkpoints this build speaks, so that a report or a mismatch with the firmware can
// be told from the output alone.
#pragma once

#include <string>

namespace cdro::service {

// "<program> 0.1.0 (protocol 2, frame layout 0x4D0F, checkpoint layout 0x3879)"
std::string versionText(const std::string &program);

// The release alone ("0.1.0"), from the CMake project version.
const char *releaseVersion();

} // namespace cdro::service
