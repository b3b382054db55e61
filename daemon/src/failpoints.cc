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
  auto seconds_argument = [&](double& seconds) -> std::string {
    double value = 0.0;
    try {
      std::size_t used = 0;
      value = std::stod(argument, &used);
      if (used != argument.size()) throw std::invalid_argument(argument);
    } catch (const std::exception&) {
      return "failpoint " + name + " needs =SECONDS, got '" + argument + "'";
    }
    if (!(value > 0.0 && value <= 86400.0))
      return "failpoint " + name + ": SECONDS must be in (0, 86400], got " + argument;
    seconds = value;
    return {};
  };
  if (name == "estimator.hang") return seconds_argument(failpoints.estimator_hang_seconds);
  if (name == "exit.linger") return seconds_argument(failpoints.exit_linger_seconds);
  return "unknown failpoint '" + name +
         "' (known: marginal.silence, marginal.garbage, estimator.hang=SECONDS, output.fail, exit.linger=SECONDS)";
}

}  // namespace concord::daemon
