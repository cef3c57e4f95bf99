#include "cdro/service/output_file.hpp"

#include <cerrno>
#include <cstring>
#include <vector>

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include "cdro/service/config.hpp"

namespace cdro::service {

namespace {

std::string directoryOf(const std::string &path)
{
    const size_t slash = path.rfind('/');
    if (slash == std::string::npos) {
        return ".";
    }
    return slash == 0 ? "/" : path.substr(0, slash);
}

std::string octal(unsigned mode)
{
    char text[8];
    std::snprintf(text, sizeof text, "%04o", mode & 07777U);
    return text;
}

} // namespace

void checkOutputPath(const std::string &path, const std::string &what)
{
    struct stat st {};
    if (::lstat(path.c_str(), &st) == 0) {
        if (S_ISLNK(st.st_mode)) {
            throw ConfigError(what + ": '" + path +
                              "' is a symbolic link; refusing to write through it (its target "
                              "could be any file you can write). Remove the link, or give the real path");
        }
        if (S_ISCHR(st.st_mode) || S_ISFIFO(st.st_mode)) {
            return; // /dev/null, a named pipe: nothing to plant there
        }
    }
    const std::string directory = directoryOf(path);
    struct stat dir {};
    if (::stat(directory.c_str(), &dir) != 0) {
        return; // no such directory: opening the file fails and says so
    }
    if ((dir.st_mode & S_IWOTH) != 0) {
        throw ConfigError(what + ": the directory '" + directory + "' (mode " + octal(dir.st_mode) +
                          ") can be written by every user, who could plant a link or a file of their own "
                          "under '" +
                          path + "'; write to a directory only you (or your group) can write");
    }
}

int openOutputFile(const std::string &path, int flags, const std::string &what)
{
    checkOutputPath(path, what);
    const int fd = ::open(path.c_str(), flags | O_NOFOLLOW | O_CLOEXEC, 0644);
    if (fd < 0) {
        const int error = errno;
        if (error == ELOOP) {
            throw ConfigError(what + ": '" + path + "' is a symbolic link; refusing to write through it");
        }
        throw ConfigError(what + ": cannot write " + path + ": " + std::strerror(error));
    }
    return fd;
}

int createTempNextTo(const std::string &path, const std::string &what, std::string *temp_path)
{
    checkOutputPath(path, what);
    std::string pattern = path + ".tmp.XXXXXX";
    std::vector<char> name(pattern.begin(), pattern.end());
    name.push_back('\0');
    const int fd = ::mkostemp(name.data(), O_CLOEXEC); // O_EXCL with a random name
    if (fd < 0) {
        throw ConfigError(what + ": cannot create a temporary file next to '" + path + "': " + std::strerror(errno));
    }
    ::fchmod(fd, 0644);
    *temp_path = name.data();
    return fd;
}

std::string rotatedFileName(const std::string &path, uint32_t index)
{
    return index == 0 ? path : path + "." + std::to_string(index);
}

void rotateFiles(const std::string &path, uint32_t keep)
{
    if (keep == 0) {
        ::unlink(path.c_str());
        return;
    }
    // path.<keep> falls off the end; then every file moves up by one.
    ::unlink(rotatedFileName(path, keep).c_str());
    for (uint32_t index = keep; index >= 1; --index) {
        const std::string from = rotatedFileName(path, index - 1);
        struct stat st {};
        if (::lstat(from.c_str(), &st) == 0) { // a link counts, whatever it points at
            ::rename(from.c_str(), rotatedFileName(path, index).c_str());
        }
    }
}

} // namespace cdro::service
