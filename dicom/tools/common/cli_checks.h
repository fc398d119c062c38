#pragma once
// CLI11 checks whose messages a person can read. CLI11 2.1's PositiveNumber and
// NonNegativeNumber are ranges up to DBL_MAX and say so in 300 digits ("Value 0 not in range
// 0.000000 to 17976931348623157081452742373170435679807056752584499659891747680315726…").

#include <CLI/CLI.hpp>

#include <optional>
#include <string>

#include "cli_support.h"

namespace octoray::cli {

namespace detail {

// A check that the option's text is a finite number with `accept(value)` true; otherwise
// "<what>, not <text>".
template <typename Accept>
CLI::Validator numberCheck(const char* name, const char* what, Accept accept) {
  return CLI::Validator(
      [what, accept](std::string& text) -> std::string {
        const std::optional<double> value = parseFiniteNumber(text);
        if (value && accept(*value)) return "";
        return std::string(what) + ", not " + text;
      },
      name);
}

}  // namespace detail

// A finite number above 0.
inline const CLI::Validator kPositive =
    detail::numberCheck("POSITIVE", "must be a number above 0", [](double v) { return v > 0; });

// A finite number of 0 or more.
inline const CLI::Validator kNonNegative =
    detail::numberCheck("NONNEGATIVE", "must be 0 or a number above it", [](double v) { return v >= 0; });

}  // namespace octoray::cli
