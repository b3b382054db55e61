#include "concord/daemon/failpoints.h"

#include <cmath>
#include <stdexcept>

namespace concord::daemon {

std::string enable_failpoint(const std::string& text, Failpoints& failpoints) {
  const std::size_t equals = text.find('=');
  const std::string name = text.substr(0, equals);
  const std::string argument = equals == std::string::npos ? "" : text.substr(equals + 1);
  const bool has_argument = equals != std::string::npos;
  auto no_argument = [&](bool& flag) -> std::string {
    if (has_argument) return "failpoint " + name + " takes no argument";
    flag = true;
    return {};
  };
  if (name == "marginal.silence") return no_argument(failpoints.marginal_silence);
  if (name == "marginal.garbage") return no_argument(failpoints.marginal_garbage);
  if (name == "output.fail") return no_argument(failpoints.output_fail);
  if (name == "estimator.hang") {
    double seconds = 0.0;
    try {
      std::size_t used = 0;
      seconds = std::stod(argument, &used);
      if (used != argument.size()) throw std::invalid_argument(argument);
    } catch (const std::exception&) {
      return "failpoint estimator.hang needs =SECONDS, got '" + argument + "'";
    }
    if (!(seconds > 0.0 && seconds <= 86400.0))
      return "failpoint estimator.hang: SECONDS must be in (0, 86400], got " + argument;
    failpoints.estimator_hang_seconds = seconds;
    return {};
  }
  return "unknown failpoint '" + name +
         "' (known: marginal.silence, marginal.garbage, estimator.hang=SECONDS, output.fail)";
}

}  // namespace concord::daemon
