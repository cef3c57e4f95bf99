#include "cdro/service/checkpoint.hpp"

#include <cerrno>
#include <cstring>
#include <fstream>
#include <iterator>

#include <fcntl.h>
#include <unistd.h>

#include "cdro/service/config.hpp"
#include "cdro/service/output_file.hpp"
#include "cdro/checkpoint_layout.h"

namespace cdro::service {

namespace {

int vectorSink(void *context, const uint8_t *bytes, size_t len)
{
    auto *out = static_cast<std::vector<uint8_t> *>(context);
    out->insert(out->end(), bytes, bytes + len);
    return 1;
}

void check(cdro_result_t status, const char *what)
{
    if (status != CDRO_OK) {
        throw CheckpointError(std::string("checkpoint: encoding failed at ") + what);
    }
}

std::string directoryOf(const std::string &path)
{
    const size_t slash = path.rfind('/');
    if (slash == std::string::npos) {
        return ".";
    }
    return slash == 0 ? "/" : path.substr(0, slash);
}

} // namespace

const SogSnapshot::Extension *SogSnapshot::findExtension(uint16_t tag) const
{
    for (const Extension &extension : extensions) {
        if (extension.tag == tag) {
            return &extension;
        }
    }
    return nullptr;
}

std::vector<uint8_t> encodeServiceInfo(const ServiceCheckpointInfo &info)
{
    cdro_service_info_t block{};
    block.run_start_unix_us = info.run_start_unix_us;
    block.last_event_unix_us = info.last_event_unix_us;
    block.frames_delivered = info.frames_delivered;
    std::vector<uint8_t> bytes(CDRO_SERVICE_INFO_MAX_SIZE);
    bytes.resize(cdro_service_info_encode(&block, bytes.data()));
    return bytes;
}

bool decodeServiceInfo(const std::vector<uint8_t> &bytes, ServiceCheckpointInfo *info)
{
    cdro_service_info_t block{};
    if (cdro_service_info_decode(bytes.data(), bytes.size(), &block) != CDRO_OK) {
        return false;
    }
    info->run_start_unix_us = block.run_start_unix_us;
    info->last_event_unix_us = block.last_event_unix_us;
    info->frames_delivered = block.frames_delivered;
    return true;
}

std::vector<uint8_t> encodeSnapshot(const SogSnapshot &snapshot)
{
    cdro_sog_header_t header = snapshot.header;
    header.layout_version = CDRO_SOG_LAYOUT_VERSION;
    header.layout_hash = CDRO_SOG_LAYOUT_HASH;
    if (snapshot.nodes.size() > UINT16_MAX || snapshot.pairs.size() > UINT32_MAX) {
        throw CheckpointError("checkpoint: too many nodes or pairs for the snapshot format");
    }
    header.node_count = static_cast<uint16_t>(snapshot.nodes.size());
    header.pair_count = static_cast<uint32_t>(snapshot.pairs.size());
    uint64_t components = 0;
    for (const SogSnapshot::Pair &pair : snapshot.pairs) {
        if (pair.components.size() > UINT16_MAX) {
            throw CheckpointError("checkpoint: a pair has more than 65535 components");
        }
        components += pair.components.size();
    }
    if (components > UINT32_MAX) {
        throw CheckpointError("checkpoint: too many components");
    }
    header.component_count = static_cast<uint32_t>(components);

    std::vector<uint8_t> out;
    cdro_sog_writer_t writer;
    cdro_sog_writer_init(&writer, vectorSink, &out);
    check(cdro_sog_write_header(&writer, &header), "header");
    for (const cdro_sog_node_t &node : snapshot.nodes) {
        check(cdro_sog_write_node(&writer, &node), "node");
    }
    for (const SogSnapshot::Pair &pair : snapshot.pairs) {
        cdro_sog_pair_t record = pair.pair;
        record.component_count = static_cast<uint16_t>(pair.components.size());
        check(cdro_sog_write_pair(&writer, &record), "pair");
        for (const cdro_sog_component_t &component : pair.components) {
            check(cdro_sog_write_component(&writer, &component), "component");
        }
    }
    for (const SogSnapshot::Extension &extension : snapshot.extensions) {
        if (extension.tag == 0 || extension.bytes.size() > UINT32_MAX) {
            throw CheckpointError("checkpoint: extension tag 0 is the end marker");
        }
        check(cdro_sog_write_extension(&writer, extension.tag, extension.bytes.data(),
                                       static_cast<uint32_t>(extension.bytes.size())),
              "extension");
    }
    check(cdro_sog_write_end(&writer), "end");
    return out;
}

SogSnapshot decodeSnapshot(const uint8_t *bytes, size_t len, const std::string &origin)
{
    SogSnapshot snapshot;
    cdro_sog_reader_t reader;
    const cdro_result_t status = cdro_sog_reader_init(&reader, bytes, len, &snapshot.header);
    switch (status) {
    case CDRO_OK: break;
    case CDRO_ERR_TYPE: throw CheckpointError(origin + ": not a SoG snapshot (bad magic or too short)");
    case CDRO_ERR_CRC:
        throw CheckpointError(origin + ": corrupt or cut short (CRC-32 mismatch over " + std::to_string(len) +
                              " bytes); refusing to resume from it");
    case CDRO_ERR_VERSION:
        throw CheckpointError(origin + ": snapshot of another layout (this build reads layout version " +
                              std::to_string(CDRO_SOG_LAYOUT_VERSION) + ")");
    case CDRO_ERR_LENGTH: throw CheckpointError(origin + ": the record counts do not fit the file");
    default: throw CheckpointError(origin + ": unreadable snapshot (" + std::string(cdro_result_name(status)) + ")");
    }
    auto fail = [&origin](const std::string &what) -> CheckpointError {
        return CheckpointError(origin + ": " + what + " (snapshot inconsistent; refusing to resume from it)");
    };
    snapshot.nodes.resize(snapshot.header.node_count);
    for (cdro_sog_node_t &node : snapshot.nodes) {
        if (cdro_sog_read_node(&reader, &node) != CDRO_OK) {
            throw fail("node records run out");
        }
    }
    uint64_t components = 0;
    for (uint32_t i = 0; i < snapshot.header.pair_count; ++i) {
        SogSnapshot::Pair pair;
        if (cdro_sog_read_pair(&reader, &pair.pair) != CDRO_OK) {
            throw fail("pair records run out");
        }
        components += pair.pair.component_count;
        if (components > snapshot.header.component_count) {
            throw fail("more components than the header announces");
        }
        pair.components.resize(pair.pair.component_count);
        for (cdro_sog_component_t &component : pair.components) {
            if (cdro_sog_read_component(&reader, &component) != CDRO_OK) {
                throw fail("component records run out");
            }
        }
        snapshot.pairs.push_back(std::move(pair));
    }
    if (components != snapshot.header.component_count) {
        throw fail("fewer components than the header announces");
    }
    for (;;) {
        uint16_t tag = 0;
        const uint8_t *data = nullptr;
        uint32_t size = 0;
        if (cdro_sog_read_extension(&reader, &tag, &data, &size) != CDRO_OK) {
            throw fail("an extension block runs past the end");
        }
        if (tag == 0) {
            break;
        }
        snapshot.extensions.push_back({tag, std::vector<uint8_t>(data, data + size)});
    }
    return snapshot;
}

void writeCheckpointFile(const std::string &path, const SogSnapshot &snapshot)
{
    const std::vector<uint8_t> bytes = encodeSnapshot(snapshot);
    // A fresh temporary name each time (O_EXCL): a link planted at a predictable name can
    // neither redirect the write nor be followed.
    std::string temp;
    int fd = -1;
    try {
        fd = createTempNextTo(path, "checkpoint", &temp);
    } catch (const ConfigError &error) {
        throw CheckpointError(error.what());
    }
    size_t done = 0;
    while (done < bytes.size()) {
        const ssize_t n = ::write(fd, bytes.data() + done, bytes.size() - done);
        if (n < 0 && errno == EINTR) {
            continue;
        }
        if (n < 0) {
            const std::string error = std::strerror(errno);
            ::close(fd);
            ::unlink(temp.c_str());
            throw CheckpointError("checkpoint: cannot write " + temp + ": " + error);
        }
        done += static_cast<size_t>(n);
    }
    if (::fsync(fd) != 0) {
        const std::string error = std::strerror(errno);
        ::close(fd);
        ::unlink(temp.c_str());
        throw CheckpointError("checkpoint: fsync of " + temp + " failed: " + error);
    }
    ::close(fd);
    if (::rename(temp.c_str(), path.c_str()) != 0) {
        const std::string error = std::strerror(errno);
        ::unlink(temp.c_str());
        throw CheckpointError("checkpoint: cannot rename " + temp + " to " + path + ": " + error);
    }
    // The rename itself must reach the disk, or a power loss could bring the old file back.
    const int dir = ::open(directoryOf(path).c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    if (dir >= 0) {
        ::fsync(dir);
        ::close(dir);
    }
}

SogSnapshot loadCheckpointFile(const std::string &path)
{
    std::ifstream in(path, std::ios::binary);
    if (!in) {
        throw CheckpointError(path + ": cannot read the checkpoint: " + std::strerror(errno));
    }
    const std::vector<uint8_t> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    return decodeSnapshot(bytes.data(), bytes.size(), path);
}

} // namespace cdro::service
