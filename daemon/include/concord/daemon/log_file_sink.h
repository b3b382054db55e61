#pragma once
/// \file
/// The daemon's log file (config key `log_file`): an spdlog sink appending to a file that SIGHUP
/// reopens, so that logrotate can move the file away and the daemon goes on in a new one. Without
/// `log_file` the daemon logs to stderr (journald keeps it under systemd).

#include <spdlog/sinks/base_sink.h>

#include <cstdio>
#include <filesystem>
#include <mutex>
#include <stdexcept>
#include <string>

namespace concord::daemon {

class LogFileSink final : public spdlog::sinks::base_sink<std::mutex> {
 public:
  /// Opens (creates, appends to) `file`; std::runtime_error naming it if it cannot.
  explicit LogFileSink(std::filesystem::path file) : file_(std::move(file)) {
    stream_ = open_or_throw(file_);
  }
  ~LogFileSink() override {
    if (stream_) std::fclose(stream_);
  }
  LogFileSink(const LogFileSink&) = delete;
  LogFileSink& operator=(const LogFileSink&) = delete;

  /// Closes the file and opens it again under its name (a new file if it was moved away).
  /// Returns "" or why it failed; on failure the old stream is kept. Any thread.
  std::string reopen() {
    std::lock_guard lock(mutex_);
    std::FILE* fresh = std::fopen(file_.c_str(), "a");
    if (!fresh) return "cannot reopen the log file " + file_.string();
    if (stream_) std::fclose(stream_);
    stream_ = fresh;
    return {};
  }

  const std::filesystem::path& file() const { return file_; }

 protected:
  void sink_it_(const spdlog::details::log_msg& message) override {
    spdlog::memory_buf_t formatted;
    formatter_->format(message, formatted);
    std::fwrite(formatted.data(), 1, formatted.size(), stream_);
  }
  void flush_() override { std::fflush(stream_); }

 private:
  static std::FILE* open_or_throw(const std::filesystem::path& file) {
    std::FILE* stream = std::fopen(file.c_str(), "a");
    if (!stream)
      throw std::runtime_error("log_file: cannot open " + file.string() + " for appending");
    return stream;
  }

  std::filesystem::path file_;
  std::FILE* stream_ = nullptr;
};

}  // namespace concord::daemon
