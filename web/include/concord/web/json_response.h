#pragma once
/// \file
/// Responses with JSON bodies, including the error body every server error uses.

#include <nlohmann/json.hpp>
#include <string>

#include "concord/web/http_server.h"

namespace concord::web {

/// A response with `body` serialised compactly (plus a final newline, for curl users) and
/// Content-Type application/json. Invalid UTF-8 in strings is replaced by U+FFFD rather than
/// throwing, so data received from peers can never turn a reply into a 500. Carries
/// Access-Control-Allow-Origin: * (the live map page reads neighbours' endpoints).
Response json_response(int status, const nlohmann::json& body);

/// A JSON error response: {"error": {"status": <status>, "message": <message>}}.
Response error_response(int status, std::string message);

}  // namespace concord::web
