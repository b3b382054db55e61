#pragma once
/// \file
/// Request handling as a function of (method, target): routing, query parsing and the 400, 404,
/// 405 and 500 answers. No I/O; HttpServer's sessions call it once per request.

#include <functional>
#include <map>
#include <string>
#include <string_view>

#include "concord/web/http_server.h"

namespace concord::web {

/// The GET routes of a server.
class Router {
 public:
  /// The Allow field of every route.
  static constexpr const char* kAllowedMethods = "GET, HEAD";

  /// Registers `handler` for exactly `path`. Asserts that the path starts with '/', has no '?',
  /// and is not registered yet.
  void add_get(std::string path, Handler handler);

  /// The answer to `method` on `target` (HEAD is answered as GET; the caller drops the body):
  /// 400 for a malformed target, 404 for an unknown path, 405 with an Allow field for a method
  /// other than GET and HEAD, 500 when the handler throws or returns a status outside 200..599
  /// (logged), otherwise what the handler returns.
  Response handle(std::string_view method, std::string_view target) const;

 private:
  std::map<std::string, Handler, std::less<>> routes_;
};

}  // namespace concord::web
