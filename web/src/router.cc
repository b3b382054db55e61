#include "router.h"

#include <spdlog/spdlog.h>

#include <cassert>
#include <exception>
#include <utility>

#include "concord/web/json_response.h"
#include "concord/web/target.h"

namespace concord::web {

void Router::add_get(std::string path, Handler handler) {
  assert(!path.empty() && path.front() == '/' && "a route path starts with '/'");
  assert(path.find('?') == std::string::npos && "a route path has no query");
  assert(handler && "a route needs a handler");
  [[maybe_unused]] const bool inserted =
      routes_.emplace(std::move(path), std::move(handler)).second;
  assert(inserted && "a route path registers once");
}

Response Router::handle(std::string_view method, std::string_view target) const {
  ParsedTarget parsed = parse_target(target);
  if (!parsed.ok()) return error_response(400, parsed.error);

  const auto route = routes_.find(parsed.path);
  if (route == routes_.end()) return error_response(404, "no route for " + parsed.path);

  if (method != "GET" && method != "HEAD") {
    Response response =
        error_response(405, "method " + std::string(method) + " not allowed on " + parsed.path +
                                " (allowed: " + kAllowedMethods + ")");
    response.headers.emplace_back("Allow", kAllowedMethods);
    return response;
  }

  const Request request{std::string(method), std::string(target), std::move(parsed.path),
                        std::move(parsed.query)};
  try {
    Response response = route->second(request);
    if (response.status < 200 || response.status > 599) {
      spdlog::error("HTTP handler for {} {} returned invalid status {}", request.method,
                    request.target, response.status);
      return error_response(500, "internal error in the handler of " + request.path);
    }
    return response;
  } catch (const std::exception& error) {
    spdlog::error("HTTP handler for {} {} threw: {}", request.method, request.target, error.what());
  } catch (...) {
    spdlog::error("HTTP handler for {} {} threw a non-standard exception", request.method,
                  request.target);
  }
  return error_response(500, "internal error in the handler of " + request.path);
}

}  // namespace concord::web
