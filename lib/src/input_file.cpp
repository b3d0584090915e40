// Input files are opened here only (see input_file.hpp).
#include "depthfuse/input_file.hpp"

#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <utility>

#include "depthfuse/base/errno_text.hpp"

namespace depthfuse {
namespace {

const char* kind_of(mode_t mode) {
  if (S_ISFIFO(mode)) return "a FIFO";
  if (S_ISDIR(mode)) return "a directory";
  if (S_ISCHR(mode)) return "a character device";
  if (S_ISBLK(mode)) return "a block device";
  if (S_ISSOCK(mode)) return "a socket";
  return "not a file";
}

Status not_regular(const std::string& name, mode_t mode) {
  return invalid_argument(name + " is " + kind_of(mode) + ", not a regular file");
}

Status os_refused(const std::string& name, int err) {
  if (err == ENOENT || err == ENOTDIR) return not_found(name + ": " + errno_text(err));
  return io_error(name + ": " + errno_text(err));
}

}  // namespace

Result<InputFile> InputFile::open(const std::string& path, const std::string& what) {
  const std::string name = what + " " + path;
  // Looked at before it is opened: opening a FIFO for reading waits for a writer.
  struct stat info {};
  if (::stat(path.c_str(), &info) != 0) return os_refused(name, errno);
  if (!S_ISREG(info.st_mode)) return not_regular(name, info.st_mode);
  // Without waiting, should the name have been replaced by a FIFO in between; fstat then says so.
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NOCTTY | O_NONBLOCK);
  if (fd < 0) return os_refused(name, errno);
  if (::fstat(fd, &info) != 0 || !S_ISREG(info.st_mode)) {
    const int err = errno;
    ::close(fd);
    return S_ISREG(info.st_mode) ? os_refused(name, err) : not_regular(name, info.st_mode);
  }
  // Readers expect blocking reads (a regular file never waits either way).
  const int flags = ::fcntl(fd, F_GETFL);
  if (flags >= 0) (void)::fcntl(fd, F_SETFL, flags & ~O_NONBLOCK);
  return InputFile(fd, info, path, what);
}

InputFile::InputFile(int fd, const struct stat& info, std::string path, std::string what)
    : fd_(fd), info_(info), path_(std::move(path)), what_(std::move(what)) {}

InputFile::InputFile(InputFile&& other) noexcept
    : fd_(std::exchange(other.fd_, -1)), info_(other.info_), path_(std::move(other.path_)),
      what_(std::move(other.what_)) {}

InputFile& InputFile::operator=(InputFile&& other) noexcept {
  if (this != &other) {
    if (fd_ >= 0) ::close(fd_);
    fd_ = std::exchange(other.fd_, -1);
    info_ = other.info_;
    path_ = std::move(other.path_);
    what_ = std::move(other.what_);
  }
  return *this;
}

InputFile::~InputFile() {
  if (fd_ >= 0) ::close(fd_);
}

Result<std::string> InputFile::read_all(size_t max_bytes) {
  auto too_large = [&](uint64_t bytes) {
    return invalid_argument(name() + " is " + std::to_string(bytes) + " bytes; a " + what_ +
                            " is at most " + std::to_string(max_bytes));
  };
  if (static_cast<uint64_t>(info_.st_size) > max_bytes) return too_large(info_.st_size);
  std::string text;
  text.resize(static_cast<size_t>(info_.st_size));
  size_t got = 0;
  for (;;) {
    // One byte beyond the size the file had: a file that grew is read to its end, within the cap.
    if (got == text.size()) {
      if (text.size() > max_bytes) return too_large(text.size());
      text.resize(std::min(max_bytes + 1, std::max<size_t>(text.size() * 2, 4096)));
    }
    const ssize_t n = ::read(fd_, text.data() + got, text.size() - got);
    if (n < 0) {
      if (errno == EINTR) continue;
      return io_error(name() + ": cannot read: " + errno_text());
    }
    if (n == 0) break;
    got += static_cast<size_t>(n);
  }
  if (got > max_bytes) return too_large(got);
  text.resize(got);
  return text;
}

Result<std::string> read_input_file(const std::string& path, const std::string& what,
                                    size_t max_bytes) {
  auto file = InputFile::open(path, what);
  if (!file) return file.status();
  return file->read_all(max_bytes);
}

Status check_input_file(const std::string& path, const std::string& what) {
  return InputFile::open(path, what).status();
}

}  // namespace depthfuse
