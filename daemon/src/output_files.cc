#include "output_files.h"

#include <fcntl.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cstring>
#include <stdexcept>

namespace concord::daemon {

namespace {

std::string errno_text() { return std::strerror(errno); }

void fsync_folder(const std::filesystem::path& folder) {
  const int fd = ::open(folder.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) throw std::runtime_error(folder.string() + ": cannot open folder: " + errno_text());
  const int result = ::fsync(fd);
  ::close(fd);
  if (result != 0) throw std::runtime_error(folder.string() + ": fsync failed: " + errno_text());
}

}  // namespace

void write_output_file(const std::filesystem::path& file, const std::string& content,
                       bool durable) {
  static std::atomic<unsigned long> counter{0};
  const std::filesystem::path folder = file.parent_path().empty() ? "." : file.parent_path();
  const std::filesystem::path temporary =
      folder / ("." + file.filename().string() + ".tmp." + std::to_string(::getpid()) + "." +
                std::to_string(counter++));
  auto fail = [&](const std::string& problem) {
    ::unlink(temporary.c_str());
    throw std::runtime_error(file.string() + ": cannot write: " + problem);
  };
  const int fd = ::open(temporary.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) fail("cannot create " + temporary.string() + ": " + errno_text());
  std::size_t written = 0;
  while (written < content.size()) {
    const ssize_t n = ::write(fd, content.data() + written, content.size() - written);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      const std::string reason = errno_text();
      ::close(fd);
      fail("write error: " + reason);
    }
    written += static_cast<std::size_t>(n);
  }
  if (durable && ::fsync(fd) != 0) {
    const std::string reason = errno_text();
    ::close(fd);
    fail("fsync failed: " + reason);
  }
  if (::close(fd) != 0) fail("close failed: " + errno_text());
  if (::rename(temporary.c_str(), file.c_str()) != 0) fail("rename failed: " + errno_text());
  if (durable) fsync_folder(folder);
}

void check_output_folder(const std::filesystem::path& folder) {
  std::error_code error;
  std::filesystem::create_directories(folder, error);
  if (error)
    throw std::runtime_error("output directory " + folder.string() +
                             ": cannot create: " + error.message());
  const std::filesystem::path probe = folder / (".write-probe." + std::to_string(::getpid()));
  const int fd = ::open(probe.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0)
    throw std::runtime_error("output directory " + folder.string() +
                             " is not writable: " + errno_text());
  const bool ok = ::write(fd, "x", 1) == 1 && ::fsync(fd) == 0;
  const std::string reason = errno_text();
  ::close(fd);
  ::unlink(probe.c_str());
  if (!ok)
    throw std::runtime_error("output directory " + folder.string() + " is not writable: " + reason);
}

int remove_stale_temporaries(const std::filesystem::path& folder) {
  int removed = 0;
  std::error_code error;
  for (const auto& entry : std::filesystem::directory_iterator(folder, error)) {
    const std::string name = entry.path().filename().string();
    const bool temporary =
        name.size() > 1 && name[0] == '.' &&
        (name.find(".tmp.") != std::string::npos || name.rfind(".write-probe.", 0) == 0);
    if (!temporary || !entry.is_regular_file(error)) continue;
    if (std::filesystem::remove(entry.path(), error)) ++removed;
  }
  return removed;
}

}  // namespace concord::daemon
