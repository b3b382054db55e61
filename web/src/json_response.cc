#include "concord/web/json_response.h"

#include <utility>

namespace concord::web {

Response json_response(int status, const nlohmann::json& body) {
  Response response;
  response.status = status;
  response.content_type = "application/json";
  response.body = body.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
  response.body.push_back('\n');
  return response;
}

Response error_response(int status, std::string message) {
  return json_response(status, {{"error", {{"status", status}, {"message", std::move(message)}}}});
}

}  // namespace concord::web
