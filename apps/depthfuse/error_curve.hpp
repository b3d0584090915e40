// The cumulative error curve of `depthfuse eval`, written as CSV and as a PNG plot. Kept out of the
// core library, which knows only the method: the plot is the one thing there that needs OpenCV.
#pragma once

#include <string>
#include <utility>
#include <vector>

#include "depthfuse/evaluation.hpp"
#include "depthfuse/status.hpp"

namespace depthfuse::cli {

// "error_m,fraction_of_points" rows from 0 to max_m in steps of step_m.
Status write_cumulative_csv(const std::string& path, const DistanceSummary& s,
                            double step_m = 0.0005, double max_m = 0.02);

// One or more labelled curves in one plot, errors from 0 to max_m.
Status write_cumulative_png(const std::string& path,
                            const std::vector<std::pair<std::string, const DistanceSummary*>>& curves,
                            double max_m = 0.02);

}  // namespace depthfuse::cli
