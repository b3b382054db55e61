#pragma once
/// \file
/// Prometheus text exposition format (version 0.0.4): HELP and TYPE once per metric name, then
/// samples with labels.

#include <cmath>
#include <cstdio>
#include <set>
#include <string>

namespace concord::daemon {

class MetricsText {
 public:
  void counter(const std::string& name, const std::string& help, const std::string& labels,
               double value) {
    sample(name, "counter", help, labels, value);
  }
  void gauge(const std::string& name, const std::string& help, const std::string& labels,
             double value) {
    sample(name, "gauge", help, labels, value);
  }
  const std::string& str() const { return text_; }

 private:
  void sample(const std::string& name, const char* type, const std::string& help,
              const std::string& labels, double value) {
    if (declared_.insert(name).second) {
      text_ += "# HELP " + name + " " + help + "\n# TYPE " + name + " " + type + "\n";
    }
    char number[32];
    if (std::isfinite(value)) {
      std::snprintf(number, sizeof number, "%.17g", value);
    } else {
      std::snprintf(number, sizeof number, "%s", std::isnan(value) ? "NaN" : value > 0 ? "+Inf" : "-Inf");
    }
    text_ += name + (labels.empty() ? "" : "{" + labels + "}") + " " + number + "\n";
  }

  std::string text_;
  std::set<std::string> declared_;
};

}  // namespace concord::daemon
