#include "concord/net/team_key.h"

#include <fcntl.h>
#include <sodium.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <string_view>

#include "secret_file.h"

namespace concord::net {

namespace {

constexpr std::string_view kHeader = "concord-team-key-v1 ";
constexpr std::size_t kMaxKeyFileBytes = 4096;

}  // namespace

void ensure_sodium() {
  if (sodium_init() < 0) throw TeamKeyError("libsodium could not be initialized");
}

TeamKey::TeamKey() = default;
TeamKey::~TeamKey() { sodium_memzero(bytes_.data(), bytes_.size()); }
TeamKey::TeamKey(const TeamKey& other) = default;
TeamKey& TeamKey::operator=(const TeamKey& other) = default;

TeamKey TeamKey::generate() {
  ensure_sodium();
  TeamKey key;
  randombytes_buf(key.bytes_.data(), key.bytes_.size());
  return key;
}

TeamKey TeamKey::from_seed_for_tests(const std::string& seed) {
  ensure_sodium();
  TeamKey key;
  crypto_generichash(key.bytes_.data(), key.bytes_.size(),
                     reinterpret_cast<const unsigned char*>(seed.data()), seed.size(), nullptr, 0);
  return key;
}

TeamKey TeamKey::parse(const std::string& text, const std::string& source_name) {
  ensure_sodium();
  std::string_view rest(text);
  if (rest.substr(0, kHeader.size()) != kHeader)
    throw TeamKeyError(source_name + ": not a Concord team key (expected a line starting with '" +
                       std::string(kHeader) + "')");
  rest.remove_prefix(kHeader.size());
  TeamKey key;
  if (!detail::decode_hex(rest, key.bytes_.data(), key.bytes_.size()))
    throw TeamKeyError(source_name + ": malformed team key (expected " +
                       std::to_string(2 * kBytes) + " hex digits)");
  return key;
}

std::string TeamKey::format() const {
  std::string hex = detail::encode_hex(bytes_.data(), bytes_.size());
  std::string text = std::string(kHeader) + hex + "\n";
  detail::wipe(hex);
  return text;
}

TeamKey load_team_key(const std::filesystem::path& path) {
  const std::string name = "team key " + path.string();
  return detail::parse_secret_file(
      path, name, [&](const std::string& text) { return TeamKey::parse(text, name); });
}

void write_team_key(const std::filesystem::path& path, const TeamKey& key) {
  std::string text = key.format();
  detail::write_secret_file(path, "team key " + path.string(), text);
}

namespace detail {

std::string read_secret_file(const std::filesystem::path& path, const std::string& name) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NOFOLLOW);
  if (fd < 0) throw TeamKeyError(name + ": cannot open: " + std::strerror(errno));
  struct stat info {};
  if (::fstat(fd, &info) != 0 || !S_ISREG(info.st_mode)) {
    ::close(fd);
    throw TeamKeyError(name + ": not a regular file");
  }
  if ((info.st_mode & (S_IRWXG | S_IRWXO)) != 0) {
    ::close(fd);
    char mode[8];
    std::snprintf(mode, sizeof mode, "%04o", static_cast<unsigned>(info.st_mode & 07777));
    throw TeamKeyError(name + ": mode " + mode +
                       " lets other users read or change it; run chmod 600 on it");
  }
  std::string text(kMaxKeyFileBytes, '\0');
  const ssize_t bytes = ::read(fd, text.data(), text.size());
  ::close(fd);
  if (bytes < 0) throw TeamKeyError(name + ": cannot read: " + std::strerror(errno));
  text.resize(static_cast<std::size_t>(bytes));
  return text;
}

void write_secret_file(const std::filesystem::path& path, const std::string& name,
                       std::string& text) {
  const WipeOnExit wipe_text{text};
  const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC | O_NOFOLLOW, 0600);
  if (fd < 0) throw TeamKeyError(name + ": cannot create: " + std::strerror(errno));
  const ssize_t written = ::write(fd, text.data(), text.size());
  const bool synced = ::fsync(fd) == 0;
  ::close(fd);
  if (written != static_cast<ssize_t>(text.size()) || !synced) {
    ::unlink(path.c_str());
    throw TeamKeyError(name + ": cannot write");
  }
}

void wipe(std::string& text) { sodium_memzero(text.data(), text.size()); }

bool decode_hex(std::string_view hex, unsigned char* out, std::size_t size) {
  while (!hex.empty() && (hex.back() == '\n' || hex.back() == '\r' || hex.back() == ' '))
    hex.remove_suffix(1);
  std::size_t decoded = 0;
  const char* end = nullptr;
  return hex.size() == 2 * size &&
         sodium_hex2bin(out, size, hex.data(), hex.size(), nullptr, &decoded, &end) == 0 &&
         decoded == size;
}

std::string encode_hex(const unsigned char* bytes, std::size_t size) {
  std::string hex(2 * size + 1, '\0');
  sodium_bin2hex(hex.data(), hex.size(), bytes, size);
  hex.pop_back();
  return hex;
}

}  // namespace detail

}  // namespace concord::net
