// output_file.hpp: opening the files the service writes (JSON Lines, checkpoints, captures, the
// log) so that another user cannot redirect them (docs/service.md, "Security
// model"):
//   - never through a symbolic link: the file is opened with O_NOFOLLOW (a link planted at the
//     path is refused with a message, its target never touched), and files that must not exist
//     yet are created with O_EXCL;
//   - temporary files get a name nobody can predict (mkostemp), in the target's directory;
//   - a directory every user may write to (/tmp, mode 1777, or worse) is refused: anyone could
//     plant a link or a file of their own under the name the service is about to use.
// Character devices (/dev/null) and FIFOs are allowed as they are: they are not files another
// user can plant in a directory of ours.
#pragma once

#include <cstdint>
#include <string>

namespace cdro::service {

// Throws ConfigError naming `what` (e.g. "output.jsonl") and the reason when `path` is a
// symbolic link or sits in a directory that every user may write to. A path that does not
// exist yet is fine (its directory is checked).
void checkOutputPath(const std::string &path, const std::string &what);

// open(2) of an output file after checkOutputPath, with O_NOFOLLOW | O_CLOEXEC added to flags;
// returns the descriptor or throws ConfigError with strerror and the advice.
int openOutputFile(const std::string &path, int flags, const std::string &what);

// A new, empty file with an unpredictable name next to `path` ("<path>.tmp.XXXXXX"), created
// with O_EXCL; *temp_path receives its name. Throws ConfigError.
int createTempNextTo(const std::string &path, const std::string &what, std::string *temp_path);

// Rotation of a size-bounded output file (the capture and the JSON Lines file): path.<keep>
// is deleted, path.<i> becomes path.<i+1>, path becomes path.1 (keep == 0: path is deleted).
// Links are renamed as they are, never followed. Leaves nothing at path.
void rotateFiles(const std::string &path, uint32_t keep);

// The name of the index-th rotated file: path for 0, else "path.<index>".
std::string rotatedFileName(const std::string &path, uint32_t index);

} // namespace cdro::service
