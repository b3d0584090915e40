// Opening the files a program takes as input: a config, the rig key, a scan file, an image, a
// camera file, a list or a trajectory, a cloud, an LCM log. Only a regular file is opened: a FIFO,
// a device, a socket or a directory where a file is expected is refused with a message naming it
// before anything opens it for reading (opening a FIFO waits for a writer, forever if none comes;
// reading a device may never end).
#pragma once

#include <sys/stat.h>

#include <cstddef>
#include <string>

#include "depthfuse/status.hpp"

namespace depthfuse {

class InputFile {
 public:
  // `what` names the file in messages ("config", "rig key", "scan file"): "config /tmp/x is a
  // FIFO, not a regular file". not_found when there is no such file, invalid_argument when it is
  // not a regular file, io_error when the system refuses (permissions, ...).
  static Result<InputFile> open(const std::string& path, const std::string& what);

  InputFile(InputFile&& other) noexcept;
  InputFile& operator=(InputFile&& other) noexcept;
  InputFile(const InputFile&) = delete;
  InputFile& operator=(const InputFile&) = delete;
  ~InputFile();

  int fd() const { return fd_; }
  // The open file's status (fstat): its size, mode, owner.
  const struct stat& info() const { return info_; }
  // "<what> <path>", for messages.
  std::string name() const { return what_ + " " + path_; }

  // The whole file; one of more than max_bytes is refused ("... is N bytes; a <what> is at most
  // M").
  Result<std::string> read_all(size_t max_bytes);

 private:
  InputFile(int fd, const struct stat& info, std::string path, std::string what);

  int fd_ = -1;
  struct stat info_ {};
  std::string path_, what_;
};

// The whole of a regular file (InputFile::open, then read_all).
Result<std::string> read_input_file(const std::string& path, const std::string& what,
                                    size_t max_bytes);

// For a library that opens a file by its name (SQLite, liblcm's log reader): the same refusals,
// the file opened (without waiting, should it have become a FIFO) and closed again.
Status check_input_file(const std::string& path, const std::string& what);

}  // namespace depthfuse
