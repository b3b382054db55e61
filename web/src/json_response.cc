#include "concord/web/json_response.h"

#include <utility>

namespace concord::web {

Response json_response(int status, const nlohmann::json& body) {
  Response response;
  response.status = status;
  response.content_type = "application/json";
  response.body = body.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
  response.body.push_back('\n');
  // Readable from any origin: the live map page of one robot draws its neighbours from their
  // endpoints. The state is read-only and served without credentials, so a page elsewhere learns
  // nothing it could not ask for with curl.
  response.headers.emplace_back("Access-Control-Allow-Origin", "*");
  return response;
}

Response error_response(int status, std::string message) {
  return json_response(status, {{"error", {{"status", status}, {"message", std::move(message)}}}});
}

}  // namespace concord::web
