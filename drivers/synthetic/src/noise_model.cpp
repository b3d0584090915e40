#include "depthfuse/synthetic/noise_model.hpp"

#include <cmath>
#include <string>

namespace depthfuse::synthetic {

namespace {

Status check_probability(const char* name, double v) {
  if (!(v >= 0.0 && v <= 1.0))
    return invalid_argument(std::string("noise.") + name +
                            " must be a probability in [0, 1], got " + std::to_string(v));
  return Status::ok();
}

Status check_non_negative(const char* name, double v) {
  if (!(v >= 0.0) || !std::isfinite(v))
    return invalid_argument(std::string("noise.") + name + " must be finite and >= 0, got " +
                            std::to_string(v));
  return Status::ok();
}

}  // namespace

Status NoiseConfig::validate() const {
  DF_RETURN_IF_ERROR(check_non_negative("axial_scale", axial_scale));
  if (!(axial_max_incidence_deg >= 0.0 && axial_max_incidence_deg < 90.0))
    return invalid_argument("noise.axial_max_incidence_deg must be in [0, 90), got " +
                            std::to_string(axial_max_incidence_deg));
  DF_RETURN_IF_ERROR(check_probability("flying_probability", flying_probability));
  DF_RETURN_IF_ERROR(check_non_negative("flying_min_jump_m", flying_min_jump_m));
  DF_RETURN_IF_ERROR(check_non_negative("flying_min_jump_fraction", flying_min_jump_fraction));
  DF_RETURN_IF_ERROR(check_non_negative("mpi_max_bias_m", mpi_max_bias_m));
  DF_RETURN_IF_ERROR(check_non_negative("mpi_range_m", mpi_range_m));
  DF_RETURN_IF_ERROR(check_probability("dropout_probability", dropout_probability));
  if (!(dropout_grazing_start_deg >= 0.0 && dropout_grazing_start_deg < 90.0))
    return invalid_argument("noise.dropout_grazing_start_deg must be in [0, 90), got " +
                            std::to_string(dropout_grazing_start_deg));
  DF_RETURN_IF_ERROR(check_non_negative("dropout_far_start_m", dropout_far_start_m));
  DF_RETURN_IF_ERROR(check_probability("dropout_far_probability", dropout_far_probability));
  DF_RETURN_IF_ERROR(check_probability("outlier_probability", outlier_probability));
  return Status::ok();
}

}  // namespace depthfuse::synthetic
