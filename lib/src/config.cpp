#include "depthfuse/config.hpp"

namespace depthfuse {

const char* to_string(Method m) {
  switch (m) {
    case Method::kKyostila13: return "kyostila13";
    case Method::kYlimaki17: return "ylimaki17";
    case Method::kFull: return "full";
  }
  return "unknown";
}

bool parse_method(const std::string& text, Method* out) {
  for (Method m : {Method::kKyostila13, Method::kYlimaki17, Method::kFull}) {
    if (text == to_string(m)) {
      *out = m;
      return true;
    }
  }
  return false;
}

ReconstructionConfig ReconstructionConfig::with_method(Method m) const {
  ReconstructionConfig c = *this;
  c.pipeline.method = m;
  c.prefilter.enabled = m != Method::kKyostila13;
  c.postfilter.enabled = m != Method::kKyostila13;
  c.registration.enabled = m == Method::kFull;
  return c;
}

}  // namespace depthfuse
