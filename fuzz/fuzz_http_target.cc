// libFuzzer target: the HTTP request-target parser (path and percent-decoded query) on
// arbitrary bytes. Never crash; a target accepted starts with '/'.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string_view>

#include "concord/web/target.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  const concord::web::ParsedTarget parsed = concord::web::parse_target(text);
  if (parsed.ok() && (text.empty() || text.front() != '/')) std::abort();
  (void)concord::web::percent_decode(text, true);
  return 0;
}
